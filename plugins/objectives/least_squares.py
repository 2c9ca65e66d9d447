"""``least-squares``: squared distance to each point's most confident proposal.

    L(h) = sum_j ||delta_j(h) - p_j*||^2  (mm^2),   p_j* = the proposal with the largest weight

The "k = 1" baseline: it ignores every proposal but the top one (ties: the first) and the
confidences' values. A point without proposals (all weights 0) contributes 0.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from hybridfit.objective import Objective


@nb.njit(cache=True, fastmath=True)
def least_squares_point(x, y, z, proposals, weights, constants, out):
    """out[i] = the squared distance (mm^2) of (x[i], y[i], z[i]) to the most confident proposal."""
    top = np.argmax(weights)
    px, py, pz = proposals[top, 0], proposals[top, 1], proposals[top, 2]
    for i in range(x.shape[0]):
        out[i] = (px - x[i]) ** 2 + (py - y[i]) ** 2 + (pz - z[i]) ** 2


class LeastSquares(Objective):
    """Squared distance to the most confident proposal per point (the k = 1 baseline)."""

    def point_loss(self):
        return least_squares_point, np.zeros(0)

    def lower_bound(self, weights):
        return 0.0
