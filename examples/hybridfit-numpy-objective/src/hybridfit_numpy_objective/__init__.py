"""``numpy-clamped``: the paper's clamped, confidence-weighted objective in plain numpy.

    E(P, h) = sum_j max_r w_jr (1 - d_jr^2),   d_jr = min(1, ||p_jr - delta_j(h)|| / d_max)

The loss is -E (optimisers minimise). ``bind`` is the contract: it scores N hypotheses of one
frame. ``score_frames`` is the optional frame-batched capability: the same loss for F frames
x N hypotheses in one call, given only the scored points and their proposals, so hybridfit's
driver scores a whole chunk of frames per generation with one Python call.
``hybridfit.testing`` checks that the two agree.
"""

from __future__ import annotations

import threading

import numpy as np
from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings


class NumpyClampedSettings(Settings):
    d_max_mm: float = Field(40.0, gt=0, description="clamping distance d_max in millimetres")


#: elements of :func:`clamped_loss`'s scratch array (at most, or one hypothesis's): 1 MiB, so it
#: stays in a core's second-level cache beside the points
SCRATCH_ELEMENTS = 1 << 17

_kept = threading.local()  # each thread's buffers: the driver may score chunks of frames on threads


def kept(name: str, size: int) -> np.ndarray:
    """This thread's float64 buffer ``name`` (size,), uninitialised, kept from call to call and
    starting on a cache line (64 bytes): numpy's arrays start 16 or 32 bytes into one, and the
    loops that write a megabyte scratch so placed took about a fifth longer (measured:
    hybridfit's ``docs/results.md``)."""
    buffer = getattr(_kept, name, None)
    if buffer is None or buffer.size < size:
        raw = np.empty(size + 8)
        start = (-raw.ctypes.data % 64) // 8
        buffer = raw[start:start + size]
        setattr(_kept, name, buffer)
    return buffer[:size]


def clamped_loss(points, proposals, weights, d_max_mm):
    """points (F, N, m, 3) mm, proposals (F, m, K, 3) mm, weights (F, m, K) of the same m points
    -> (F, N) losses -E over those points.

    Every proposal at once, in one (F, n, m, K, 3) scratch array laid out frames innermost (then
    the points, hypotheses, proposals, coordinates), so each of the few numpy calls runs
    contiguous loops over (points, frames) blocks, the arguments broadcast along them:
    w (1 - d^2) = w - (w / d_max^2) ||p - h||^2, and the clamp at 0 is the maximum's initial
    value. Few calls matter as much as few passes (a stage that moves one finger scores a few
    thousand points per call); a large batch goes through in nearly equal runs of hypotheses
    whose scratch fits :data:`SCRATCH_ELEMENTS`. The scratch is the thread's, kept between calls
    (:func:`kept`)."""
    F, N, m, K = points.shape[0], points.shape[1], points.shape[2], proposals.shape[2]
    step = -(-N // -(-3 * K * F * N * m // SCRATCH_ELEMENTS))  # hypotheses per run
    scratch = kept("scratch", 3 * K * step * m * F).reshape(3, K, step, m, F).transpose(4, 2, 3, 1, 0)
    best = kept("best", N * m * F).reshape(N, m, F).transpose(2, 0, 1)  # (F, N, m), frames innermost
    ws = weights[:, None] / d_max_mm**2
    for a in range(0, N, step):
        h = points[:, a:a + step, :, None, :]
        diff = scratch[:, :h.shape[1]]
        np.subtract(h, proposals[:, None], out=diff)
        np.square(diff, out=diff)
        d2 = np.add(diff[..., 0], diff[..., 1], out=diff[..., 0])  # (F, n, m, K), in place
        d2 += diff[..., 2]
        d2 *= ws
        np.subtract(weights[:, None], d2, out=d2)
        np.maximum.reduce(d2, axis=-1, initial=0.0, out=best[:, a:a + step])
    return -best.sum(axis=-1)


def bound_clamped_loss(proposals, weights, d_max_mm):
    """loss(points (N, Q, 3), subset (m,)) -> (N,) of one frame, in a few numpy calls (for small
    batches the cost is per call, not per element).

    With ws = w / d_max^2, each term -w (1 - d^2 / d_max^2) = ws ||h||^2 - 2 ws p.h + ws ||p||^2 - w
    is linear in (x, y, z, x^2, y^2, z^2, 1) of the point h: one batched matmul of the
    frame's coefficients A (m, K, 7), made once per point set, with those rows (m, 7, N)
    scores every proposal of every point; the minimum's initial 0 is the clamp. The expansion
    rounds differently from the difference form (its terms cancel to within a few ulps of
    ws ||h||^2)."""
    scale = 1.0 / d_max_mm**2
    cut = {}

    def loss(points, subset):
        n = points.shape[0]
        key = (subset.tobytes(), n)
        if key not in cut:
            p, w = proposals[subset], weights[subset]  # (m, K, 3), (m, K)
            ws = (w * scale)[..., None]
            A = np.concatenate([-2.0 * ws * p, np.repeat(ws, 3, axis=-1), ws * (p * p).sum(-1, keepdims=True)
                                - w[..., None]], axis=-1)
            cut[key] = (np.ascontiguousarray(A), np.ones((len(subset), 1, n)))
        A, ones = cut[key]
        h = points.transpose(1, 2, 0)[subset]  # (m, 3, N); a copy, the hypothesis innermost
        terms = np.matmul(A, np.concatenate((h, h * h, ones), axis=1))  # (m, K, N)
        return np.add.reduce(np.minimum.reduce(terms, axis=1, initial=0.0), axis=0)

    return loss


class NumpyClamped(Objective):
    """The paper's objective, numpy only; loss = -E in [-Q, 0]."""

    Settings = NumpyClampedSettings

    def bind(self, proposals, weights):
        return bound_clamped_loss(np.asarray(proposals, float), np.asarray(weights, float), self.settings.d_max_mm)

    def score_frames(self, points, subset, proposals, weights):
        """points (F, N, m, 3), proposals (F, m, K, 3), weights (F, m, K) of the points
        ``subset`` -> (F, N)."""
        return clamped_loss(points, proposals, weights, self.settings.d_max_mm)

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())
