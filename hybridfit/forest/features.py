"""Depth-invariant features (Shotton et al. 2013) on packed depth crops, as numba kernels.

f(x) = d(x + u / d(x)) - d(x + v / d(x)), with the offsets u, v stored in millimetres
(a lateral displacement at the pixel's depth): the pixel offset is u * fx / d(x), so a
forest transfers between cameras of different focal length. Background (depth 0) and
out-of-image pixels read the large constant ``background_mm``.

Depth frames are held as foreground crops packed into one flat uint16 buffer: frame f is
``buf[meta[f, 4] : meta[f, 4] + h * w]`` laid out row-major, where ``meta[f] = (y0, x0,
h, w, offset)``. Everything outside the crop is background, so a crop is exact as long as
it covers every foreground pixel. At test time (``traverse``) a frame is read directly as
an image, 0 off the foreground: the same values as its crop.
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


def pack_nodes(node_feature: np.ndarray, node_threshold: np.ndarray, node_left: np.ndarray, node_right: np.ndarray,
               node_leaf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The node arrays (N, 4), (N,), (N,), (N,), (N,) interleaved for ``traverse``: one 32-byte
    record per node, so a visit reads one cache line. Returns nodes (N, 8) float32 (ux, uy, vx,
    vy mm, threshold mm, then three int32 stored bitwise) and links, the (N, 3) int32 view of
    those three (left, right, leaf)."""
    nodes = np.empty((len(node_threshold), 8), np.float32)
    nodes[:, :4] = node_feature
    nodes[:, 4] = node_threshold
    bits = nodes.view(np.int32)
    bits[:, 5], bits[:, 6], bits[:, 7] = node_left, node_right, node_leaf
    return nodes, bits[:, 5:]


@njit(cache=True, nogil=True, inline="always")
def _pixel(image, x, y, background):
    if x < 0 or y < 0 or x >= image.shape[1] or y >= image.shape[0]:
        return background
    d = image[y, x]
    return background if d == 0 else np.float32(d)


@njit(cache=True, nogil=True)
def traverse(image, s_u, s_v, s_d, nodes, links, roots, fx, fy, background, lanes=16):
    """Leaf index (n, T) int32 of pixels (s_u, s_v) with depths s_d (n,) float32 mm of one
    frame in every tree (left when f < threshold). image: the frame (H, W) uint16 mm, 0
    off the foreground (the features read as on a packed crop of it); nodes, links from
    ``pack_nodes``.

    ``lanes`` pixels go down all trees in lockstep, one level per step, and the child is
    picked without a branch: the memory reads of independent walks overlap."""
    n, T = s_u.shape[0], roots.shape[0]
    out = np.empty((n, T), np.int32)
    L = lanes * T
    node = np.empty(L, np.int64)
    u, v = np.empty(L, np.int64), np.empty(L, np.int64)
    sx, sy = np.empty(L), np.empty(L)
    for i0 in range(0, n, lanes):
        nl = min(lanes, n - i0) * T
        for w in range(nl):
            i = i0 + w // T
            node[w], u[w], v[w] = roots[w % T], s_u[i], s_v[i]
            sx[w], sy[w] = fx / s_d[i], fy / s_d[i]
        busy = True
        while busy:
            busy = False
            for w in range(nl):
                k = node[w]
                if links[k, 0] < 0:
                    continue
                busy = True
                a = _pixel(image, u[w] + int(np.floor(nodes[k, 0] * sx[w] + 0.5)),
                           v[w] + int(np.floor(nodes[k, 1] * sy[w] + 0.5)), background)
                b = _pixel(image, u[w] + int(np.floor(nodes[k, 2] * sx[w] + 0.5)),
                           v[w] + int(np.floor(nodes[k, 3] * sy[w] + 0.5)), background)
                node[w] = links[k, np.int64(np.float32(a - b) >= nodes[k, 4])]
        for w in range(nl):
            out[i0 + w // T, w % T] = links[node[w], 2]
    return out


@njit(cache=True, nogil=True)
def grid_pixels(mask, depth, stride, cx, cy, fx, fy):
    """The test pixels of one frame: foreground (mask (H, W) bool, and depth (H, W) uint16 mm
    > 0) on every ``stride``-th row and column, ordered by a fixed hash of their position (so ties between equal votes are
    broken evenly over the hand). Returns u, v (n,) int32, d (n,) float32 mm and their
    camera points xyz (n, 3) float64 mm."""
    H, W = mask.shape
    u = np.empty((H // stride + 1) * (W // stride + 1), np.int32)
    v = np.empty_like(u)
    n = 0
    for y in range(0, H, stride):
        for x in range(0, W, stride):
            u[n], v[n] = x, y
            n += mask[y, x] and depth[y, x] > 0
    h = np.empty(n, np.uint32)
    for i in range(n):
        h[i] = (np.uint32(u[i]) * np.uint32(2654435761)) ^ (np.uint32(v[i]) * np.uint32(40503))
    order = np.argsort(h, kind="mergesort")
    su, sv, d = np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.float32)
    xyz = np.empty((n, 3))
    for r in range(n):
        i = order[r]
        su[r], sv[r] = u[i], v[i]
        d[r] = np.float32(depth[v[i], u[i]])
        xyz[r, 0] = (u[i] - cx) * np.float64(d[r]) / fx
        xyz[r, 1] = (v[i] - cy) * np.float64(d[r]) / fy
        xyz[r, 2] = d[r]
    return su, sv, d, xyz
