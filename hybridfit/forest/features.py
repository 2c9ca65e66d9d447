"""Depth-invariant features (Shotton et al. 2013) on packed depth crops, as numba kernels.

f(x) = d(x + u / d(x)) - d(x + v / d(x)), with the offsets u, v stored in millimetres
(a lateral displacement at the pixel's depth): the pixel offset is u * fx / d(x), so a
forest transfers between cameras of different focal length. Background (depth 0) and
out-of-image pixels read the large constant ``background_mm``.

Depth frames are held as foreground crops packed into one flat uint16 buffer: frame f is
``buf[meta[f, 4] : meta[f, 4] + h * w]`` laid out row-major, where ``meta[f] = (y0, x0,
h, w, offset)``. Everything outside the crop is background, so a crop is exact as long as
it covers every foreground pixel. Training and test use the same code path.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def pack_crops(depths: np.ndarray, masks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, H, W) uint16 mm and (n, H, W) bool foreground -> buffer (total,) uint16, meta (n, 5) int64.

    Pixels outside the mask become background (0); each frame keeps its mask's bounding box.
    """
    bufs, meta, offset = [], np.zeros((len(depths), 5), np.int64), 0
    for f in range(len(depths)):
        rows = np.flatnonzero(masks[f].any(axis=1))
        cols = np.flatnonzero(masks[f].any(axis=0))
        if len(rows) == 0:
            meta[f] = (0, 0, 0, 0, offset)
            continue
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        crop = np.where(masks[f, y0:y1, x0:x1], depths[f, y0:y1, x0:x1], 0).astype(np.uint16)
        bufs.append(crop.ravel())
        meta[f] = (y0, x0, y1 - y0, x1 - x0, offset)
        offset += crop.size
    buf = np.concatenate(bufs) if bufs else np.zeros(0, np.uint16)
    return buf, meta


@njit(cache=True, nogil=True, inline="always")
def _read(buf, meta, f, u, v, background):
    x = u - meta[f, 1]
    y = v - meta[f, 0]
    if x < 0 or y < 0 or x >= meta[f, 3] or y >= meta[f, 2]:
        return background
    d = buf[meta[f, 4] + y * meta[f, 3] + x]
    return background if d == 0 else np.float32(d)


@njit(cache=True, nogil=True, inline="always")
def feature(buf, meta, f, u, v, d, feat, fx, fy, background):
    """One feature value (float32 mm) at pixel (u, v) of frame f with depth d (mm).

    feat: (4,) offsets (ux, uy, vx, vy) in mm."""
    sx = fx / d
    sy = fy / d
    a = _read(buf, meta, f, u + int(np.floor(feat[0] * sx + 0.5)), v + int(np.floor(feat[1] * sy + 0.5)), background)
    b = _read(buf, meta, f, u + int(np.floor(feat[2] * sx + 0.5)), v + int(np.floor(feat[3] * sy + 0.5)), background)
    return np.float32(a - b)


@njit(cache=True, nogil=True)
def eval_features(buf, meta, s_frame, s_u, s_v, s_d, rows, feats, fx, fy, background):
    """Feature values (nf, n) float32 for samples ``rows`` (n,) and features (nf, 4) mm."""
    out = np.empty((feats.shape[0], rows.shape[0]), np.float32)
    for i in range(rows.shape[0]):
        r = rows[i]
        for k in range(feats.shape[0]):
            out[k, i] = feature(buf, meta, s_frame[r], s_u[r], s_v[r], s_d[r], feats[k], fx, fy, background)
    return out


@njit(cache=True, nogil=True)
def traverse(buf, meta, s_frame, s_u, s_v, s_d, node_feature, node_threshold, node_left, node_right,
             node_leaf, roots, fx, fy, background):
    """Leaf index (n, T) int32 of every sample in every tree (left when f < threshold)."""
    n, T = s_frame.shape[0], roots.shape[0]
    out = np.empty((n, T), np.int32)
    for i in range(n):
        for t in range(T):
            node = roots[t]
            while node_left[node] >= 0:
                val = feature(buf, meta, s_frame[i], s_u[i], s_v[i], s_d[i], node_feature[node], fx, fy, background)
                node = node_left[node] if val < node_threshold[node] else node_right[node]
            out[i, t] = node_leaf[node]
    return out
