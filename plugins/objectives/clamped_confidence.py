"""``clamped-confidence``: the paper's objective (Poier et al. 2015, Eq. 1).

    E(P, h) = sum_j max_r w_jr (1 - d_jr^2),   d_jr = min(1, ||p_jr - delta_j(h)|| / d_max)

w_jr are the confidences normalised per joint (they sum to 1, or are all 0 for a joint
without proposals, which then contributes nothing). E lies in [0, J]; optimisers minimise,
so the loss returned is -E, in [-J, 0].

d_max (the clamping distance) is not given in the paper. The default, 40 mm, was chosen on
synthetic proposals (``benchmarks/bench_dmax.py``; figures: the docs' results page): about
twice the typical proposal error and half a finger's length, so a proposal on a neighbouring
finger still pulls while outliers further than d_max are ignored.

Offers a compiled kernel (``compiled_kernel``), which ``bind`` itself runs, and a compiled
frames kernel (``compiled_frames_kernel``, many frames in one call); the three share one
loop (``_score_columns``), so they agree by construction.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.objective import FRAMES_KERNEL_SIGNATURE, KERNEL_SIGNATURE, Objective, kernel_loss
from hybridfit.plugin import Settings


class ClampedConfidenceSettings(Settings):
    d_max_mm: float = Field(40.0, gt=0, description="clamping distance d_max in millimetres")


@nb.njit(cache=True, fastmath=True, inline="always")
def _score_columns(points, subset, proposals, weights, inv_d_max_sq, first, out):
    """out (n,) = -E of the hypotheses in columns first, ..., first + n - 1 of points (Q, 3,
    C) mm over the subset's points, against one frame's proposals (Q, K, 3) and weights (Q, K)."""
    N = out.shape[0]
    K = proposals.shape[1]
    for n in range(N):
        out[n] = 0.0
    if K <= 3:  # up to three proposals per point: one loop per point (a short swarm pays per loop)
        for jj in range(subset.shape[0]):
            j = subset[jj]
            x, y, z = points[j, 0, first:first + N], points[j, 1, first:first + N], points[j, 2, first:first + N]
            # a missing proposal weighs 0 and so gives 0, as a weight of 0 does
            w0 = weights[j, 0] if K > 0 else 0.0
            w1 = weights[j, 1] if K > 1 else 0.0
            w2 = weights[j, 2] if K > 2 else 0.0
            r0, r1, r2 = 0, min(1, K - 1), min(2, K - 1)
            ax, ay, az = proposals[j, r0, 0], proposals[j, r0, 1], proposals[j, r0, 2]
            bx, by, bz = proposals[j, r1, 0], proposals[j, r1, 1], proposals[j, r1, 2]
            cx, cy, cz = proposals[j, r2, 0], proposals[j, r2, 1], proposals[j, r2, 2]
            for n in range(N):
                xn, yn, zn = x[n], y[n], z[n]
                da = ((ax - xn) ** 2 + (ay - yn) ** 2 + (az - zn) ** 2) * inv_d_max_sq
                db = ((bx - xn) ** 2 + (by - yn) ** 2 + (bz - zn) ** 2) * inv_d_max_sq
                dc = ((cx - xn) ** 2 + (cy - yn) ** 2 + (cz - zn) ** 2) * inv_d_max_sq
                best = max(w0 * max(1.0 - da, 0.0), w1 * max(1.0 - db, 0.0))
                out[n] -= max(best, w2 * max(1.0 - dc, 0.0))
        return
    best = np.empty(N)
    for jj in range(subset.shape[0]):  # hypotheses innermost and contiguous: the loops vectorise
        j = subset[jj]
        x, y, z = points[j, 0, first:first + N], points[j, 1, first:first + N], points[j, 2, first:first + N]
        for n in range(N):
            best[n] = 0.0
        for r in range(K):  # branch-free: a weight of 0 or a distance beyond d_max gives 0
            w = weights[j, r]
            px, py, pz = proposals[j, r, 0], proposals[j, r, 1], proposals[j, r, 2]
            for n in range(N):
                dx = px - x[n]
                dy = py - y[n]
                dz = pz - z[n]
                d2 = (dx * dx + dy * dy + dz * dz) * inv_d_max_sq
                best[n] = max(best[n], w * max(1.0 - d2, 0.0))
        for n in range(N):
            out[n] -= best[n]


@nb.njit(KERNEL_SIGNATURE, cache=True, fastmath=True)
def clamped_confidence_kernel(points, subset, proposals, weights, consts, out):
    """points (Q, 3, N) mm (the hypothesis innermost), subset (m,), proposals (Q, K, 3),
    weights (Q, K), consts (1/d_max^2,) -> out (n,) -E of the first n hypotheses over the
    subset's points."""
    _score_columns(points, subset, proposals, weights, consts[0], 0, out)


@nb.njit(FRAMES_KERNEL_SIGNATURE, cache=True, fastmath=True)
def clamped_confidence_frames_kernel(points, subset, proposals, weights, consts, f0, f1, n, out):
    """points (Q, 3, C) mm, frame f's hypothesis i in column (f - f0) n + i, subset (m,),
    proposals (F, Q, K, 3), weights (F, Q, K), consts (1/d_max^2,) -> out[f, :n] for f0 <= f < f1:
    the kernel's losses, frame by frame in one call."""
    for f in range(f0, f1):
        _score_columns(points, subset, proposals[f], weights[f], consts[0], (f - f0) * n, out[f, :n])


@nb.njit(cache=True)
def clamped_confidence_loss(points, subset, proposals, weights, consts):
    """points (N, Q, 3), subset (m,), proposals (Q, K, 3), weights (Q, K) -> (N,) -E."""
    N, Q = points.shape[0], points.shape[1]
    transposed = np.empty((Q, 3, N))
    for jj in range(subset.shape[0]):
        j = subset[jj]
        for c in range(3):
            for n in range(N):
                transposed[j, c, n] = points[n, j, c]
    out = np.empty(N)
    clamped_confidence_kernel(transposed, subset, proposals, weights, consts, out)
    return out


class ClampedConfidence(Objective):
    """The paper's clamped, confidence-weighted objective; loss = -E in [-J, 0]."""

    Settings = ClampedConfidenceSettings

    def bind(self, proposals, weights):
        return kernel_loss(clamped_confidence_loss, np.ascontiguousarray(proposals, dtype=np.float64),
                           np.ascontiguousarray(weights, dtype=np.float64), *self.compiled_kernel()[1:])

    def compiled_kernel(self):
        return clamped_confidence_kernel, np.array([1.0 / self.settings.d_max_mm**2])

    def compiled_frames_kernel(self):
        return clamped_confidence_frames_kernel, np.array([1.0 / self.settings.d_max_mm**2])

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())
