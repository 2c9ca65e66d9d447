"""Helpers shared by the forest commands (train, propose, estimate): opening a data set."""

from __future__ import annotations

import numpy as np

from ..errors import HybridfitError


def open_dataset(path: str):
    """A data-set folder through ``hybridfit.dataset.load_dataset`` (errors name the folder)."""
    try:
        from ..dataset import load_dataset
    except ImportError as err:
        raise HybridfitError(f"{path}: reading data sets needs hybridfit.dataset ({err})") from None
    return load_dataset(path)


def frame_indices(ds, frames: int | None) -> np.ndarray:
    """The first ``frames`` frames of ``ds`` (all for None)."""
    n = len(ds)
    return np.arange(n if frames is None else min(frames, n))


def ground_truth(ds, indices: np.ndarray) -> np.ndarray | None:
    """(n, J, 3) mm joints of the frames, or None where the data set has none."""
    try:
        gt = ds.joints_xyz
    except (AttributeError, NotImplementedError, KeyError):
        return None
    if gt is None:
        return None
    gt = np.asarray(gt, np.float64)
    return gt[indices] if gt.ndim == 3 and len(gt) >= len(indices) and np.isfinite(gt[indices]).all() else None


def report_empty(empty: np.ndarray, indices: np.ndarray, err) -> None:
    """List frames without foreground pixels on ``err`` (at most 10)."""
    bad = indices[np.flatnonzero(empty)]
    for f in bad[:10]:
        print(f"  frame {int(f)}: no foreground pixels (empty result)", file=err)
    if len(bad) > 10:
        print(f"  ... and {len(bad) - 10} more empty frames", file=err)
