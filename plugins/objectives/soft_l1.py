"""``soft-l1``: a robust, confidence-weighted distance to every proposal within reach.

    L(h) = sum_j sum_r w_jr rho(min(d_jr, reach)^2 / s^2),   rho(u) = 2 (sqrt(1 + u) - 1)

d_jr = ||p_jr - delta_j(h)|| in mm, w_jr the confidences normalised per point. rho is soft-L1:
quadratic below the scale s (``scale_mm``), linear above, so one wrong proposal cannot drag a
point far; a proposal further than ``reach_mm`` adds a constant (another mode: it does not
pull). Where several proposals agree, a point settles at their robust weighted mean: a fusion
of the proposals, not a choice of one. A point without proposals contributes 0.

It is the loss of the local stage of the default objective ``clamped-then-soft-l1``; alone it
suits a local optimiser started near the answer (its flat far field gives a global search
little to go on). Defaults (5 mm, 60 mm) were chosen on tuning data (synthetic seeds 11, 12
and stress seed 31: the docs' results page).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings


class SoftL1Settings(Settings):
    scale_mm: float = Field(5.0, gt=0, description="s: quadratic below, linear above this distance (mm)")
    reach_mm: float = Field(60.0, gt=0, description="a proposal further than this (mm) adds a constant: it does not pull")


@nb.njit(cache=True, fastmath=True)
def soft_l1_point(x, y, z, proposals, weights, constants, out):
    """out[i] = sum_r w_r rho(min(d_r^2, reach^2) / s^2) for one point at (x[i], y[i], z[i]) mm;
    constants: (1 / s^2, reach^2 in mm^2)."""
    scale, reach2 = constants[0], constants[1]
    out[:] = 0.0
    for r in range(proposals.shape[0]):
        px, py, pz, w = proposals[r, 0], proposals[r, 1], proposals[r, 2], weights[r]
        if w > 0.0:
            for i in range(x.shape[0]):
                d2 = min((px - x[i]) ** 2 + (py - y[i]) ** 2 + (pz - z[i]) ** 2, reach2)
                out[i] += w * 2.0 * (np.sqrt(1.0 + d2 * scale) - 1.0)


class SoftL1(Objective):
    """Robust (soft-L1) confidence-weighted distance to the proposals within reach: a fusion."""

    Settings = SoftL1Settings

    def point_loss(self):
        s = self.settings
        return soft_l1_point, np.array([1.0 / s.scale_mm**2, s.reach_mm**2])

    def lower_bound(self, weights):
        return 0.0
