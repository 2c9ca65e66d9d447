"""Hand models described as data: a kinematic tree, and its batched forward kinematics.

A :class:`KinematicTree` is the model's one kinematic description. The numba kernel here
evaluates it for N parameter vectors at once, and other consumers (the CasADi inverse
kinematics, calibration) build on the same description, so there is never a second
hand-written copy of a model's kinematics.

Frames: joint j's frame is ``R_j = R_parent @ rest_j @ Rot(axis_1, theta_1) @ ...``; its
position ``p_j = p_parent + R_parent @ offset_j``; the root's parent is the hand frame.
Hand-frame points are mirrored (x negated) for a left hand, then rotated by the global
quaternion (parameters 3..6) and translated by parameters 0..2.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numba as nb
import numpy as np

from .rotations import quaternion_matrix
from .base import HandModel

X_AXIS, Y_AXIS, Z_AXIS, NO_AXIS = 0, 1, 2, -1


@dataclass(frozen=True, eq=False)
class KinematicTree:
    """parents (J,) int, -1 for the root, parents before children; offsets (J, 3) mm in
    the parent's frame; rest (J, 3, 3) fixed rotation relative to the parent's frame;
    axes (J, A) rotation axes applied in order at each joint (0 x, 1 y, 2 z, -1 none);
    axis_params (J, A) the parameter index of each angle (radians); mirror: +1 right
    hand, -1 left hand (x negated in the hand frame)."""

    parents: np.ndarray
    offsets: np.ndarray
    rest: np.ndarray
    axes: np.ndarray
    axis_params: np.ndarray
    mirror: float = 1.0

    def __post_init__(self) -> None:
        J = len(self.parents)
        assert self.offsets.shape == (J, 3) and self.rest.shape == (J, 3, 3)
        assert self.axes.shape == self.axis_params.shape and len(self.axes) == J
        assert all(p < j for j, p in enumerate(self.parents)), "parents must precede children"

    @cached_property
    def rest_is_identity(self) -> np.ndarray:
        # (J,) bool, vectorised: np.allclose per joint cost 1.7 ms per model build
        return np.all(np.abs(np.asarray(self.rest) - np.eye(3)) <= 1e-8 + 1e-5 * np.eye(3), axis=(1, 2))


#: fast-math flags without reassociation (the range reduction below relies on evaluation order)
_NO_REASSOC = {"nnan", "ninf", "nsz", "arcp", "contract", "afn"}
_PIO2_1, _PIO2_2, _PIO2_3 = 1.5707963267341256, 6.077100506506192e-11, 2.0222662487959506e-21


@nb.njit(cache=True, fastmath=_NO_REASSOC, inline="always")
def sincos1(v):
    """(sin v, cos v) for |v| < 1e6 radians: Cody-Waite reduction to [-pi/4, pi/4] and Taylor
    polynomials, within a few ulp of libm. Branch-free, so loops over it vectorise (numba has
    no vector sin/cos without SVML)."""
    k = np.floor(v * 0.6366197723675814 + 0.5)
    r = ((v - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    r2 = r * r
    sr = r + r * r2 * (-0.16666666666666666 + r2 * (0.008333333333333333 + r2 * (-0.0001984126984126984 + r2 * (
        2.7557319223985893e-06 + r2 * (-2.505210838544172e-08 + r2 * (1.6059043836821613e-10
                                                                     + r2 * -7.647163731819816e-13))))))
    cr = 1.0 + r2 * (-0.5 + r2 * (0.041666666666666664 + r2 * (-0.001388888888888889 + r2 * (
        2.48015873015873e-05 + r2 * (-2.755731922398589e-07 + r2 * (2.08767569878681e-09 + r2 * (
            -1.1470745597729725e-11 + r2 * 4.779477332387385e-14)))))))
    q = np.int64(k) & 3
    swap = (q & 1) == 1
    a = cr if swap else sr
    b = sr if swap else cr
    return (-a if q >= 2 else a), (-b if q == 1 or q == 2 else b)


@nb.njit(cache=True, fastmath=_NO_REASSOC)
def sincos(x, s, c):
    """Elementwise s = sin(x), c = cos(x) of C-contiguous arrays of the same shape (radians,
    |x| < 1e6; see :func:`sincos1`)."""
    xf = x.reshape(-1)
    sf = s.reshape(-1)
    cf = c.reshape(-1)
    for i in range(xf.size):
        sf[i], cf[i] = sincos1(xf[i])


@nb.njit(cache=True, fastmath=_NO_REASSOC)
def sincos_rows(rows, count, x, s, c, m):
    """s[k, :m], c[k, :m] = sin, cos of x[k, :m] for k in rows[:count] (x, s, c (P, n))."""
    for t in range(count):
        k = rows[t]
        for i in range(m):
            s[k, i], c[k, i] = sincos1(x[k, i])


#: hypotheses per block of :func:`tree_forward` (its loops over a block vectorise)
BLOCK = 64


@nb.njit(cache=True, fastmath=True)
def tree_forward(params, parents, offsets, rest, rest_is_identity, axes, axis_params, mirror, active, out):
    """params (N, P) -> out (N, J, 3) mm: forward kinematics of a KinematicTree.

    Only joints with ``active[j]`` are computed (the others are NaN); the active set must
    contain the parents of its joints. Works on blocks of hypotheses with the hypothesis as
    the innermost, contiguous axis, so that every step is a vector operation."""
    N, P = params.shape
    J = parents.shape[0]
    A = axes.shape[1]
    G = np.empty((3, 3, BLOCK))
    R = np.empty((J, 3, 3, BLOCK))
    pos = np.empty((J, 3, BLOCK))
    pT = np.empty((P, BLOCK))
    sin_p = np.empty((P, BLOCK))
    cos_p = np.empty((P, BLOCK))
    world = np.empty((3, BLOCK))
    angle = np.zeros(P, dtype=np.bool_)  # the parameters that are angles of active joints
    for j in range(J):
        for a in range(A):
            if active[j] and axes[j, a] >= 0:
                angle[axis_params[j, a]] = True
    for n0 in range(0, N, BLOCK):
        B = min(BLOCK, N - n0)
        for i in range(B):
            for k in range(P):
                pT[k, i] = params[n0 + i, k]
            quaternion_matrix(pT[3, i], pT[4, i], pT[5, i], pT[6, i], G[:, :, i])
        for k in range(P):  # every angle of the block at once
            if angle[k]:
                sincos(pT[k], sin_p[k], cos_p[k])
        for j in range(J):
            if not active[j]:
                continue
            par = parents[j]
            if par < 0:
                for r in range(3):
                    for i in range(B):
                        pos[j, r, i] = offsets[j, r]
                    for c in range(3):
                        for i in range(B):
                            R[j, r, c, i] = rest[j, r, c]
            else:
                o0, o1, o2 = offsets[j, 0], offsets[j, 1], offsets[j, 2]
                for r in range(3):
                    for i in range(B):
                        pos[j, r, i] = pos[par, r, i] + R[par, r, 0, i] * o0 + R[par, r, 1, i] * o1 + R[par, r, 2, i] * o2
                if rest_is_identity[j]:
                    for r in range(3):
                        for c in range(3):
                            for i in range(B):
                                R[j, r, c, i] = R[par, r, c, i]
                else:
                    for r in range(3):
                        for c in range(3):
                            q0, q1, q2 = rest[j, 0, c], rest[j, 1, c], rest[j, 2, c]
                            for i in range(B):
                                R[j, r, c, i] = R[par, r, 0, i] * q0 + R[par, r, 1, i] * q1 + R[par, r, 2, i] * q2
            for a in range(A):
                ax = axes[j, a]
                if ax < 0:
                    break
                k = axis_params[j, a]
                # right-multiplying by a rotation about a local axis mixes two columns
                if ax == 0:
                    i0, i1 = 1, 2
                elif ax == 1:
                    i0, i1 = 2, 0
                else:
                    i0, i1 = 0, 1
                for r in range(3):
                    for i in range(B):
                        a0 = R[j, r, i0, i]
                        a1 = R[j, r, i1, i]
                        R[j, r, i0, i] = cos_p[k, i] * a0 + sin_p[k, i] * a1
                        R[j, r, i1, i] = cos_p[k, i] * a1 - sin_p[k, i] * a0
        for j in range(J):
            if not active[j]:
                for i in range(B):
                    for c in range(3):
                        out[n0 + i, j, c] = np.nan
                continue
            for c in range(3):  # to camera coordinates, vectorised, then stored per hypothesis
                for i in range(B):
                    world[c, i] = G[c, 0, i] * (mirror * pos[j, 0, i]) + G[c, 1, i] * pos[j, 1, i] \
                        + G[c, 2, i] * pos[j, 2, i] + pT[c, i]
            for i in range(B):
                for c in range(3):
                    out[n0 + i, j, c] = world[c, i]
    return out


class TreeHandModel(HandModel):
    """A HandModel whose kinematics are a :class:`KinematicTree` (subclasses build it)."""

    def kinematic_tree(self) -> KinematicTree:
        raise NotImplementedError

    @cached_property
    def _tree(self) -> KinematicTree:
        return self.kinematic_tree()

    @property
    def parents(self) -> np.ndarray:
        return self._tree.parents

    @cached_property
    def _all_active(self) -> np.ndarray:
        return np.ones(len(self._tree.parents), dtype=np.bool_)

    @cached_property
    def _active_cache(self) -> dict[bytes, np.ndarray]:
        return {}

    def active_joints(self, joints) -> np.ndarray:
        """(J,) bool: the given joints and all their ancestors (cached per joint set)."""
        joints = np.asarray(joints, dtype=np.int64)
        key = joints.tobytes()
        active = self._active_cache.get(key)
        if active is None:
            parents = self._tree.parents
            active = np.zeros(len(parents), dtype=np.bool_)
            for j in joints:
                while j >= 0 and not active[j]:
                    active[j] = True
                    j = parents[j]
            self._active_cache[key] = active
        return active

    def _forward(self, params: np.ndarray, joints=None) -> np.ndarray:
        t = self._tree
        active = self._all_active if joints is None else self.active_joints(joints)
        out = np.empty((params.shape[0], len(t.parents), 3))
        return tree_forward(params, t.parents, t.offsets, t.rest, t.rest_is_identity, t.axes, t.axis_params,
                            float(t.mirror), active, out)
