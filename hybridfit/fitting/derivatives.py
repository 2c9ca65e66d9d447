"""A stage's loss gradient and curvature, for an optimiser's derivative steps.

For each hypothesis (the stage's d parameters, the others at the frame's base) the loss over
the stage's points, its gradient (d,) and a positive semi-definite curvature (d, d):

- the points' Jacobians J_q (3, d) by forward differences through the kinematic tree, the
  d + 1 poses of a hypothesis in one call of the one forward kinematics
  (:func:`~hybridfit.model.kinematics.tree_points`);
- each point's loss gradient g_q (3,) and Hessian H_q (3, 3) by finite differences of the
  objective's per-point loss at that point alone (ten positions, one call: cheap);
- gradient sum_q J_q^T g_q, curvature sum_q J_q^T H_q+ J_q with H_q+ the Hessian's positive
  part (its negative eigenvalues set to 0): Gauss-Newton for any per-point loss.

Three compiled steps: :func:`pose_jacobians` (the points and their Jacobians, any model),
:func:`point_derivatives` (compiled with the objective's ``point_loss`` inlined,
:func:`~hybridfit.point_loss.specialise`: a small loop, quick to compile for a new objective)
and :func:`assemble` (the gradient and curvature). A row costs what a forward-difference
gradient would, ``d + 1`` evaluations (:class:`~hybridfit.task.DerivativeSteps`).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ..model.kinematics import block_setup, tree_points
from ..point_loss import has_proposals, specialise

#: the per-point loss in the loop below: each specialised copy binds it (:func:`specialise`)
point_loss = None

#: forward-difference step of a parameter: this times max(1, |value|) (mm, rad or quaternion units)
PARAMETER_STEP = 1e-6
#: finite-difference step of a point's position in its loss's derivatives, mm
POINT_STEP_MM = 1e-3


@nb.njit(cache=True, nogil=True)
def positive_part(H, out):
    """out (3, 3) = the symmetric H (3, 3) with its negative eigenvalues set to 0 (H itself when
    it is positive semi-definite: every principal minor >= 0, the common case)."""
    m01 = H[0, 0] * H[1, 1] - H[0, 1] * H[0, 1]
    m02 = H[0, 0] * H[2, 2] - H[0, 2] * H[0, 2]
    m12 = H[1, 1] * H[2, 2] - H[1, 2] * H[1, 2]
    det = H[0, 0] * m12 - H[0, 1] * (H[0, 1] * H[2, 2] - H[1, 2] * H[0, 2]) \
        + H[0, 2] * (H[0, 1] * H[1, 2] - H[1, 1] * H[0, 2])
    if H[0, 0] >= 0.0 and H[1, 1] >= 0.0 and H[2, 2] >= 0.0 and m01 >= 0.0 and m02 >= 0.0 and m12 >= 0.0 \
            and det >= 0.0:
        out[:, :] = H
        return
    values, vectors = np.linalg.eigh(H)
    for a in range(3):
        for b in range(3):
            s = 0.0
            for e in range(3):
                if values[e] > 0.0:
                    s += vectors[a, e] * values[e] * vectors[b, e]
            out[a, b] = s


@nb.njit(cache=True, nogil=True)
def pose_jacobians(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                   ints, floats, base, pidx, subset, X, fresh, points, jacobians):
    """points[f, i] (Q, 3) mm and jacobians[f, i] (Q, 3, d) (mm per unit of each parameter) of
    frame f's hypotheses X[f] (m, d) at the points ``subset``, the parameters ``pidx`` (d,)
    moving from ``base`` (F, P), by forward differences: the d + 1 poses of a hypothesis in one
    call of :func:`tree_points` (``ints``, ``floats``: its :func:`block_setup` over d + 1 columns).
    Only the frames ``fresh`` (F,) bool are computed."""
    F, m, d = X.shape
    P = base.shape[1]
    Q = points.shape[2]
    poses = np.empty((d + 1, P))
    pts = np.empty((Q, 3, d + 1))
    steps = np.empty(d)
    for f in range(F):
        if not fresh[f]:
            continue
        for i in range(m):
            poses[0] = base[f]
            for k in range(d):
                poses[0, pidx[k]] = X[f, i, k]
            for k in range(d):
                poses[1 + k] = poses[0]
                steps[k] = PARAMETER_STEP * max(1.0, abs(X[f, i, k]))
                poses[1 + k, pidx[k]] += steps[k]
            tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                        ints, floats, poses, subset, pts)
            for t in range(subset.shape[0]):
                q = subset[t]
                for a in range(3):
                    points[f, i, q, a] = pts[q, a, 0]
                    for k in range(d):
                        jacobians[f, i, q, a, k] = (pts[q, a, 1 + k] - pts[q, a, 0]) / steps[k]


def point_derivatives(constants, proposals, weights, subset, fresh, points, losses, gradients, hessians):
    """losses[f, i] = the loss of points[f, i] (Q, 3) over ``subset``; gradients[f, i, q] (3,)
    and hessians[f, i, q] (3, 3) (positive part) of each point's loss, by finite differences
    of the per-point loss at ten positions around the point (one call); 0 for a point without
    proposals. proposals (F, Q, K, 3) mm, weights (F, Q, K); frames not ``fresh`` are skipped."""
    F, m = points.shape[0], points.shape[1]
    xs, ys, zs, term = np.empty(10), np.empty(10), np.empty(10), np.empty(10)
    H = np.empty((3, 3))
    h = POINT_STEP_MM
    for f in range(F):
        if not fresh[f]:
            continue
        for i in range(m):
            total = 0.0
            for t in range(subset.shape[0]):
                q = subset[t]
                gradients[f, i, q, :] = 0.0
                hessians[f, i, q, :, :] = 0.0
                if not has_proposals(weights[f, q]):
                    continue
                # the point, +h along each axis, -h along each, +h along two (columns 0, 1-3, 4-6, 7-9)
                for e in range(10):
                    xs[e], ys[e], zs[e] = points[f, i, q, 0], points[f, i, q, 1], points[f, i, q, 2]
                xs[1] += h
                ys[2] += h
                zs[3] += h
                xs[4] -= h
                ys[5] -= h
                zs[6] -= h
                xs[7] += h
                ys[7] += h
                xs[8] += h
                zs[8] += h
                ys[9] += h
                zs[9] += h
                point_loss(xs, ys, zs, proposals[f, q], weights[f, q], constants, term)
                total += term[0]
                for a in range(3):
                    gradients[f, i, q, a] = (term[1 + a] - term[4 + a]) / (2.0 * h)
                    H[a, a] = (term[1 + a] - 2.0 * term[0] + term[4 + a]) / (h * h)
                H[0, 1] = H[1, 0] = (term[7] - term[1] - term[2] + term[0]) / (h * h)
                H[0, 2] = H[2, 0] = (term[8] - term[1] - term[3] + term[0]) / (h * h)
                H[1, 2] = H[2, 1] = (term[9] - term[2] - term[3] + term[0]) / (h * h)
                positive_part(H, hessians[f, i, q])
            losses[f, i] = total


@nb.njit(cache=True, nogil=True)
def assemble(subset, fresh, jacobians, point_gradients, hessians, gradients, curvatures):
    """gradients[f, i] = sum_q J^T g_q (d,) and curvatures[f, i] = sum_q J^T H_q J (d, d) over
    ``subset``, for the ``fresh`` frames."""
    F, m = jacobians.shape[0], jacobians.shape[1]
    d = jacobians.shape[4]
    bent = np.empty((3, d))
    moving = np.empty(d, dtype=np.int64)  # the parameters that move the point (its Jacobian's nonzero columns)
    for f in range(F):
        if not fresh[f]:
            continue
        for i in range(m):
            grad, curv = gradients[f, i], curvatures[f, i]
            grad[:] = 0.0
            curv[:, :] = 0.0
            for t in range(subset.shape[0]):
                q = subset[t]
                J, g, Hq = jacobians[f, i, q], point_gradients[f, i, q], hessians[f, i, q]
                if g[0] == 0.0 and g[1] == 0.0 and g[2] == 0.0 and Hq[0, 0] == 0.0 and Hq[1, 1] == 0.0 \
                        and Hq[2, 2] == 0.0:
                    continue  # no pull (no proposals, or a flat loss there)
                n = 0
                for k in range(d):
                    if J[0, k] != 0.0 or J[1, k] != 0.0 or J[2, k] != 0.0:
                        moving[n] = k
                        n += 1
                for e in range(n):
                    k = moving[e]
                    grad[k] += g[0] * J[0, k] + g[1] * J[1, k] + g[2] * J[2, k]
                    for a in range(3):
                        bent[a, k] = Hq[a, 0] * J[0, k] + Hq[a, 1] * J[1, k] + Hq[a, 2] * J[2, k]
                for e in range(n):
                    k = moving[e]
                    for e2 in range(e + 1):
                        l = moving[e2]
                        curv[k, l] += J[0, k] * bent[0, l] + J[1, k] * bent[1, l] + J[2, k] * bent[2, l]
            for k in range(d):
                for l in range(k):
                    curv[l, k] = curv[k, l]


def derivative_setup(tree, point_map, P: int, subset: np.ndarray, d: int):
    """(ints, floats): the block set-up :func:`pose_jacobians` reads, all P parameters moving,
    for the points ``subset`` over d + 1 columns."""
    return block_setup(*tree, *point_map, np.zeros((0, P)), np.arange(P, dtype=np.int64), subset, subset, d + 1)


def compiled_point_derivatives(function):
    """:func:`point_derivatives` compiled with the per-point loss ``function`` inlined."""
    return specialise(point_derivatives, function)
