"""The polish: a fit's last millimetres, on the model's own rigid hand.

Stochastic search (PSO) gets close to the best pose, not onto it: its last millimetres are
the budget's, not the model's. The polish finishes every fitted frame with a few steps of a
projected Levenberg-Marquardt on a robust least-squares loss, within the model as it is
configured (its bones, the subject's after calibration), so the polished hand is the one its
parameters describe: ``joints == model.points(params)``.

- every proposal within ``reach_mm`` of its point in the start pose pulls that point (a
  second round chooses them again around the first round's pose: ``rounds``),
  weighted by its normalised confidence (so the polish keeps the mode the search chose, and
  several agreeing predictors pull towards their robust mean: a fusion);
- the residual is the distance in millimetres under soft-L1 (quadratic below ``scale_mm``,
  linear above), so an outlier the search rightly ignored cannot drag the hand;
- joint angles stay within the model's limits (steps are projected onto them); the global
  rotation moves in its tangent space and stays a unit quaternion;
- a frame's step is taken only when it lowers that frame's loss, so no frame ends worse
  than it started on that loss; frames that failed (NaN) stay NaN.

Jacobians are forward differences through the model's one forward-kinematics kernel
(:func:`hybridfit.model.kinematics.tree_points`, all hypotheses of a frame in one call), and
the whole loop is compiled (numba), frame by frame, so its cost is a small part of the fit's.
The polish is a named step of :func:`hybridfit.fit` (``polish=True``, the default, what
``hybridfit fit`` runs); it needs a model with a kinematic tree.
"""

from __future__ import annotations

from typing import Sequence

import numba as nb
import numpy as np

from ..model.kinematics import block_setup, tree_points
from ..stages import structure_of

#: the robust loss's scale (mm): quadratic below it, linear above
SCALE_MM = 10.0
#: a proposal further than this (mm) from its point in the start pose is another mode
REACH_MM = 40.0
#: Levenberg-Marquardt iterations at most (a frame stops earlier once it no longer improves)
ITERATIONS = 30
#: rounds of the polish, each choosing the proposals within reach of the last round's pose
ROUNDS = 2
#: forward-difference steps: radians for angles and the rotation, mm for the position
STEP = 1e-6


def proposal_weights(proposals: np.ndarray, confidences: np.ndarray, points: np.ndarray,
                     reach_mm: float = REACH_MM) -> np.ndarray:
    """Each proposal's weight in the polish: proposals (F, Q, K, 3) mm, confidences
    (F, Q, K), start points (F, Q, 3) mm -> (F, Q, K): the confidences normalised per point,
    0 for a proposal further than ``reach_mm`` from the start point (another mode) unless
    it is the point's nearest proposal with a confidence, and 0 for a non-finite proposal."""
    conf = np.where(np.isfinite(proposals).all(-1), np.asarray(confidences, dtype=np.float64), 0.0)
    total = conf.sum(-1, keepdims=True)
    w = np.divide(conf, total, out=np.zeros_like(conf), where=total > 0)
    d = np.nan_to_num(np.linalg.norm(proposals - points[:, :, None], axis=-1), nan=np.inf)
    d = np.where(w > 0, d, np.inf)
    nearest = d == d.min(-1, keepdims=True)
    return np.where((d <= reach_mm) | nearest, w, 0.0)


def polish(model, params: np.ndarray, proposals: np.ndarray, confidences: np.ndarray, names: Sequence[str], *,
           scale_mm: float = SCALE_MM, reach_mm: float = REACH_MM, iterations: int = ITERATIONS,
           rounds: int = ROUNDS) -> np.ndarray:
    """params (F, P) fitted poses of ``model`` -> (F, P) polished poses (see the module doc):
    proposals (F, Q, K, 3) mm and confidences (F, Q, K) of the Q points ``names``. Rows that
    are not finite, or whose points have no proposal, come back unchanged."""
    params = np.ascontiguousarray(params, dtype=np.float64)
    out = params.copy()
    ok = np.isfinite(params).all(1)
    if not ok.any():
        return out
    structure = structure_of(model, tuple(names))
    tree = structure.tree()
    if tree is None:
        raise NotImplementedError(f"model {model.name or type(model).__name__} has no kinematic tree to polish on")
    P = model.n_params
    subset = np.arange(len(names), dtype=np.int64)
    ints, floats = block_setup(*tree.arrays, *tree.point_map, np.zeros((0, P)), np.arange(P), subset, subset, P)
    proposals = np.asarray(proposals, dtype=np.float64)
    targets = np.ascontiguousarray(np.nan_to_num(proposals))
    lower, upper = (np.ascontiguousarray(b, dtype=np.float64) for b in model.bounds())
    deps_ptr, deps = tangent_dependencies(tree, P, len(names))
    start = np.full(proposals.shape[:2] + (3,), np.nan)
    for _ in range(rounds):  # each round picks the proposals within reach of the pose the last one left
        start[ok] = model.points(out[ok], names)
        weights = proposal_weights(proposals, confidences, start, reach_mm)
        rows = np.flatnonzero(ok & (weights > 0).any((1, 2))).astype(np.int64)
        _polish_frames(out, rows, targets, np.ascontiguousarray(weights), *tree.arrays, *tree.point_map, ints, floats,
                       subset, lower, upper, deps_ptr, deps, float(scale_mm), int(iterations), STEP)
    return out


def tangent_dependencies(tree, P: int, Q: int) -> tuple[np.ndarray, np.ndarray]:
    """For each of the Q points, the tangent coordinates that move it, in CSR form (row
    starts (Q + 1,), indices): the position (0..2) and rotation (3..5) always, and each
    angle (parameter p >= 7, tangent p - 1) of a joint at or above one of the point's joints."""
    parents = tree.parents
    pm_ptr, pm_joint, _ = tree.point_map
    ptr, idx = [0], []
    for q in range(Q):
        moving = set(range(6))
        for e in range(pm_ptr[q], pm_ptr[q + 1]):
            j = int(pm_joint[e])
            while j >= 0:
                moving.update(int(p) - 1 for a, p in zip(tree.axes[j], tree.axis_params[j]) if a >= 0 and p >= 7)
                j = int(parents[j])
        idx.extend(sorted(moving))
        ptr.append(len(idx))
    assert all(0 <= i < P - 1 for i in idx)
    return np.asarray(ptr, dtype=np.int64), np.asarray(idx, dtype=np.int64)


@nb.njit(cache=True, inline="always")
def _soft_l1(d2):
    """soft-L1 of a squared scaled residual and its derivative: 2 (sqrt(1 + d2) - 1), 1 / sqrt(1 + d2)."""
    root = np.sqrt(1.0 + d2)
    return 2.0 * (root - 1.0), 1.0 / root


@nb.njit(cache=True, inline="always")
def _rotate(x, h, axis, out):
    """out = x with its quaternion (x[3:7]) turned by h radians about the camera axis ``axis``
    (left multiplication by exp(h e_axis / 2)), renormalised."""
    s, c = np.sin(0.5 * h), np.cos(0.5 * h)
    w, a, b, d = x[3], x[4], x[5], x[6]
    if axis == 0:
        nw, na, nb_, nd = c * w - s * a, c * a + s * w, c * b - s * d, c * d + s * b
    elif axis == 1:
        nw, na, nb_, nd = c * w - s * b, c * a + s * d, c * b + s * w, c * d - s * a
    else:
        nw, na, nb_, nd = c * w - s * d, c * a - s * b, c * b + s * a, c * d + s * w
    n = np.sqrt(nw * nw + na * na + nb_ * nb_ + nd * nd)
    out[3], out[4], out[5], out[6] = nw / n, na / n, nb_ / n, nd / n


@nb.njit(cache=True)
def _cost(points, col, y, w, scale2, irls):
    """sum_qk w_qk soft_l1(|points[:, :, col] - y_qk|^2 / scale2); irls (Q,) = sum_k w_qk rho'_qk."""
    Q, K = w.shape
    total = 0.0
    for q in range(Q):
        irls[q] = 0.0
        for k in range(K):
            if w[q, k] > 0.0:
                d0 = points[q, 0, col] - y[q, k, 0]
                d1 = points[q, 1, col] - y[q, k, 1]
                d2 = points[q, 2, col] - y[q, k, 2]
                rho, drho = _soft_l1((d0 * d0 + d1 * d1 + d2 * d2) / scale2)
                total += w[q, k] * rho
                irls[q] += w[q, k] * drho
    return total


@nb.njit(cache=True)
def _cholesky_solve(A, b, L, out):
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
def _polish_frames(params, rows, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params,
                   mirror, pm_ptr, pm_joint, pm_weight, ints, floats, subset, lower, upper, deps_ptr, deps,
                   scale_mm, iterations, step):
    """Polish params[f] (P,) in place for every f in ``rows``: proposals (F, Q, K, 3) mm,
    weights (F, Q, K); tangent coordinates: position (3), rotation (3), angles (P - 7)."""
    P = params.shape[1]
    Q, K = weights.shape[1], weights.shape[2]
    D = P - 1
    scale2 = scale_mm * scale_mm
    H = np.empty((D + 1, P))
    pts = np.empty((Q, 3, D + 1))
    trial_pts = np.empty((Q, 3, 1))
    Jq = np.empty((3, D))
    A = np.empty((D, D))
    M = np.empty((D, D))
    L = np.empty((D, D))
    g = np.empty(D)
    neg_g = np.empty(D)
    delta = np.empty(D)
    held = np.zeros(D, dtype=np.bool_)
    irls = np.empty(Q)
    trial_irls = np.empty(Q)
    trial = np.empty((1, P))
    for f in rows:
        x = params[f].copy()
        y, w = proposals[f], weights[f]
        tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                    ints, floats, x.reshape((1, P)), subset, trial_pts)
        current = _cost(trial_pts, 0, y, w, scale2, irls)
        lam = 1e-3
        for _ in range(iterations):
            for i in range(D + 1):  # the pose, then a step along each tangent coordinate
                H[i] = x
            for i in range(3):
                H[1 + i, i] += step * max(1.0, abs(x[i]))
                _rotate(x, step, i, H[4 + i])
            for i in range(6, D):
                H[1 + i, i + 1] += step
            tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint,
                        pm_weight, ints, floats, H, subset, pts)
            A[:, :] = 0.0
            g[:] = 0.0
            for q in range(Q):
                if irls[q] == 0.0:
                    continue
                r0 = r1 = r2 = 0.0  # sum_k w rho' (point - proposal)
                for k in range(K):
                    if w[q, k] > 0.0:
                        d0 = pts[q, 0, 0] - y[q, k, 0]
                        d1 = pts[q, 1, 0] - y[q, k, 1]
                        d2 = pts[q, 2, 0] - y[q, k, 2]
                        _, drho = _soft_l1((d0 * d0 + d1 * d1 + d2 * d2) / scale2)
                        r0 += w[q, k] * drho * d0
                        r1 += w[q, k] * drho * d1
                        r2 += w[q, k] * drho * d2
                for e in range(deps_ptr[q], deps_ptr[q + 1]):
                    i = deps[e]
                    h = step * max(1.0, abs(x[i])) if i < 3 else step
                    for c in range(3):
                        Jq[c, i] = (pts[q, c, 1 + i] - pts[q, c, 0]) / h
                    g[i] += Jq[0, i] * r0 + Jq[1, i] * r1 + Jq[2, i] * r2
                for e in range(deps_ptr[q], deps_ptr[q + 1]):
                    i = deps[e]
                    for e2 in range(deps_ptr[q], e + 1):
                        j = deps[e2]
                        A[i, j] += irls[q] * (Jq[0, i] * Jq[0, j] + Jq[1, i] * Jq[1, j] + Jq[2, i] * Jq[2, j])
            for i in range(D):  # an angle at its limit that the gradient pushes out stays there
                neg_g[i] = -g[i]
                held[i] = i >= 6 and ((x[i + 1] <= lower[i + 1] and g[i] > 0.0)
                                      or (x[i + 1] >= upper[i + 1] and g[i] < 0.0))
                if held[i]:
                    neg_g[i] = 0.0
            improved = False
            for _try in range(4):  # raise the damping until a step lowers the loss
                for i in range(D):
                    for j in range(i + 1):
                        M[i, j] = 0.0 if held[i] or held[j] else A[i, j]
                    M[i, i] = 1.0 if held[i] else A[i, i] + lam * max(A[i, i], 1e-9) + 1e-12
                if not _cholesky_solve(M, neg_g, L, delta):
                    lam *= 10.0
                    continue
                trial[0, :] = x
                for i in range(3):
                    trial[0, i] = x[i] + delta[i]
                angle = np.sqrt(delta[3] ** 2 + delta[4] ** 2 + delta[5] ** 2)
                if angle > 0.0:  # the rotation step: exp of the tangent vector, left-multiplied
                    s, c = np.sin(0.5 * angle) / angle, np.cos(0.5 * angle)
                    ew, ea, eb, ed = c, s * delta[3], s * delta[4], s * delta[5]
                    w0, a0, b0, d0 = x[3], x[4], x[5], x[6]
                    nw = ew * w0 - ea * a0 - eb * b0 - ed * d0
                    na = ew * a0 + ea * w0 + eb * d0 - ed * b0
                    nbq = ew * b0 - ea * d0 + eb * w0 + ed * a0
                    nd = ew * d0 + ea * b0 - eb * a0 + ed * w0
                    n = np.sqrt(nw * nw + na * na + nbq * nbq + nd * nd)
                    trial[0, 3], trial[0, 4], trial[0, 5], trial[0, 6] = nw / n, na / n, nbq / n, nd / n
                for i in range(6, D):
                    trial[0, i + 1] = min(max(x[i + 1] + delta[i], lower[i + 1]), upper[i + 1])
                tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint,
                            pm_weight, ints, floats, trial, subset, trial_pts)
                cost = _cost(trial_pts, 0, y, w, scale2, trial_irls)
                if cost < current:
                    gain = current - cost
                    x[:] = trial[0]
                    current = cost
                    irls[:] = trial_irls
                    lam = max(lam / 3.0, 1e-7)
                    improved = gain > 1e-6 * (1.0 + current)
                    break
                lam *= 10.0
            if not improved:
                break
        params[f] = x
