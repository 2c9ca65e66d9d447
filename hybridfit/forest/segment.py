"""Foreground (hand) masks for depth frames.

- Synthetic data: the part labels (> 0), or simply depth > 0 (the background reads 0).
- Real frames (``segment_hand``): with a given hand centre, the pixels whose 3D point lies
  in an axis-aligned cube of side ``cube_mm`` around it; otherwise the nearest object: the
  pixels no deeper than ``depth_range_mm`` behind the frame's nearest surface, where the
  nearest surface is the ``speckle``-th smallest valid depth (so a few flying pixels in
  front of the hand do not count).
"""

from __future__ import annotations

import numpy as np

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError


def segment_hand(depths: np.ndarray, intrinsics: Intrinsics | None = None, centres_xyz: np.ndarray | None = None,
                 *, depth_range_mm: float = 150.0, cube_mm: float = 250.0, speckle: int = 20) -> np.ndarray:
    """(n, H, W) uint16 mm -> (n, H, W) bool hand masks (see the module docstring).

    centres_xyz: optional (n, 3) hand centres in camera mm (needs ``intrinsics``)."""
    depths = np.asarray(depths)
    if depths.ndim != 3:
        raise HybridfitError(f"depths must be (frames, H, W), got shape {depths.shape}")
    valid = depths > 0
    d = depths.astype(np.float32)
    if centres_xyz is not None:
        if intrinsics is None:
            raise HybridfitError("segmenting around a hand centre needs the camera intrinsics")
        c = np.asarray(centres_xyz, np.float64).reshape(len(depths), 3)
        h = cube_mm / 2
        H, W = depths.shape[1:]
        u = np.arange(W, dtype=np.float32)[None, None, :]
        v = np.arange(H, dtype=np.float32)[None, :, None]
        x = (u - intrinsics.cx) * d / intrinsics.fx
        y = (v - intrinsics.cy) * d / intrinsics.fy
        return (valid & (np.abs(d - c[:, 2, None, None]) <= h) & (np.abs(x - c[:, 0, None, None]) <= h)
                & (np.abs(y - c[:, 1, None, None]) <= h))
    masks = np.zeros(depths.shape, bool)
    for i in range(len(depths)):
        vals = d[i][valid[i]]
        if len(vals) == 0:
            continue
        near = np.partition(vals, min(speckle, len(vals) - 1))[min(speckle, len(vals) - 1)]
        masks[i] = valid[i] & (d[i] <= near + depth_range_mm)
    return masks


def dataset_masks(ds, indices: np.ndarray, depths: np.ndarray, foreground: str = "auto") -> np.ndarray:
    """Foreground masks (n, H, W) bool for frames ``indices`` of a Dataset.

    foreground: "labels" (part labels > 0), "depth" (depth > 0), "segment"
    (``segment_hand``, nearest object), or "auto": the part labels where the dataset has
    any for these frames, else the segmentation."""
    if foreground not in ("auto", "labels", "depth", "segment"):
        raise HybridfitError(f"unknown foreground mode {foreground!r} (auto, labels, depth, segment)")
    if foreground == "depth":
        return depths > 0
    if foreground == "segment":
        return segment_hand(depths)
    try:
        parts = np.asarray(ds.part_labels(indices))
    except (AttributeError, NotImplementedError, KeyError, OSError, HybridfitError):
        parts = None
    if parts is not None and parts.shape == depths.shape and parts.any():
        return parts > 0
    if foreground == "labels":
        raise HybridfitError("the data set has no part labels for these frames")
    return segment_hand(depths)
