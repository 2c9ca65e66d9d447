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

The loop (:func:`derivative_blocks`) is compiled with the objective's ``point_loss`` inlined
(:func:`~hybridfit.point_loss.specialise`), as the driver's scoring loop is. A row costs what
a forward-difference gradient would, ``d + 1`` evaluations (:class:`~hybridfit.task.DerivativeSteps`).
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


@nb.njit(cache=True, nogil=True, inline="always")
def positive_part(H, out):
    """out (3, 3) = the symmetric H (3, 3) with its negative eigenvalues set to 0."""
    values, vectors = np.linalg.eigh(H)
    for a in range(3):
        for b in range(3):
            s = 0.0
            for e in range(3):
                if values[e] > 0.0:
                    s += vectors[a, e] * values[e] * vectors[b, e]
            out[a, b] = s


def derivative_blocks(constants, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params,
                      mirror, pm_ptr, pm_joint, pm_weight, ints, floats, base, pidx, subset, X, losses, gradients,
                      curvatures):
    """losses[f, :m], gradients[f, :m] (d,), curvatures[f, :m] (d, d) of frame f's hypotheses
    X[f] (m, d) over the points ``subset``, the parameters ``pidx`` (d,) moving from ``base``
    (F, P); proposals (F, Q, K, 3) mm, weights (F, Q, K); ``ints``, ``floats``: a
    :func:`block_setup` of all parameters for ``subset`` over d + 1 columns."""
    F, m, d = X.shape
    P = base.shape[1]
    Q = weights.shape[1]
    poses = np.empty((d + 1, P))
    pts = np.empty((Q, 3, d + 1))
    steps = np.empty(d)
    jac = np.empty((3, d))
    bent = np.empty((3, d))
    H = np.empty((3, 3))
    Hp = np.empty((3, 3))
    g = np.empty(3)
    xs, ys, zs, term = np.empty(10), np.empty(10), np.empty(10), np.empty(10)
    h = POINT_STEP_MM
    for f in range(F):
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
            total = 0.0
            grad, curv = gradients[f, i], curvatures[f, i]
            grad[:] = 0.0
            curv[:, :] = 0.0
            for t in range(subset.shape[0]):
                q = subset[t]
                if not has_proposals(weights[f, q]):
                    continue
                # the point, +-h along each axis, +h along two axes (columns 0, 1-3, 4-6, 7-9)
                for e in range(10):
                    xs[e], ys[e], zs[e] = pts[q, 0, 0], pts[q, 1, 0], pts[q, 2, 0]
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
                    g[a] = (term[1 + a] - term[4 + a]) / (2.0 * h)
                    H[a, a] = (term[1 + a] - 2.0 * term[0] + term[4 + a]) / (h * h)
                H[0, 1] = H[1, 0] = (term[7] - term[1] - term[2] + term[0]) / (h * h)
                H[0, 2] = H[2, 0] = (term[8] - term[1] - term[3] + term[0]) / (h * h)
                H[1, 2] = H[2, 1] = (term[9] - term[2] - term[3] + term[0]) / (h * h)
                positive_part(H, Hp)
                for k in range(d):
                    for a in range(3):
                        jac[a, k] = (pts[q, a, 1 + k] - pts[q, a, 0]) / steps[k]
                    grad[k] += g[0] * jac[0, k] + g[1] * jac[1, k] + g[2] * jac[2, k]
                    for a in range(3):
                        bent[a, k] = Hp[a, 0] * jac[0, k] + Hp[a, 1] * jac[1, k] + Hp[a, 2] * jac[2, k]
                for k in range(d):
                    for l in range(k + 1):
                        s = jac[0, k] * bent[0, l] + jac[1, k] * bent[1, l] + jac[2, k] * bent[2, l]
                        curv[k, l] += s
            for k in range(d):
                for l in range(k):
                    curv[l, k] = curv[k, l]
            losses[f, i] = total


def derivative_setup(tree, point_map, P: int, subset: np.ndarray, d: int):
    """(ints, floats): the block set-up :func:`derivative_blocks` reads, all P parameters
    moving, for the points ``subset`` over d + 1 columns."""
    return block_setup(*tree, *point_map, np.zeros((0, P)), np.arange(P, dtype=np.int64), subset, subset, d + 1)


def compiled_derivatives(function):
    """:func:`derivative_blocks` compiled with the per-point loss ``function`` inlined."""
    return specialise(derivative_blocks, function)
