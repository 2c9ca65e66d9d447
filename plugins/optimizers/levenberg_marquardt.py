"""``levenberg-marquardt``: a local, gradient-based step on any objective with a per-point loss.

Projected Levenberg-Marquardt (Levenberg 1944, Marquardt 1963) on the objective in force:
each row it asks is scored with its loss, gradient g (d,) and Gauss-Newton curvature A (d, d),
which the driver computes through the kinematic tree's Jacobian and the objective's
``point_loss`` (:mod:`hybridfit.fitting.derivatives`; a row costs d + 1 evaluations). The
first row is the start; every later row is the step from the best pose so far,

    (A + lambda diag(A)) delta = -g,

with the parameters at a bound that the gradient pushes out held there, and the step clipped
to the box. A step that lowers the loss is taken and lambda shrinks (/3); one that does not is
refused and lambda grows (x10). So no row is worse than the start for the loss, and the stage
spends its budget in whole rows (``budget // (d + 1)`` of them, whatever the frame: a frame's
count of evaluations does not depend on the frames beside it). A frame has converged once a
taken step gains less than ``tolerance`` (relative) or lambda passes ``1e4`` after a refusal:
it then asks its best pose again (the driver does not compute a row it has just computed).

Written as numba-compiled :class:`~hybridfit.task.DerivativeSteps` (a frame axis first): the
driver runs it for many frames in lockstep. It draws no random numbers.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.optimizer import DerivativeSteps, Optimizer, Task
from hybridfit.plugin import Settings


class LevenbergMarquardtSettings(Settings):
    damping: float = Field(1e-3, gt=0, description="lambda at the start, relative to the curvature's diagonal")
    shrink: float = Field(3.0, gt=1, description="lambda is divided by this after a step that lowers the loss")
    grow: float = Field(10.0, gt=1, description="lambda is multiplied by this after a refused step")
    tolerance: float = Field(1e-4, ge=0, description="converged when a taken step lowers the loss by less than this "
                             "times (1 + |loss|)")


#: columns of the settings array (:meth:`LevenbergMarquardt.batch_settings`)
DAMPING, SHRINK, GROW, TOLERANCE = range(4)
#: lambda stays within these
MIN_DAMPING, MAX_DAMPING = 1e-9, 1e12
#: a refusal that takes lambda past this ends a frame's steps (they would no longer move it)
HOLD_DAMPING = 1e4


@nb.njit(cache=True, nogil=True)
def lm_init(start, lower, upper, keys, budget, settings):
    """The state of F frames: the best pose x (F, d) with its loss, gradient and curvature,
    lambda (F,), the bounds, and whether the start has been scored."""
    F, d = start.shape
    return (start.copy(), np.full(F, np.inf), np.zeros((F, d)), np.zeros((F, d, d)), np.full(F, settings[DAMPING]),
            lower.copy(), upper.copy(), np.zeros(1, dtype=np.int64), settings.copy(), np.empty((F, 1, d)),
            np.empty((d, d)), np.empty((d, d)), np.empty(d), np.zeros(F, dtype=np.bool_))


@nb.njit(cache=True, nogil=True)
def cholesky_solve(A, b, L, out):
    """out = A^-1 b for a symmetric positive definite A (D, D), L scratch (D, D); False when
    A is not positive definite."""
    D = A.shape[0]
    for i in range(D):
        for j in range(i + 1):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            if i == j:
                if s <= 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    for i in range(D):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * out[k]
        out[i] = s / L[i, i]
    for i in range(D - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, D):
            s -= L[k, i] * out[k]
        out[i] = s / L[i, i]
    return True


@nb.njit(cache=True, nogil=True)
def lm_ask(state, m):
    """(F, 1, d): the start (first call), then each frame's damped step from its best pose (its
    best pose itself once it has converged)."""
    x, _, g, A, lam, lower, upper, scored, _, X, M, L, delta, done = state
    F, d = x.shape
    if scored[0] == 0:
        X[:, 0, :] = x
        return X
    rhs = np.empty(d)
    held = np.empty(d, dtype=np.bool_)
    for f in range(F):
        if done[f]:
            X[f, 0, :] = x[f]
            continue
        top = 0.0
        for k in range(d):
            top = max(top, A[f, k, k])
        floor = 1e-12 * top + 1e-300
        for k in range(d):  # a parameter at a bound that the gradient pushes out stays there
            held[k] = (x[f, k] <= lower[f, k] and g[f, k] > 0.0) or (x[f, k] >= upper[f, k] and g[f, k] < 0.0)
            rhs[k] = 0.0 if held[k] else -g[f, k]
            for j in range(k + 1):
                M[k, j] = 0.0 if held[k] or held[j] else A[f, k, j]
            M[k, k] = 1.0 if held[k] else A[f, k, k] + lam[f] * max(A[f, k, k], floor) + floor
        ok = cholesky_solve(M, rhs, L, delta)
        for k in range(d):
            X[f, 0, k] = min(max(x[f, k] + (delta[k] if ok else 0.0), lower[f, k]), upper[f, k])
    return X


@nb.njit(cache=True, nogil=True)
def lm_tell(state, X, losses, gradients, curvatures):
    """Take each frame's row if it lowers the loss (lambda / shrink), else refuse it (lambda x
    grow); a frame whose step gained too little, or whose lambda passed HOLD_DAMPING, is done."""
    x, loss, g, A, lam, _, _, scored, settings, _, _, _, _, done = state
    F, d = x.shape
    for f in range(F):
        if done[f]:
            continue
        if scored[0] == 0 or losses[f, 0] < loss[f]:
            gain = loss[f] - losses[f, 0]
            loss[f] = losses[f, 0]
            x[f] = X[f, 0]
            g[f] = gradients[f, 0]
            A[f] = curvatures[f, 0]
            if scored[0]:
                lam[f] = max(lam[f] / settings[SHRINK], MIN_DAMPING)
                done[f] = gain <= settings[TOLERANCE] * (1.0 + abs(loss[f]))
        else:
            lam[f] = min(lam[f] * settings[GROW], MAX_DAMPING)
            done[f] = lam[f] > HOLD_DAMPING
    scored[0] = 1


STEPS = DerivativeSteps(lm_init, lm_ask, lm_tell)


class LevenbergMarquardt(Optimizer):
    """Projected Levenberg-Marquardt on the objective's per-point loss, one row per frame a step."""

    Settings = LevenbergMarquardtSettings

    def derivative_steps(self) -> DerivativeSteps:
        return STEPS

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        s = self.settings
        return 1, np.array([s.damping, s.shrink, s.grow, s.tolerance], dtype=np.float64)

    def min_budget(self, task: Task) -> int:
        # the start and one step, d + 1 evaluations each
        return 2 * (task.dim + 1)
