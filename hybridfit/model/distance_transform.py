"""Exact Euclidean distance transform of a 2-D mask, compiled with numba: a drop-in for
``scipy.ndimage.distance_transform_edt(~mask)``, bit for bit and several times faster. Squared
distances are exact int64, by the separable algorithm of P. Felzenszwalb, D. Huttenlocher,
"Distance Transforms of Sampled Functions", Theory of Computing 8, 2012 (columns, then the lower
envelope of parabolas along rows); the square root is taken last, in float64."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def _distances(mask):
    """(h, w) float64 distance to the nearest True pixel of mask (h, w) bool, C-contiguous."""
    h, w = mask.shape
    out = np.empty((h, w), np.float64)
    if not mask.any():  # as scipy: its feature transform points every pixel at (-1, 0)
        for i in range(h):
            for q in range(w):
                out[i, q] = np.sqrt(np.float64((i + 1) ** 2 + q * q))
        return out
    # Columns: the 1-D transform of a 0 / infinity function is the distance to the nearest
    # True pixel of the column (two sweeps, along contiguous rows); h means there is none.
    g = np.empty((h, w), np.int64)
    for q in range(w):
        g[0, q] = 0 if mask[0, q] else h
    for i in range(1, h):
        for q in range(w):
            g[i, q] = 0 if mask[i, q] else min(g[i - 1, q] + 1, h)
    for i in range(h - 2, -1, -1):
        for q in range(w):
            g[i, q] = min(g[i, q], g[i + 1, q] + 1)
    # Rows: min over sites p of g[p]^2 + (q - p)^2, parabola p written as F[p] - 2 q p + q^2.
    v = np.empty(w, np.int64)  # the lower envelope's sites, left to right
    F = np.empty(w, np.int64)  # their g[p]^2 + p^2
    for i in range(h):
        k = -1
        for q in range(w):
            if g[i, q] == h:
                continue
            Fq = g[i, q] ** 2 + q * q
            # drop the top site while q's parabola meets it no later than it meets the one below
            while k > 0 and (Fq - F[k]) * (v[k] - v[k - 1]) <= (F[k] - F[k - 1]) * (q - v[k]):
                k -= 1
            k += 1
            v[k] = q
            F[k] = Fq
        j = 0
        for q in range(w):
            while j < k and F[j + 1] - F[j] <= 2 * q * (v[j + 1] - v[j]):
                j += 1
            out[i, q] = F[j] - 2 * q * v[j] + q * q  # exact: below 2^53
        for q in range(w):
            out[i, q] = np.sqrt(out[i, q])
    return out


def distance_transform(mask: np.ndarray) -> np.ndarray:
    """Distance (pixels) from each pixel to the nearest True pixel of ``mask`` (h, w) bool.

    Returns (h, w) float64, 0 on the mask: exactly ``scipy.ndimage.distance_transform_edt(~mask)``.
    A mask without any True pixel gives, as scipy does, sqrt((i + 1)^2 + j^2) at pixel (i, j)
    (the distance to a virtual pixel (-1, 0)). Any memory layout is accepted (copied to C order)."""
    mask = np.ascontiguousarray(mask)
    if mask.dtype != np.bool_ or mask.ndim != 2:
        raise ValueError(f"distance_transform takes a 2-D bool mask, not a {mask.ndim}-D {mask.dtype} array")
    return _distances(mask)
