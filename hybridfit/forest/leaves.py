"""What a leaf stores: per joint, the few strongest mean-shift modes of the offsets (mm)
from its samples' points to the joint (Shotton et al. 2013)."""

from __future__ import annotations

import numpy as np
from numba import njit

from .meanshift import mean_shift


@njit(cache=True, nogil=True)
def leaf_modes(idx, leaf_start, leaf_end, s_frame, xyz, joints, max_len, bandwidth, n_modes, max_samples):
    """Per leaf and joint the strongest offset modes: offsets (L, J, M, 3) float32 mm and
    weights (L, J, M) float32 = share of the leaf's (sub-sampled) samples in the mode's basin."""
    L, J = leaf_start.shape[0], joints.shape[1]
    offsets = np.zeros((L, J, n_modes, 3), np.float32)
    weights = np.zeros((L, J, n_modes), np.float32)
    pts = np.empty((max_samples, 3))
    for leaf in range(L):
        n = min(leaf_end[leaf] - leaf_start[leaf], max_samples)
        for j in range(J):
            m = 0
            for i in range(n):
                r = idx[leaf_start[leaf] + i]
                o0 = joints[s_frame[r], j, 0] - xyz[r, 0]
                o1 = joints[s_frame[r], j, 1] - xyz[r, 1]
                o2 = joints[s_frame[r], j, 2] - xyz[r, 2]
                if o0 * o0 + o1 * o1 + o2 * o2 <= max_len * max_len:
                    pts[m, 0], pts[m, 1], pts[m, 2] = o0, o1, o2
                    m += 1
            if m == 0:
                continue
            modes, support = mean_shift(pts[:m].copy(), np.ones(m), bandwidth)
            for q in range(min(n_modes, modes.shape[0])):
                offsets[leaf, j, q] = modes[q]
                weights[leaf, j, q] = support[q] / n
    return offsets, weights
