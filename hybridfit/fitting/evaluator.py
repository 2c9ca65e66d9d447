"""Scoring a stage's hypotheses of many frames for the driver.

A *scorer* has the two methods the driver (:mod:`.driver`) calls: ``prepare(base (F, P),
parameters (d,), points (m,), owned (o,), batch) -> stage`` once per stage, and ``score(stage,
X (F, m, d), points, losses (F, >= m))`` per generation: ``losses[:, :m]`` = each frame's
hypotheses (the parameters outside the stage at ``base``) scored over ``points``.
:class:`PointScorer` scores by the per-point loss on a kinematic tree; :class:`BoundScorer` by
the objective's bound losses, one frame at a time (plain numpy, a model without a kinematic
tree, or an objective that observes depth; derivatives where the bound losses offer them).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..model.kinematics import block_kinematics, block_points, block_setup, block_views
from ..objective import checked_losses, point_loss_of
from ..point_loss import has_proposals, specialise
from .derivatives import PARAMETER_STEP, assemble, compiled_point_derivatives, derivative_setup, pose_jacobians

#: the objective's per-point loss in the loop below: each specialised copy binds it (:func:`specialise`)
point_loss = None


@nb.njit(cache=True, nogil=True, inline="always")
def stage_block(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                joints_are_points, ints, floats, f0, f1, X, m, particles_last, subset):
    """The points (Q, 3, C) mm of frames f0 <= f < f1's hypotheses X[f] (m, d), or with
    ``particles_last`` X (F, d, m), frame f's hypothesis i in column (f - f0) m + i: the stage's
    block kinematics (:func:`block_kinematics`), then the points (unless the point map is
    the identity, when they are the joints)."""
    block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X,
                     0, m, particles_last)
    views = block_views(ints, floats)
    if joints_are_points:
        return views[9]
    block_points((f1 - f0) * m, views[9], pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], views[11])
    return views[11]


def score_blocks(constants, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params, mirror,
                 pm_ptr, pm_joint, pm_weight, joints_are_points, ints, floats, X, particles_last, subset, losses):
    """losses[f, :m] = the loss over ``subset`` of frame f's hypotheses X[f] (m, d), or with
    ``particles_last`` X (F, d, m), against proposals (F, Q, K, 3) and weights (F, Q, K): block
    by block of frames, the points (:func:`stage_block`) and the per-point loss."""
    F, m = X.shape[0], X.shape[2 if particles_last else 1]
    term = np.empty(m)
    for f0 in range(0, F, ints[9]):
        f1 = min(F, f0 + ints[9])
        pts = stage_block(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint,
                          pm_weight, joints_are_points, ints, floats, f0, f1, X, m, particles_last, subset)
        for f in range(f0, f1):
            c0, c1 = (f - f0) * m, (f - f0 + 1) * m
            out = losses[f, :m]
            out[:] = 0.0
            for t in range(subset.shape[0]):
                q = subset[t]
                if has_proposals(weights[f, q]):
                    point_loss(pts[q, 0, c0:c1], pts[q, 1, c0:c1], pts[q, 2, c0:c1], proposals[f, q], weights[f, q],
                               constants, term)
                    for i in range(m):
                        out[i] += term[i]


class CompiledLoss:
    """An objective's per-point loss compiled into :func:`score_blocks` (``score_blocks``,
    :func:`~hybridfit.point_loss.specialise`), and its ``constants`` (c,) float64."""

    def __init__(self, objective) -> None:
        found = point_loss_of(objective)
        if found is None:
            raise ValueError(f"objective {getattr(objective, 'name', '')!r} has no valid point_loss")
        self.score_blocks = specialise(score_blocks, found[0])
        self.constants = found[1]
        self._function = found[0]

    @property
    def point_derivatives(self):
        """:func:`~.derivatives.point_derivatives` with this per-point loss (compiled when first asked)."""
        return compiled_point_derivatives(self._function)


def along_rows(X: np.ndarray) -> tuple[np.ndarray, bool]:
    """Hypotheses X (F, m, d) as the block kinematics read them fastest: (X (F, d, m), True)
    where that view is C-contiguous (PSO's swarm is: no copy), else (X, False)."""
    XT = X.transpose(0, 2, 1)
    return (XT, True) if XT.flags.c_contiguous else (X, False)


def joints_are_points(tree, point_map) -> bool:
    """Whether the point map (pm_ptr, pm_joint, pm_weight) is the identity of the tree's joints."""
    J = len(tree[0])
    pm_ptr, pm_joint, pm_weight = point_map
    return (len(pm_ptr) == J + 1 and np.array_equal(pm_ptr, np.arange(J + 1))
            and np.array_equal(pm_joint, np.arange(J)) and bool(np.all(pm_weight == 1.0)))


class _Stages:
    """A scorer's kinematic ``tree`` (None: none) and ``point_map``, and its stage set-up:
    :func:`block_setup` in one working buffer kept for all its stages (a fresh one each stage
    costs page faults)."""

    def __init__(self, tree, point_map) -> None:
        self.tree, self.point_map, self._work = tree, point_map, None
        self.identity = tree is not None and joints_are_points(tree, point_map)

    def prepare(self, base, pidx, subset, owned, n):
        ints, floats = block_setup(*self.tree, *self.point_map, base, pidx, subset, owned, n, self._work)
        if self._work is None or floats.shape[0] > self._work.shape[0]:
            self._work = floats
        return ints, floats


class PointScorer(_Stages):
    """Scores by an objective's per-point loss on a kinematic tree (see the module doc).
    tree: (parents, offsets, rest, rest_identity, axes, axis_params, mirror); point_map:
    (pm_ptr, pm_joint, pm_weight), the (Q, J) point matrix in CSR form; compiled: the
    objective's :class:`CompiledLoss`; proposals (F, Q, K, 3) mm, weights (F, Q, K)."""

    def __init__(self, tree, point_map, compiled: CompiledLoss, proposals, weights, objective=None) -> None:
        super().__init__(tree, point_map)
        self.compiled, self.proposals, self.weights, self.objective = compiled, proposals, weights, objective

    def score(self, stage, X, subset, losses):
        self.compiled.score_blocks(self.compiled.constants, self.proposals, self.weights, *self.tree, *self.point_map,
                                   self.identity, *stage, *along_rows(X), subset, losses)

    def prepare_derivatives(self, base, pidx, subset, n):
        """A stage's set-up for :meth:`derivatives`: the block set-up and buffers for n rows a frame."""
        F, Q, d = base.shape[0], len(self.point_map[0]) - 1, len(pidx)
        buffers = (np.zeros((F, n, Q, 3)), np.zeros((F, n, Q, 3, d)), np.zeros((F, n, Q, 3)), np.zeros((F, n, Q, 3, 3)),
                   np.zeros((F, n)))
        return derivative_setup(self.tree, self.point_map, base.shape[1], subset, d), base, pidx, buffers

    def derivatives(self, stage, X, subset, frames, gradients, curvatures):
        """gradients[f, :m] (d,) and curvatures[f, :m] (d, d) of hypotheses X (F, m, d) over
        ``subset`` (:mod:`.derivatives`) for the ``frames`` (F,) bool; the others' are left as they are."""
        (ints, floats), base, pidx, buffers = stage
        m = X.shape[1]
        points, jacobians, point_gradients, hessians, losses = (a[:, :m] for a in buffers)
        X = np.ascontiguousarray(X)
        pose_jacobians(*self.tree, *self.point_map, ints, floats, base, pidx, subset, X, frames, points, jacobians)
        self.compiled.point_derivatives(self.compiled.constants, self.proposals, self.weights, subset, frames, points,
                                        losses, point_gradients, hessians)
        assemble(subset, frames, jacobians, point_gradients, hessians, gradients[:, :m], curvatures[:, :m])


@nb.njit(cache=True, nogil=True)
def stage_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                 joints_are_points, ints, floats, X, particles_last, subset, out):
    """out[f, q, :, :m] = the points ``subset`` of frame f's hypotheses X[f] (m, d) (or with
    ``particles_last`` X (F, d, m)), mm, out (F, Q, 3, >= m): :func:`stage_block`, the points
    written out instead of scored."""
    F, m = X.shape[0], X.shape[2 if particles_last else 1]
    for f0 in range(0, F, ints[9]):
        f1 = min(F, f0 + ints[9])
        pts = stage_block(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint,
                          pm_weight, joints_are_points, ints, floats, f0, f1, X, m, particles_last, subset)
        for f in range(f0, f1):
            for t in range(subset.shape[0]):
                q = subset[t]
                for c in range(3):
                    for i in range(m):
                        out[f, q, c, i] = pts[q, c, (f - f0) * m + i]


class BoundScorer(_Stages):
    """Scores by bound losses, one frame at a time: ``losses`` (F,) loss(points (m, Q, 3),
    subset) each (``Objective.bind``'s), or with ``observed`` loss(points, subset, joints (m, J,
    3)) (``bind_observed``'s). On a kinematic ``tree`` (as :class:`PointScorer`'s; None: the
    model's ``forward`` and ``point_matrix`` (Q, J), None for the joints themselves) a bound
    loss gets a view with the hypothesis innermost of the stage's points (the others 0), as
    the kinematics compute them. ``objective`` is named in errors."""

    def __init__(self, model, tree, point_map, point_matrix, losses, observed: bool = False, objective=None) -> None:
        super().__init__(None if observed else tree, point_map)
        self.model, self.point_matrix, self.losses = model, point_matrix, losses
        self.observed, self.objective = observed, objective
        if observed and losses and all(callable(getattr(loss, "derivatives", None)) for loss in losses):
            self.prepare_derivatives, self.derivatives = self._prepare_observed, self._observed_derivatives

    def prepare(self, base, pidx, subset, owned, n):
        if self.tree is None:
            return base.copy(), pidx
        return (*super().prepare(base, pidx, subset, owned, n),
                np.zeros((len(base), len(self.point_map[0]) - 1, 3, max(n, 1))))

    def _points(self, stage, X, subset):
        """(points (F, m, Q, 3) mm, joints (F, m, J, 3) mm or None) of hypotheses X (F, m, d)."""
        if self.tree is not None:
            ints, floats, buffer = stage
            stage_points(*self.tree, *self.point_map, self.identity, ints, floats, *along_rows(X), subset, buffer)
            return buffer[..., :X.shape[1]].transpose(0, 3, 1, 2), None
        base, pidx = stage
        F, m = X.shape[:2]
        full = np.repeat(base[:, None], m, axis=1)
        full[:, :, pidx] = X
        joints = self.model.forward(full.reshape(F * m, -1)).reshape(F, m, -1, 3)
        return (joints if self.point_matrix is None else np.einsum("qj,fnjc->fnqc", self.point_matrix, joints)), joints

    def _prepare_observed(self, base, pidx, subset, n):
        return base, pidx

    def _observed_derivatives(self, stage, X, subset, frames, gradients, curvatures):
        """:meth:`PointScorer.derivatives` of bound losses that offer ``derivatives`` (objectives with
        ``observed_derivatives``): their partial derivatives with respect to the points and the
        joints, chained through the joints' Jacobians (forward differences of the model's
        ``forward``, the steps of :mod:`.derivatives`)."""
        base, pidx = stage
        m, d, P = X.shape[1], X.shape[2], base.shape[1]
        every = np.arange(d)
        for f in np.flatnonzero(frames):
            poses = np.repeat(base[f][None, None], m, axis=0).repeat(d + 1, axis=1)
            poses[:, :, pidx] = X[f][:, None]
            steps = PARAMETER_STEP * np.maximum(1.0, np.abs(X[f]))
            poses[:, 1 + every, pidx] += steps
            joints = self.model.forward(poses.reshape(-1, P)).reshape(m, d + 1, -1, 3)
            jac = (joints[:, 1:] - joints[:, :1]) / steps[:, :, None, None]  # (m, d, J, 3)
            at = np.ascontiguousarray(joints[:, 0])
            M = self.point_matrix
            points = at if M is None else np.einsum("qj,njc->nqc", M, at)
            _, pg, ph, jg, jc = self.losses[f].derivatives(points, subset, at)
            J = at.shape[1]
            grad = jg + (pg if M is None else np.einsum("qj,nqc->njc", M, pg))  # (m, J, 3)
            curv = np.array(jc, dtype=np.float64).reshape(m, J, 3, J, 3)
            if M is None:  # the points' 3 x 3 blocks on the joints' diagonal
                diagonal = np.arange(J)
                curv.transpose(1, 3, 0, 2, 4)[diagonal, diagonal] += ph.transpose(1, 0, 2, 3)
            else:  # sum_q M[q, j] M[q, k] H_q
                pairs = (M[:, :, None] * M[:, None, :]).reshape(len(M), -1)
                curv += np.tensordot(ph.reshape(m, len(M), 9), pairs, axes=([1], [0])).reshape(
                    m, 3, 3, J, J).transpose(0, 3, 1, 4, 2)
            flat = jac.reshape(m, d, -1)
            gradients[f, :m] = (flat @ grad.reshape(m, -1, 1))[..., 0]
            curvatures[f, :m] = flat @ curv.reshape(m, 3 * J, 3 * J) @ flat.transpose(0, 2, 1)

    def score(self, stage, X, subset, losses):
        points, joints = self._points(stage, X, subset)
        m = X.shape[1]
        for f in range(len(points)):
            out = (self.losses[f](points[f], subset, joints[f]) if self.observed
                   else self.losses[f](points[f], subset))
            losses[f, :m] = checked_losses(out, m, self.objective)
