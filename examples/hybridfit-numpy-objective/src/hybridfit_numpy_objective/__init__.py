"""Two third-party objectives, both the paper's clamped, confidence-weighted objective:

    E(P, h) = sum_j max_r w_jr (1 - d_jr^2),   d_jr = min(1, ||p_jr - delta_j(h)|| / d_max)

The loss is -E (optimisers minimise). ``clamped-point`` writes the loss of one point as a
numba function (``point_loss``): hybridfit compiles it into its own loops, so it runs as fast
as the built-in ``clamped-confidence``, and ``bind`` comes built from it. ``numpy-clamped``
writes ``bind`` in plain numpy instead: the loss of a frame's hypotheses in a few lines,
slower (one call per frame and generation), no numba needed.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings


class ClampedSettings(Settings):
    d_max_mm: float = Field(40.0, gt=0, description="clamping distance d_max in millimetres")


@nb.njit(cache=True)
def clamped_point(x, y, z, proposals, weights, constants, out):
    """out[i] = -max_r w_r (1 - d_r^2) for the point at (x[i], y[i], z[i]) mm, its proposals
    (K, 3) mm and weights (K,); constants = (1 / d_max^2,)."""
    inv_d_max2 = constants[0]
    out[:] = 0.0
    for r in range(proposals.shape[0]):
        px, py, pz, w = proposals[r, 0], proposals[r, 1], proposals[r, 2], weights[r]
        for i in range(x.shape[0]):
            d2 = min(1.0, ((x[i] - px) ** 2 + (y[i] - py) ** 2 + (z[i] - pz) ** 2) * inv_d_max2)
            out[i] = min(out[i], -w * (1.0 - d2))


class ClampedPoint(Objective):
    """The paper's objective as a per-point numba function; loss = -E in [-Q, 0]."""

    Settings = ClampedSettings

    def point_loss(self):
        return clamped_point, np.array([1.0 / self.settings.d_max_mm**2])

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())


class NumpyClamped(Objective):
    """The paper's objective as a plain numpy ``bind``; loss = -E in [-Q, 0]."""

    Settings = ClampedSettings

    def bind(self, proposals, weights):
        """proposals (Q, K, 3) mm, weights (Q, K) -> loss(points (N, Q, 3) mm, subset (m,)) -> (N,)."""
        inv_d_max2 = 1.0 / self.settings.d_max_mm**2

        def loss(points, subset):
            h = points[:, subset, None, :]                                     # (N, m, 1, 3)
            d2 = np.minimum(1.0, ((h - proposals[subset]) ** 2).sum(-1) * inv_d_max2)  # (N, m, K)
            return -(weights[subset] * (1.0 - d2)).max(axis=-1).sum(axis=-1)

        return loss

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())
