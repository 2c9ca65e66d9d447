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

from hybridfit.objective import Objective, kernel_loss
from hybridfit.plugin import Settings


class GaussianMixtureSettings(Settings):
    sigma_mm: float = Field(15.0, gt=0, description="standard deviation of every mixture component, mm")


@nb.njit(cache=True, fastmath=False)
def gaussian_mixture_loss(points, subset, proposals, weights, sigma):
    """points (N, Q, 3), subset (m,), proposals (Q, K, 3), weights (Q, K) -> (N,) NLL."""
    N = points.shape[0]
    K = proposals.shape[1]
    inv_two_var = 0.5 / (sigma * sigma)
    log_norm = 1.5 * math.log(2.0 * math.pi * sigma * sigma)
    d2 = np.empty(K)
    out = np.empty(N)
    for n in range(N):
        total = 0.0
        for jj in range(subset.shape[0]):
            j = subset[jj]
            smallest = np.inf
            for r in range(K):
                if weights[j, r] > 0.0:
                    dx = proposals[j, r, 0] - points[n, j, 0]
                    dy = proposals[j, r, 1] - points[n, j, 1]
                    dz = proposals[j, r, 2] - points[n, j, 2]
                    d2[r] = dx * dx + dy * dy + dz * dz
                    if d2[r] < smallest:
                        smallest = d2[r]
            if smallest == np.inf:  # no proposals (or none at a finite distance)
                continue
            s = 0.0
            for r in range(K):
                if weights[j, r] > 0.0:
                    s += weights[j, r] * math.exp(-(d2[r] - smallest) * inv_two_var)
            total += smallest * inv_two_var - math.log(s) + log_norm
        out[n] = total
    return out


class GaussianMixture(Objective):
    """Smooth negative log-likelihood of a per-point Gaussian mixture of the proposals."""

    Settings = GaussianMixtureSettings

    def bind(self, proposals, weights):
        return kernel_loss(gaussian_mixture_loss, np.ascontiguousarray(proposals, dtype=np.float64),
                           np.ascontiguousarray(weights, dtype=np.float64), float(self.settings.sigma_mm))

    def lower_bound(self, weights):
        # a mixture's density never exceeds its components' peak density (2 pi sigma^2)^-1.5
        with_proposals = int((np.asarray(weights) > 0).any(axis=-1).sum())
        return with_proposals * 1.5 * math.log(2.0 * math.pi * self.settings.sigma_mm**2)
