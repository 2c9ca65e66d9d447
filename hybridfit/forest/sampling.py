"""Training samples: foreground pixels drawn from depth frames, with part labels.

Each sample carries its part label (the closest joint) and, via its frame, the 3D offsets
from its point to every joint; the frames are kept as packed depth crops (``features.py``).
Pixels are drawn with ``numpy.random.default_rng([seed, 1_000_003])``.
"""

from __future__ import annotations

import numpy as np

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError
from .config import ForestConfig
from .features import pack_crops


class TrainingSet:
    """Sampled training pixels over packed depth crops (see ``features.py``).

    s_frame, s_u, s_v (N,) int32, s_d (N,) float32 mm, labels (N,) int32 in [0, J),
    xyz (N, 3) float32 mm, joints (F, J, 3) float32 mm, buf / meta the packed crops.
    """

    def __init__(self, config: ForestConfig, intrinsics: Intrinsics):
        self.config, self.intrinsics = config, intrinsics
        self._rng = np.random.default_rng([config.seed, 1_000_003])
        self._parts: dict[str, list] = {k: [] for k in ("buf", "meta", "frame", "u", "v", "d", "label", "joints")}
        self._frames = self._offset = 0

    def add(self, depths: np.ndarray, joints_xyz: np.ndarray, parts: np.ndarray | None = None) -> None:
        """Add frames: depths (n, H, W) uint16 mm, joints_xyz (n, J, 3) mm, parts (n, H, W)
        uint8 (0 background, j + 1 closest joint j) or None (foreground = depth > 0,
        labels = nearest joint in 3D)."""
        depths, joints_xyz, parts = _check_frames(depths, joints_xyz, parts, self.intrinsics)
        masks = parts > 0 if parts is not None else depths > 0
        buf, meta = pack_crops(depths, masks)
        meta[:, 4] += self._offset
        P, K = self._parts, self.config.pixels_per_frame
        for i in range(len(depths)):
            v, u = np.nonzero(masks[i])
            if len(v) > K:
                pick = np.sort(self._rng.choice(len(v), K, replace=False))
                v, u = v[pick], u[pick]
            d = depths[i, v, u].astype(np.float32)
            if parts is not None:
                label = parts[i, v, u].astype(np.int32) - 1
            else:
                xyz = _points(u, v, d, self.intrinsics)
                label = np.argmin(((xyz[:, None, :] - joints_xyz[i][None]) ** 2).sum(-1), axis=1).astype(np.int32)
            P["frame"].append(np.full(len(v), self._frames + i, np.int32))
            P["u"].append(u.astype(np.int32))
            P["v"].append(v.astype(np.int32))
            P["d"].append(d)
            P["label"].append(label)
        P["buf"].append(buf)
        P["meta"].append(meta)
        P["joints"].append(joints_xyz.astype(np.float32))
        self._frames += len(depths)
        self._offset += len(buf)

    def finish(self) -> "TrainingSet":
        """Concatenate what was added and shuffle the sample order (leaves subsample by order)."""
        P = self._parts
        if not P["frame"] or sum(len(a) for a in P["frame"]) == 0:
            raise HybridfitError("no training samples: the frames have no foreground pixels")
        cat = {k: np.concatenate(v) for k, v in P.items()}
        order = self._rng.permutation(len(cat["frame"]))
        self.s_frame, self.s_u, self.s_v = cat["frame"][order], cat["u"][order], cat["v"][order]
        self.s_d, self.labels = cat["d"][order], cat["label"][order]
        self.buf, self.meta, self.joints = cat["buf"], cat["meta"], cat["joints"]
        self.xyz = _points(self.s_u, self.s_v, self.s_d, self.intrinsics).astype(np.float32)
        return self

    def __len__(self) -> int:
        return len(self.s_frame)


def _points(u, v, d, K: Intrinsics) -> np.ndarray:
    """Pixel (u, v) with depth d mm -> (n, 3) camera xyz mm."""
    d = np.asarray(d, np.float64)
    return np.stack([(u - K.cx) * d / K.fx, (v - K.cy) * d / K.fy, d], axis=-1)


def _check_frames(depths, joints_xyz, parts, K: Intrinsics):
    depths, joints_xyz = np.asarray(depths), np.asarray(joints_xyz)
    if depths.ndim != 3 or depths.dtype != np.uint16:
        raise HybridfitError(f"depths must be (frames, H, W) uint16 mm, got {depths.shape} {depths.dtype}")
    if depths.shape[1:] != (K.height, K.width):
        raise HybridfitError(f"depth frames are {depths.shape[2]}x{depths.shape[1]} but the intrinsics say {K.width}x{K.height}")
    if joints_xyz.ndim != 3 or joints_xyz.shape[0] != len(depths) or joints_xyz.shape[2] != 3:
        raise HybridfitError(f"joints_xyz must be ({len(depths)}, J, 3) mm, got {joints_xyz.shape}")
    if not np.isfinite(joints_xyz).all():
        raise HybridfitError("joints_xyz has NaN or inf values")
    if parts is not None:
        parts = np.asarray(parts)
        if parts.shape != depths.shape or parts.dtype != np.uint8:
            raise HybridfitError(f"parts must be {depths.shape} uint8, got {parts.shape} {parts.dtype}")
        if parts.max(initial=0) > joints_xyz.shape[1]:
            raise HybridfitError(f"part label {int(parts.max())} exceeds the {joints_xyz.shape[1]} joints")
    return depths, joints_xyz, parts
