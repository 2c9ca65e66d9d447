"""Weighted mean-shift (Comaniciu & Meer 2002) with a Gaussian kernel, as a numba kernel.

Used twice: at the leaves on training offsets, and at test time on the votes for a joint.
Seeding by bins (as scikit-learn's ``bin_seeding``): the points are binned on a grid of
cell size ``2 * bandwidth`` and each occupied cell's weighted centroid seeds one search, the
heaviest cells first (ties: by cell position); a search stops as soon as it comes within
``bandwidth / 2`` of a mode already found. The kernel is cut at 2 sigma. The support of a
mode is the number of points whose nearest mode it is (the number of votes supporting it).
Every sum runs over the points in index order, so a result depends only on its input.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _near(modes, m, x0, x1, x2, r2):
    for q in range(m):
        d0, d1, d2 = x0 - modes[q, 0], x1 - modes[q, 1], x2 - modes[q, 2]
        if d0 * d0 + d1 * d1 + d2 * d2 < r2:
            return q
    return -1


@njit(cache=True, nogil=True)
def mean_shift(points, weights, bandwidth, max_iter=30, tol=0.1):
    """Modes of a weighted 3D point set.

    points: (n, 3) float64 mm; weights: (n,) float64 >= 0; bandwidth: Gaussian sigma, mm;
    a search stops when a shift is below ``tol * bandwidth`` or after ``max_iter`` shifts.
    Returns modes (m, 3) float64 and support (m,) int64 (points per mode), sorted by
    descending support (ties: the mode found first). m = 0 when n = 0.
    """
    n = points.shape[0]
    if n == 0:
        return np.empty((0, 3)), np.zeros(0, np.int64)
    # bin seeding: one seed per occupied cell, the heaviest cells first
    cell = 2.0 * bandwidth
    keys = np.empty(n, np.int64)
    for i in range(n):
        a = np.int64(np.floor(points[i, 0] / cell)) + 1048576
        b = np.int64(np.floor(points[i, 1] / cell)) + 1048576
        c = np.int64(np.floor(points[i, 2] / cell)) + 1048576
        keys[i] = (a << 42) | (b << 21) | c
    size = 1 << max(4, int(np.ceil(np.log2(2 * n))))  # open-addressing table: cell key -> seed
    table = np.full(size, -1, np.int64)
    cell_keys = np.empty(n, np.int64)
    seeds = np.zeros((n, 3))
    mass = np.zeros(n)
    S = 0
    for i in range(n):  # each cell sums its points in index order
        h = (np.uint64(keys[i]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)
        s = -1
        while s < 0:
            h &= np.uint64(size - 1)
            if table[h] < 0:
                table[h] = S
                cell_keys[S] = keys[i]
                S += 1
            if cell_keys[table[h]] == keys[i]:
                s = table[h]
            h += np.uint64(1)
        w = weights[i] + 1e-12
        seeds[s, 0] += w * points[i, 0]
        seeds[s, 1] += w * points[i, 1]
        seeds[s, 2] += w * points[i, 2]
        mass[s] += w
    by_cell = np.argsort(cell_keys[:S])
    visit = by_cell[np.argsort(-mass[by_cell], kind="mergesort")]  # heaviest first, ties by cell key
    inv2s2 = 0.5 / (bandwidth * bandwidth)
    cutoff2 = 4.0 * bandwidth * bandwidth  # the kernel is cut at 2 sigma
    merge2 = 0.25 * bandwidth * bandwidth
    tol2 = (tol * bandwidth) ** 2
    px, py, pz = points[:, 0].copy(), points[:, 1].copy(), points[:, 2].copy()  # SIMD-friendly layout
    r2 = np.empty(n)
    near = np.empty(n, np.int64)
    modes = np.empty((S, 3))
    m = 0
    for s in visit:
        x0, x1, x2 = seeds[s, 0] / mass[s], seeds[s, 1] / mass[s], seeds[s, 2] / mass[s]
        hit = -1
        for _ in range(max_iter):
            hit = _near(modes, m, x0, x1, x2, merge2)
            if hit >= 0:
                break
            for p in range(n):  # branch-free: distances, then the points inside the cutoff in index order
                d0, d1, d2 = px[p] - x0, py[p] - x1, pz[p] - x2
                r2[p] = d0 * d0 + d1 * d1 + d2 * d2
            k = 0
            for p in range(n):
                near[k] = p
                k += r2[p] < cutoff2
            s0 = s1 = s2 = sw = 0.0
            for q in range(k):
                p = near[q]
                w = weights[p] * np.exp(-r2[p] * inv2s2)
                s0 += w * px[p]
                s1 += w * py[p]
                s2 += w * pz[p]
                sw += w
            if sw <= 0.0:
                break
            y0, y1, y2 = s0 / sw, s1 / sw, s2 / sw
            step = (y0 - x0) ** 2 + (y1 - x1) ** 2 + (y2 - x2) ** 2
            x0, x1, x2 = y0, y1, y2
            if step < tol2:
                break
        if hit < 0:
            hit = _near(modes, m, x0, x1, x2, merge2)
        if hit < 0:
            modes[m, 0], modes[m, 1], modes[m, 2] = x0, x1, x2
            m += 1
    support = np.zeros(m, np.int64)
    for p in range(n):  # each point supports its nearest mode
        best, best_d = 0, np.inf
        for q in range(m):
            d0, d1, d2 = points[p, 0] - modes[q, 0], points[p, 1] - modes[q, 1], points[p, 2] - modes[q, 2]
            d = d0 * d0 + d1 * d1 + d2 * d2
            if d < best_d:
                best, best_d = q, d
        support[best] += 1
    rank = np.argsort(-support, kind="mergesort")
    return modes[:m][rank], support[rank]
