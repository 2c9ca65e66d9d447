"""A final least-squares polish of fitted poses: the representable optimum near a fit.

Stochastic search (PSO) gets close to the best pose, not onto it: its last millimetres are
the budget's, not the model's. :func:`refine` finishes every frame with a few steps of a
projected Levenberg-Marquardt on a robust least-squares loss:

- every proposal within ``reach_mm`` of its point in the start pose pulls that point,
  weighted by its normalised confidence (so the polish keeps the mode the search chose,
  and several agreeing predictors pull towards their robust mean: a fusion);
- the residual is the distance in millimetres under a robust loss (``loss``, scale
  ``scale_mm``: quadratic below it, growing slowly or not at all above), so an outlier
  the search rightly ignored cannot drag the hand;
- the joint angles stay within the model's limits (steps are clipped to the bounds) and
  the quaternion is renormalised, so the result is as valid as the start;
- the bone lengths are the model's (the subject's, after calibration), or, with
  ``bone_tolerance`` > 0, each frame's bones may stretch within 1 +- ``bone_tolerance``
  of them at a quadratic cost (``bone_weight``): annotations and predictions are not one
  rigid skeleton (ICVL's bones vary by 2-4 mm within a sequence), and a model that cannot
  follow that keeps every fit millimetres away. :func:`fit_and_refine`, what ``hybridfit
  fit`` runs, uses ``BONE_TOLERANCE`` and ``BONE_WEIGHT``;
- with ``palm_tolerance_mm`` > 0, each frame's finger bases (the root's children: hand26's
  thumb CMC and finger MCPs) may also move, each with its whole finger, by up to
  +-``palm_tolerance_mm`` along each axis of the hand frame (the global quaternion's) at a
  quadratic cost (``palm_weight``): the palm is not rigid (real MCPs spread and arch by
  several millimetres between frames). The fingers' own bones and joint angles are
  unchanged; only where each base sits relative to the wrist changes, by at most sqrt(3)
  times the tolerance beyond the bone freedom. :func:`fit_and_refine` uses ``PALM_TOLERANCE_MM`` and
  ``PALM_WEIGHT``.

A frame's step is taken only when it lowers that frame's loss, so no frame ends worse
than it started on that loss; frames that are NaN (failed fits) stay NaN. All frames are
solved together (batched Jacobians by forward differences), so a thousand frames cost
about as much as a few.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any, Sequence

import numpy as np

from .. import registry
from ..model.rotations import quaternions_to_matrices
from ..problem import Problem
from .frames import FitResult, fit

#: default robust loss and its scale (mm), and how far a proposal may be from the start
LOSS = "soft_l1"
SCALE_MM = 10.0
REACH_MM = 40.0
#: default per-frame bone freedom of fit_and_refine: relative tolerance and prior weight
#: (chosen on ICVL frames 0-99 and NYU actor 2 with stress predictors: benchmarks/bench_floor.py)
BONE_TOLERANCE = 0.15
BONE_WEIGHT = 0.3
#: default per-frame palm freedom of fit_and_refine: each finger base's move (mm, per axis of
#: the hand frame) and its prior weight (chosen on ICVL frames 0-99 and every 20th NYU actor-2
#: frame with stress predictors: benchmarks/bench_floor.py --palm)
PALM_TOLERANCE_MM = 5.0
PALM_WEIGHT = 0.3


@dataclasses.dataclass
class RefinedFitResult(FitResult):
    """A FitResult after the polish: ``bone_factors`` (F, J) each frame's bone lengths as
    factors of the model's (within 1 +- the bone tolerance); ``base_moves`` (F, J, 3) mm
    each finger base's move in the hand frame (within +- the palm tolerance; 0 elsewhere);
    ``model_joints`` are the model's joints with those bones and bases, ``joints`` their
    named points."""

    bone_factors: np.ndarray | None = None
    base_moves: np.ndarray | None = None

    def to_npz(self) -> dict[str, np.ndarray]:
        return {**super().to_npz(), "bone_factors": self.bone_factors, "base_moves": self.base_moves}


def proposal_weights(proposals: np.ndarray, confidences: np.ndarray, points: np.ndarray,
                     reach_mm: float = REACH_MM) -> np.ndarray:
    """Each proposal's weight in the polish: proposals (F, Q, K, 3) mm, confidences
    (F, Q, K), start points (F, Q, 3) mm -> (F, Q, K): the confidences normalised per point,
    0 for a proposal further than ``reach_mm`` from the start point (another mode) unless
    it is the point's nearest proposal with a confidence."""
    conf = np.asarray(confidences, dtype=np.float64)
    total = conf.sum(-1, keepdims=True)
    w = np.divide(conf, total, out=np.zeros_like(conf), where=total > 0)
    d = np.nan_to_num(np.linalg.norm(proposals - points[:, :, None], axis=-1), nan=np.inf)
    d = np.where(w > 0, d, np.inf)
    nearest = d == d.min(-1, keepdims=True)
    return np.where((d <= reach_mm) | nearest, w, 0.0)


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


@dataclasses.dataclass(frozen=True)
class Polished:
    """params (F, P) poses; bone_factors (F, J) each bone's length (joint to parent) as a
    factor of the model's (1 for the root, and everywhere without bone freedom);
    base_moves (F, J, 3) mm each finger base's move in the hand frame (the global
    quaternion's; 0 for every other joint, and everywhere without palm freedom)."""

    params: np.ndarray
    bone_factors: np.ndarray
    base_moves: np.ndarray | None = None

    def joints(self, model) -> np.ndarray:
        """(F, J, 3) mm: the model's joints with the bones stretched by ``bone_factors`` and
        the finger bases moved by ``base_moves`` (each with its finger)."""
        joints = stretch_bones(model.forward(self.params), np.asarray(model.parents), self.bone_factors)
        if self.base_moves is None or not self.base_moves.any():
            return joints
        return move_bases(joints, np.asarray(model.parents), self.params[:, 3:7], self.base_moves)

    def points(self, model, names: Sequence[str]) -> np.ndarray:
        """(F, Q, 3) mm: the named points of :meth:`joints`."""
        return np.matmul(model.point_matrix(list(names)), self.joints(model))


def stretch_bones(joints: np.ndarray, parents: np.ndarray, factors: np.ndarray) -> np.ndarray:
    """joints (F, J, 3) mm with every bone (joint - parent) scaled by factors (F, J); the
    children move with their parents, the root stays; the joint angles are unchanged."""
    out = joints.copy()
    for j, p in enumerate(parents):  # parents precede children
        if p >= 0:
            out[:, j] = out[:, p] + (joints[:, j] - joints[:, p]) * factors[:, j, None]
    return out


def subtrees(parents: np.ndarray) -> np.ndarray:
    """(J, J) bool: [j, i] when joint i is j or below it (parents precede children)."""
    parents = np.asarray(parents)
    below = np.eye(len(parents), dtype=bool)
    for i in range(len(parents) - 1, -1, -1):
        if parents[i] >= 0:
            below[parents[i]] |= below[i]
    return below


def move_bases(joints: np.ndarray, parents: np.ndarray, quaternions: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """joints (F, J, 3) mm with every joint moved by moves (F, J, 3) mm (hand frame, rotated
    by quaternions (F, 4)) of itself and its ancestors: a base's move carries its finger."""
    world = np.einsum("fij,fkj->fki", quaternions_to_matrices(quaternions), moves)
    return joints + np.einsum("ki,fkc->fic", subtrees(parents).astype(float), world)


def polish(model, params: np.ndarray, proposals: np.ndarray, weight: np.ndarray, names: Sequence[str], *,
           loss: str = LOSS, scale_mm: float = SCALE_MM, iterations: int = 20, step: float = 1e-6,
           bone_tolerance: float = 0.0, bone_weight: float = 1.0, palm_tolerance_mm: float = 0.0,
           palm_weight: float = PALM_WEIGHT) -> Polished:
    """params (F, P) start poses -> the polished poses of ``model``: a projected
    Levenberg-Marquardt of sum_qk weight_qk (F, Q, K) * rho(|point_q - proposal_qk (F, Q, K,
    3)|^2 / scale_mm^2) within the model's bounds (iteratively reweighted for the robust loss;
    forward-difference Jacobians, all frames batched). With ``bone_tolerance`` > 0 every
    frame's bones may also stretch by a factor within 1 +- bone_tolerance, at a cost of
    ``bone_weight`` * (change in mm)^2 / scale_mm^2 per bone (a prior towards the model's
    lengths). With ``palm_tolerance_mm`` > 0 every frame's finger bases (the root's
    children) may move with their fingers within +-palm_tolerance_mm per axis of the hand
    frame, at a cost of ``palm_weight`` * (move in mm)^2 / scale_mm^2 per base. A frame's
    step is taken only when it lowers that frame's loss, so no frame gets worse than its
    start."""
    params = np.asarray(params, dtype=np.float64)
    parents = np.asarray(model.parents)
    n_joints = len(parents)
    factors_out = np.ones((len(params), n_joints))
    moves_out = np.zeros((len(params), n_joints, 3))
    out = params.copy()
    weight = np.where(np.isfinite(proposals).all(-1), weight, 0.0)
    ok = np.isfinite(params).all(1) & (weight > 0).any((1, 2))
    if not ok.any():
        return Polished(out, factors_out, moves_out)
    tgt, w = np.nan_to_num(np.asarray(proposals, float)[ok]), np.asarray(weight, float)[ok]
    F, P = int(ok.sum()), params.shape[1]
    bones = np.flatnonzero(parents >= 0) if bone_tolerance > 0 else np.zeros(0, np.int64)
    roots = np.flatnonzero(parents < 0)
    bases = np.flatnonzero(np.isin(parents, roots)) if palm_tolerance_mm > 0 else np.zeros(0, np.int64)
    rest = model.forward(model.default_params()[None])[0]
    length = np.linalg.norm(rest[bones] - rest[parents[bones]], axis=-1)  # (B,) mm
    # poses, then relative bone changes, then the bases' moves (mm, hand frame)
    x = np.concatenate([params[ok], np.zeros((F, len(bones) + 3 * len(bases)))], axis=1)
    D, S = x.shape[1], P + len(bones)  # all unknowns; those before the moves
    lower, upper = model.bounds()
    lower = np.concatenate([lower, np.full(len(bones), -bone_tolerance), np.full(3 * len(bases), -palm_tolerance_mm)])
    upper = np.concatenate([upper, np.full(len(bones), bone_tolerance), np.full(3 * len(bases), palm_tolerance_mm)])
    M = model.point_matrix(list(names))
    carried = M @ subtrees(parents)[bases].T.astype(float)  # (Q, nb): how much of each base's move a point takes
    prior = np.concatenate([bone_weight * length**2, np.full(3 * len(bases), palm_weight)])  # d(cost s^2)/d(z^2)
    lam = np.full(F, 1e-2)

    def unmoved_points(z):  # (F, Q, 3): the pose and the bones, the bases where the pose puts them
        joints = model.forward(z[:, :P])
        if len(bones):
            factors = np.ones((len(z), n_joints))
            factors[:, bones] = 1.0 + z[:, P:S]
            joints = stretch_bones(joints, parents, factors)
        return np.matmul(M, joints)  # (Q, J) @ (F, J, 3) -> (F, Q, 3)

    def moved(z, out):  # out with the bases' moves added (each carrying its finger)
        if not len(bases):
            return out
        world = np.einsum("fij,fbj->fbi", quaternions_to_matrices(z[:, 3:7]), z[:, S:].reshape(len(z), -1, 3))
        return out + np.einsum("qb,fbi->fqi", carried, world)

    def points(z):
        return moved(z, unmoved_points(z))

    def cost(z, rows):
        d2 = ((points(z)[:, :, None] - tgt[rows]) ** 2).sum(-1) / scale_mm**2
        rho, drho = _rho(d2, loss)
        free = (prior * z[:, P:] ** 2).sum(1) / scale_mm**2
        return (w[rows] * rho).sum((1, 2)) + free, w[rows] * drho  # (F,), (F, Q, K)

    current, irls = cost(x, slice(None))
    h = step * np.maximum(1.0, np.abs(x))
    for _ in range(iterations):
        unmoved = unmoved_points(x)
        base = moved(x, unmoved)  # (F, Q, 3)
        J = np.empty((F, base.shape[1] * 3, D))
        for i in range(S):  # the moves' part changes with the quaternion only
            xi = x.copy()
            xi[:, i] += h[:, i]
            if 3 <= i < 7:
                J[:, :, i] = (points(xi) - base).reshape(F, -1) / h[:, i, None]
            else:
                J[:, :, i] = (unmoved_points(xi) - unmoved).reshape(F, -1) / h[:, i, None]
        if len(bases):  # the points are linear in the moves: d point_qc / d move_ba = carried_qb R_ca
            R = quaternions_to_matrices(x[:, 3:7])
            J[:, :, S:] = np.einsum("qb,fca->fqcba", carried, R).reshape(F, -1, D - S)
        W = np.repeat(irls.sum(2), 3, axis=1)  # (F, 3Q): a point's weights over its proposals
        r = np.einsum("fqk,fqkc->fqc", irls, base[:, :, None] - tgt).reshape(F, -1)  # weighted residual sums
        JtW = J.transpose(0, 2, 1) * W[:, None, :]
        A = JtW @ J
        g = (J.transpose(0, 2, 1) @ r[:, :, None])[:, :, 0]
        if D > P:
            A[:, np.arange(P, D), np.arange(P, D)] += prior
            g[:, P:] += prior * x[:, P:]
        diag = np.maximum(np.einsum("fii->fi", A), 1e-9)
        improved = np.zeros(F, bool)
        for _ in range(4):  # raise the damping of the frames whose step did not lower their loss
            todo = ~improved
            Mk = A[todo] + (lam[todo, None] * diag[todo])[:, :, None] * np.eye(D)
            delta = -np.linalg.solve(Mk, g[todo][:, :, None])[:, :, 0]
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
    rows = np.flatnonzero(ok)
    out[rows] = x[:, :P]
    factors_out[np.ix_(rows, bones)] = 1.0 + x[:, P:S]
    moves_out[np.ix_(rows, bases)] = x[:, S:].reshape(F, len(bases), 3)
    return Polished(out, factors_out, moves_out)


def refine(model, params: np.ndarray, proposals: np.ndarray, confidences: np.ndarray, names: Sequence[str], *,
           reach_mm: float = REACH_MM, loss: str = LOSS, scale_mm: float = SCALE_MM, iterations: int = 20,
           bone_tolerance: float = 0.0, bone_weight: float = 1.0, palm_tolerance_mm: float = 0.0,
           palm_weight: float = PALM_WEIGHT) -> Polished:
    """params (F, P) fitted poses of ``model`` -> polished (see the module doc and
    :func:`polish`): proposals (F, Q, K, 3) mm and confidences (F, Q, K) of the Q points
    ``names``."""
    params = np.asarray(params, dtype=np.float64)
    proposals = np.asarray(proposals, dtype=np.float64)
    start = np.full(proposals.shape[:2] + (3,), np.nan)
    ok = np.isfinite(params).all(1)
    if ok.any():
        start[ok] = model.points(params[ok], names)
    weight = proposal_weights(proposals, confidences, start, reach_mm)
    return polish(model, params, proposals, weight, names, loss=loss, scale_mm=scale_mm, iterations=iterations,
                  bone_tolerance=bone_tolerance, bone_weight=bone_weight, palm_tolerance_mm=palm_tolerance_mm,
                  palm_weight=palm_weight)


def fit_and_refine(proposals: np.ndarray, confidences: np.ndarray, *, bone_tolerance: float = BONE_TOLERANCE,
                   bone_weight: float = BONE_WEIGHT, palm_tolerance_mm: float = PALM_TOLERANCE_MM,
                   palm_weight: float = PALM_WEIGHT, **fit_options: Any) -> FitResult:
    """:func:`hybridfit.fit` followed by :func:`refine_fit`: the same arguments (and the
    bone and palm freedom's), a :class:`RefinedFitResult`."""
    result = fit(proposals, confidences, **fit_options)
    return refine_fit(result, proposals, confidences, bone_tolerance=bone_tolerance, bone_weight=bone_weight,
                      palm_tolerance_mm=palm_tolerance_mm, palm_weight=palm_weight, **fit_options)


def refine_fit(result: FitResult, proposals: np.ndarray, confidences: np.ndarray, *,
               bone_tolerance: float = BONE_TOLERANCE, bone_weight: float = BONE_WEIGHT,
               palm_tolerance_mm: float = PALM_TOLERANCE_MM, palm_weight: float = PALM_WEIGHT,
               **fit_options: Any) -> FitResult:
    """A :func:`hybridfit.fit` result of these proposals and ``fit_options`` (the plugins,
    ``joint_names``, ``search_radius_mm``; the others are ignored) with every fitted frame
    polished by :func:`refine`, with per-frame bone freedom (``bone_tolerance``,
    ``bone_weight``; 0 tolerance: the model's bones) and palm freedom (``palm_tolerance_mm``,
    ``palm_weight``; 0 tolerance: a rigid palm): a :class:`RefinedFitResult` whose
    objective is the fit objective's loss at the polished points. With depth observations
    the result is returned as it is (the polish cannot see the depth)."""
    if fit_options.get("observations") is not None:
        return result
    defaults = {k: v.default for k, v in inspect.signature(fit).parameters.items()}  # fit's own defaults
    model = registry.create("model", fit_options.get("model", defaults["model"]), fit_options.get("model_config"))
    objective = registry.create("objective", fit_options.get("objective", defaults["objective"]),
                                fit_options.get("objective_config"))
    names = result.joint_names
    done = np.flatnonzero(~result.failed)
    factors = np.ones((len(result.params), model.n_joints))
    factors[result.failed] = np.nan
    moves = np.zeros((len(result.params), model.n_joints, 3))
    moves[result.failed] = np.nan
    out = RefinedFitResult(**{f.name: getattr(result, f.name) for f in dataclasses.fields(FitResult)},
                           bone_factors=factors, base_moves=moves)
    if not len(done):
        return out
    proposals, confidences = np.asarray(proposals, float), np.asarray(confidences, float)
    polished = refine(model, result.params[done], proposals[done], confidences[done], names,
                      bone_tolerance=bone_tolerance, bone_weight=bone_weight, palm_tolerance_mm=palm_tolerance_mm,
                      palm_weight=palm_weight)
    out.params, out.joints, out.model_joints, out.objective = (result.params.copy(), result.joints.copy(),
                                                                result.model_joints.copy(), result.objective.copy())
    out.params[done], out.bone_factors[done] = polished.params, polished.bone_factors
    out.base_moves[done] = polished.base_moves
    out.model_joints[done] = polished.joints(model)
    out.joints[done] = polished.points(model, names)
    radius = float(fit_options.get("search_radius_mm", defaults["search_radius_mm"]))
    for f in done:  # the fit objective at the polished points (through the problem's loss)
        problem = Problem(model, objective, proposals[f], confidences[f], names, radius)
        out.objective[f] = float(problem.loss(out.joints[f][None], problem.all_points)[0])
    return out
