"""A final least-squares polish of fitted poses: the representable optimum near a fit.

Stochastic search (PSO) gets close to the best pose, not onto it: its last millimetres are
the budget's, not the model's. :func:`polish` finishes every frame with a bounded,
robust Gauss-Newton step (``scipy.optimize.least_squares``, trust-region reflective):

- each point is pulled towards one target: the proposal of that point nearest the start
  pose's point (so the polish keeps the mode the search chose), weighted by that
  proposal's normalised confidence; a point whose nearest proposal is further than
  ``reach_mm`` (or whose confidences are all 0) is left out;
- the residual is the distance in millimetres under a robust loss (``loss``, with
  ``f_scale = scale_mm``: quadratic below it, growing slowly above), so an outlier the
  search rightly ignored cannot drag the hand;
- the joint angles stay within the model's limits (the bounds of the solver) and the
  quaternion's length is held at 1 by a residual, so the result is as valid as the start.

A frame keeps its start pose unless the polish lowers the robust loss; frames that are
NaN (failed fits) stay NaN. Every frame is solved jointly as one sparse problem (the
Jacobian is block diagonal), so a thousand frames cost about as much as a few.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

#: default robust loss and its scale (mm), and how far a proposal may be from the start
LOSS = "soft_l1"
SCALE_MM = 10.0
REACH_MM = 40.0


def targets(proposals: np.ndarray, confidences: np.ndarray, points: np.ndarray,
            reach_mm: float = REACH_MM) -> tuple[np.ndarray, np.ndarray]:
    """Each point's target and weight: proposals (F, Q, K, 3) mm, confidences (F, Q, K),
    start points (F, Q, 3) mm -> targets (F, Q, 3) mm (the proposal with non-zero
    confidence nearest the start point) and weights (F, Q) (its confidence normalised per
    point, 0 beyond ``reach_mm`` or without proposals)."""
    conf = np.asarray(confidences, dtype=np.float64)
    total = conf.sum(-1, keepdims=True)
    w = np.divide(conf, total, out=np.zeros_like(conf), where=total > 0)
    d = np.linalg.norm(proposals - points[:, :, None], axis=-1)
    d = np.where(w > 0, d, np.inf)
    k = np.nan_to_num(d, nan=np.inf).argmin(-1)
    pick = lambda a: np.take_along_axis(a, k[..., None], axis=2)[:, :, 0]  # noqa: E731
    tgt = np.take_along_axis(proposals, k[..., None, None], axis=2)[:, :, 0]
    weight = np.where(pick(d) <= reach_mm, pick(w), 0.0)
    return tgt, weight


def _rho(r2: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """A robust loss of squared scaled residuals and its derivative (scipy's definitions)."""
    if loss == "linear":
        return r2, np.ones_like(r2)
    if loss == "soft_l1":
        root = np.sqrt(1.0 + r2)
        return 2.0 * (root - 1.0), 1.0 / root
    if loss == "cauchy":
        return np.log1p(r2), 1.0 / (1.0 + r2)
    raise ValueError(f"unknown loss {loss!r} (linear, soft_l1, cauchy)")


def polish(model, params: np.ndarray, target: np.ndarray, weight: np.ndarray, names: Sequence[str], *,
           loss: str = LOSS, scale_mm: float = SCALE_MM, iterations: int = 20, step: float = 1e-6) -> np.ndarray:
    """params (F, P) start poses -> (F, P) polished poses of ``model``: a projected
    Levenberg-Marquardt of sum_q weight (F, Q) * rho(|point_q - target_q (F, Q, 3)|^2 /
    scale_mm^2) within the model's bounds (iteratively reweighted for the robust loss;
    forward-difference Jacobians, all frames batched). A frame's step is taken only when it
    lowers that frame's loss, so no frame gets worse than its start."""
    params = np.asarray(params, dtype=np.float64)
    out = params.copy()
    ok = np.isfinite(params).all(1) & np.isfinite(target).all((1, 2)) & (np.asarray(weight) > 0).any(1)
    if not ok.any():
        return out
    x = params[ok].copy()
    tgt, w = np.asarray(target, float)[ok], np.asarray(weight, float)[ok]
    F, P = x.shape
    lower, upper = model.bounds()
    lam = np.full(F, 1e-2)

    def cost(p, rows):
        d2 = ((model.points(p, names) - tgt[rows]) ** 2).sum(-1) / scale_mm**2
        rho, drho = _rho(d2, loss)
        return (w[rows] * rho).sum(1), w[rows] * drho

    current, irls = cost(x, slice(None))
    h = step * np.maximum(1.0, np.abs(x))
    for _ in range(iterations):
        base = model.points(x, names)  # (F, Q, 3)
        r = (base - tgt).reshape(F, -1)
        J = np.empty((F, r.shape[1], P))
        for i in range(P):
            xi = x.copy()
            xi[:, i] += h[:, i]
            J[:, :, i] = (model.points(xi, names) - base).reshape(F, -1) / h[:, i, None]
        W = np.repeat(irls, 3, axis=1)  # (F, 3Q)
        JtW = J.transpose(0, 2, 1) * W[:, None, :]
        A = JtW @ J
        g = (JtW @ r[:, :, None])[:, :, 0]
        diag = np.maximum(np.einsum("fii->fi", A), 1e-9)
        improved = np.zeros(F, bool)
        for _ in range(4):  # raise the damping of the frames whose step did not lower their loss
            todo = ~improved
            M = A[todo] + (lam[todo, None] * diag[todo])[:, :, None] * np.eye(P)
            delta = -np.linalg.solve(M, g[todo][:, :, None])[:, :, 0]
            trial = np.clip(x[todo] + delta, lower, upper)
            trial[:, 3:7] /= np.linalg.norm(trial[:, 3:7], axis=1, keepdims=True)
            c, wt = cost(trial, todo)
            better = c < current[todo]
            idx = np.flatnonzero(todo)
            x[idx[better]], current[idx[better]], irls[idx[better]] = trial[better], c[better], wt[better]
            lam[idx[better]] = np.maximum(lam[idx[better]] / 3.0, 1e-6)
            lam[idx[~better]] *= 10.0
            improved[idx[better]] = True
            if improved.all():
                break
        if not improved.any():
            break
    out[np.flatnonzero(ok)] = x
    return out
