"""``gaussian-mixture``: the negative log-likelihood of a Gaussian mixture per point.

Each point's proposals and normalised confidences define an isotropic Gaussian mixture
(standard deviation ``sigma_mm`` for every component); the loss of a hypothesis is

    L(h) = sum_j -log sum_r w_jr N(delta_j(h); p_jr, sigma^2 I)

in nats, densities per mm^3. It is smooth everywhere (unlike the paper's clamped
objective), so gradient methods can use it, but it is not robust: a point far from all of
its proposals costs about d^2 / (2 sigma^2). A point without proposals (all weights 0)
contributes 0. Evaluated stably: the smallest squared distance is factored out of the
log-sum-exp, so far points never underflow to log(0).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings


class GaussianMixtureSettings(Settings):
    sigma_mm: float = Field(15.0, gt=0, description="standard deviation of every mixture component, mm")


@nb.njit(cache=True)
def gaussian_mixture_point(x, y, z, proposals, weights, constants, out):
    """out[i] = -log sum_r w_r N((x[i], y[i], z[i]); p_r, sigma^2 I) for one point, its proposals
    (K, 3) mm and weights (K,); constants: (sigma mm,)."""
    sigma = constants[0]
    inv_two_var = 0.5 / (sigma * sigma)
    log_norm = 1.5 * math.log(2.0 * math.pi * sigma * sigma)
    K = proposals.shape[0]
    for i in range(x.shape[0]):
        smallest = np.inf
        for r in range(K):
            if weights[r] > 0.0:
                smallest = min(smallest, (proposals[r, 0] - x[i]) ** 2 + (proposals[r, 1] - y[i]) ** 2
                               + (proposals[r, 2] - z[i]) ** 2)
        s = 0.0
        for r in range(K):
            if weights[r] > 0.0:
                d2 = (proposals[r, 0] - x[i]) ** 2 + (proposals[r, 1] - y[i]) ** 2 + (proposals[r, 2] - z[i]) ** 2
                s += weights[r] * math.exp(-(d2 - smallest) * inv_two_var)
        out[i] = smallest * inv_two_var - math.log(s) + log_norm


class GaussianMixture(Objective):
    """Smooth negative log-likelihood of a per-point Gaussian mixture of the proposals."""

    Settings = GaussianMixtureSettings

    def point_loss(self):
        return gaussian_mixture_point, np.array([float(self.settings.sigma_mm)])

    def lower_bound(self, weights):
        # a mixture's density never exceeds its components' peak density (2 pi sigma^2)^-1.5
        with_proposals = int((np.asarray(weights) > 0).any(axis=-1).sum())
        return with_proposals * 1.5 * math.log(2.0 * math.pi * self.settings.sigma_mm**2)
