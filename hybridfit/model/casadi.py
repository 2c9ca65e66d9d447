"""Symbolic forward kinematics of a :class:`~hybridfit.model.kinematics.KinematicTree` in CasADi.

The same frames and conventions as the numba kernel :func:`hybridfit.model.kinematics.tree_forward`
(see :mod:`hybridfit.model.kinematics`), built from the same data, so gradient-based solvers get
the model's exact kinematics without a second hand-written copy. CasADi is imported
lazily: importing this module does not need it; using it without CasADi installed raises
:class:`~hybridfit.optional.MissingLibrary` with the line that installs it.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..optional import import_library
from .kinematics import KinematicTree

#: right-multiplying by a rotation about local axis a mixes columns (i0, i1), as in tree_forward
_MIXED_COLUMNS = {0: (1, 2), 1: (2, 0), 2: (0, 1)}


def _casadi():
    return import_library("casadi", "hybridfit[casadi]", "hybridfit.model.casadi")


def quaternion_matrix_sx(w, x, y, z):
    """3x3 CasADi rotation matrix of the quaternion (w, x, y, z), normalised (zero -> identity)."""
    ca = _casadi()

    n = w * w + x * x + y * y + z * z
    s = ca.if_else(n < 1e-24, 0.0, 2.0 / n)
    return ca.vertcat(
        ca.horzcat(1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
        ca.horzcat(s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)),
        ca.horzcat(s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)),
    )


def _rotate_local(R, axis: int, theta):
    """R @ Rot(axis, theta) for a 3x3 CasADi matrix R."""
    ca = _casadi()

    i0, i1 = _MIXED_COLUMNS[axis]
    c, s = ca.cos(theta), ca.sin(theta)
    cols = [R[:, 0], R[:, 1], R[:, 2]]
    a0, a1 = cols[i0], cols[i1]
    cols[i0], cols[i1] = c * a0 + s * a1, c * a1 - s * a0
    return ca.horzcat(*cols)


def casadi_forward(tree: KinematicTree, params: Any | Sequence[Any]):
    """Joint positions of the tree as a CasADi expression.

    params: a (P, 1) CasADi SX/MX column, or a sequence of P scalars (CasADi expressions
    or numbers: constant parameters fold into constants). Returns a (J, 3) CasADi matrix
    of joint positions in mm, camera coordinates, row j = joint j.
    """
    ca = _casadi()

    p = [params[i] for i in range(params.shape[0])] if hasattr(params, "shape") else list(params)
    J = len(tree.parents)
    R: list = [None] * J
    pos: list = [None] * J
    for j in range(J):
        par = int(tree.parents[j])
        if par < 0:
            pos[j] = ca.DM(tree.offsets[j])
            R[j] = ca.DM(tree.rest[j])
        else:
            pos[j] = pos[par] + ca.mtimes(R[par], ca.DM(tree.offsets[j]))
            R[j] = R[par] if tree.rest_is_identity[j] else ca.mtimes(R[par], ca.DM(tree.rest[j]))
        for axis, index in zip(tree.axes[j], tree.axis_params[j]):
            if axis < 0:
                break
            R[j] = _rotate_local(R[j], int(axis), p[int(index)])
    G = quaternion_matrix_sx(p[3], p[4], p[5], p[6])
    mirror = ca.DM(np.diag([float(tree.mirror), 1.0, 1.0]))
    translation = ca.vertcat(p[0], p[1], p[2])
    rows = [(ca.mtimes(G, ca.mtimes(mirror, pos[j])) + translation).T for j in range(J)]
    return ca.vertcat(*rows)
