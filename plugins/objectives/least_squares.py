"""``least-squares``: squared distance to each point's most confident proposal.

    L(h) = sum_j ||delta_j(h) - p_j*||^2  (mm^2),   p_j* = the proposal with the largest weight

The "k = 1" baseline: it ignores every proposal but the top one (ties: the first) and the
confidences' values. A point without proposals (all weights 0) contributes 0.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from hybridfit.objective import Objective, kernel_loss


@nb.njit(cache=True, fastmath=True)
def least_squares_loss(points, subset, targets, active):
    """points (N, Q, 3), subset (m,), targets (Q, 3), active (Q,) bool -> (N,) sum of d^2."""
    N = points.shape[0]
    out = np.empty(N)
    for n in range(N):
        total = 0.0
        for jj in range(subset.shape[0]):
            j = subset[jj]
            if active[j]:
                dx = targets[j, 0] - points[n, j, 0]
                dy = targets[j, 1] - points[n, j, 1]
                dz = targets[j, 2] - points[n, j, 2]
                total += dx * dx + dy * dy + dz * dz
        out[n] = total
    return out


class LeastSquares(Objective):
    """Squared distance to the most confident proposal per point (the k = 1 baseline)."""

    def bind(self, proposals, weights):
        proposals = np.asarray(proposals, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64)
        top = weights.argmax(axis=-1)
        targets = np.ascontiguousarray(proposals[np.arange(len(top)), top])
        return kernel_loss(least_squares_loss, targets, np.ascontiguousarray(weights.max(axis=-1) > 0))

    def lower_bound(self, weights):
        return 0.0
