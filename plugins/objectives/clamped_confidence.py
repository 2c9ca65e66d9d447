"""``clamped-confidence``: the paper's objective (Poier et al. 2015, Eq. 1).

    E(P, h) = sum_j max_r w_jr (1 - d_jr^2),   d_jr = min(1, ||p_jr - delta_j(h)|| / d_max)

w_jr are the confidences normalised per joint (they sum to 1, or are all 0 for a joint
without proposals, which then contributes nothing). E lies in [0, J]; optimisers minimise,
so the loss returned is -E, in [-J, 0].

d_max (the clamping distance) is not given in the paper. The default, 40 mm, was chosen on
synthetic proposals (``studies/d_max.toml``; figures: the docs' results page): about
twice the typical proposal error and half a finger's length, so a proposal on a neighbouring
finger still pulls while outliers further than d_max are ignored.

Its fast form is one per-point function (``point_loss``), which hybridfit compiles into
its loops; ``bind`` comes from it.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings


class ClampedConfidenceSettings(Settings):
    d_max_mm: float = Field(40.0, gt=0, description="clamping distance d_max in millimetres")


@nb.njit(cache=True, fastmath=True)
def clamped_confidence_point(x, y, z, proposals, weights, constants, out):
    """out[i] = -max_r w_r max(0, 1 - d_r^2 / d_max^2) for one point at (x[i], y[i], z[i]) mm,
    its proposals (K, 3) mm and weights (K,); constants: (1 / d_max^2,). Computed as the
    minimum over the proposals of w_r (d_r^2 / d_max^2 - 1), starting at 0 (the clamp)."""
    scale = constants[0]
    out[:] = 0.0
    for r in range(proposals.shape[0]):
        px, py, pz, w = proposals[r, 0], proposals[r, 1], proposals[r, 2], weights[r]
        for i in range(x.shape[0]):
            d2 = ((px - x[i]) ** 2 + (py - y[i]) ** 2 + (pz - z[i]) ** 2) * scale
            out[i] = min(out[i], w * (d2 - 1.0))


class ClampedConfidence(Objective):
    """The paper's clamped, confidence-weighted objective; loss = -E in [-J, 0]."""

    Settings = ClampedConfidenceSettings

    def point_loss(self):
        return clamped_confidence_point, np.array([1.0 / self.settings.d_max_mm**2])

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())
