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
def block_frames(m, pB, sinB, cosB, joints, count, oriented, parents, offsets, rest, rest_identity, axes,
                  axis_params, mirror, WB, WpB, GB):
    """Camera-frame rotations and positions of the joints ``joints[:count]`` (parents first)
    for the first m hypotheses at once, the hypothesis the innermost axis (every loop
    vectorises): parameters pB (P, n), their sines and cosines sinB, cosB (P, n) (needed for
    the listed joints' angles), rotations WB (J, 3, 3, n) (mirror included; only where
    ``oriented[j]``: the joints whose rotation a listed child reads) and positions WpB
    (J, 3, n) mm. The entries of joints not listed are read as they are (fixed joints); GB
    (3, 3, n) is scratch space for the global rotation, computed when the root is listed."""
    if count and parents[joints[0]] < 0:  # the root moves: the global pose of each hypothesis
        for i in range(m):
            w, x, y, z = pB[3, i], pB[4, i], pB[5, i], pB[6, i]
            nq = w * w + x * x + y * y + z * z
            if nq < 1e-24:
                w, x, y, z, nq = 1.0, 0.0, 0.0, 0.0, 1.0
            sq = 2.0 / nq
            GB[0, 0, i] = (1.0 - sq * (y * y + z * z)) * mirror
            GB[0, 1, i] = sq * (x * y - w * z)
            GB[0, 2, i] = sq * (x * z + w * y)
            GB[1, 0, i] = sq * (x * y + w * z) * mirror
            GB[1, 1, i] = 1.0 - sq * (x * x + z * z)
            GB[1, 2, i] = sq * (y * z - w * x)
            GB[2, 0, i] = sq * (x * z - w * y) * mirror
            GB[2, 1, i] = sq * (y * z + w * x)
            GB[2, 2, i] = 1.0 - sq * (x * x + y * y)
    for c in range(count):
        j = joints[c]
        par = parents[j]
        o0, o1, o2 = offsets[j, 0], offsets[j, 1], offsets[j, 2]
        if par < 0:
            for r in range(3):
                for i in range(m):
                    WpB[j, r, i] = GB[r, 0, i] * o0 + GB[r, 1, i] * o1 + GB[r, 2, i] * o2 + pB[r, i]
            if not oriented[j]:
                continue
            for r in range(3):
                for k in range(3):
                    q0, q1, q2 = rest[j, 0, k], rest[j, 1, k], rest[j, 2, k]
                    for i in range(m):
                        WB[j, r, k, i] = GB[r, 0, i] * q0 + GB[r, 1, i] * q1 + GB[r, 2, i] * q2
        else:
            for r in range(3):
                for i in range(m):
                    WpB[j, r, i] = WpB[par, r, i] + WB[par, r, 0, i] * o0 + WB[par, r, 1, i] * o1 + WB[par, r, 2, i] * o2
            if not oriented[j]:
                continue
            if rest_identity[j]:
                for r in range(3):
                    for k in range(3):
                        for i in range(m):
                            WB[j, r, k, i] = WB[par, r, k, i]
            else:
                for r in range(3):
                    for k in range(3):
                        q0, q1, q2 = rest[j, 0, k], rest[j, 1, k], rest[j, 2, k]
                        for i in range(m):
                            WB[j, r, k, i] = WB[par, r, 0, i] * q0 + WB[par, r, 1, i] * q1 + WB[par, r, 2, i] * q2
        for a in range(axes.shape[1]):
            ax = axes[j, a]
            if ax < 0:
                break
            kp = axis_params[j, a]
            if ax == 0:
                i0, i1 = 1, 2
            elif ax == 1:
                i0, i1 = 2, 0
            else:
                i0, i1 = 0, 1
            for r in range(3):
                for i in range(m):
                    a0 = WB[j, r, i0, i]
                    a1 = WB[j, r, i1, i]
                    WB[j, r, i0, i] = cosB[kp, i] * a0 + sinB[kp, i] * a1
                    WB[j, r, i1, i] = cosB[kp, i] * a1 - sinB[kp, i] * a0


@nb.njit(cache=True, fastmath=True)
def block_points(m, WpB, pm_ptr, pm_joint, pm_weight, indices, lo, hi, out, first=0):
    """Points indices[lo:hi] of the m hypotheses in columns first, first + 1, ... of WpB:
    out[q, :, i] = sum_j point_map[q, j] WpB[j, :, first + i] (out (Q, 3, n) mm)."""
    for t in range(lo, hi):
        q = indices[t]
        e0 = pm_ptr[q]
        j0 = pm_joint[e0]
        w0 = pm_weight[e0]
        for i in range(m):  # one loop per point and joint, not per coordinate: a swarm is short
            out[q, 0, i] = w0 * WpB[j0, 0, first + i]
            out[q, 1, i] = w0 * WpB[j0, 1, first + i]
            out[q, 2, i] = w0 * WpB[j0, 2, first + i]
        for e in range(e0 + 1, pm_ptr[q + 1]):
            j = pm_joint[e]
            w = pm_weight[e]
            for i in range(m):
                out[q, 0, i] += w * WpB[j, 0, first + i]
                out[q, 1, i] += w * WpB[j, 1, first + i]
                out[q, 2, i] += w * WpB[j, 2, first + i]


@nb.njit(cache=True)
def mark_needed(parents, pm_ptr, pm_joint, points, needed):
    """The one "which joints are needed" walker: sets ``needed[j]`` (J,) bool for every joint
    that the points ``points`` (m,) read (the point map (Q, J) in CSR form: pm_ptr (Q + 1,),
    pm_joint) and for all their ancestors."""
    for t in range(points.shape[0]):
        q = points[t]
        for e in range(pm_ptr[q], pm_ptr[q + 1]):
            j = pm_joint[e]
            while j >= 0 and not needed[j]:
                needed[j] = True
                j = parents[j]


@nb.njit(cache=True)
def tree_forward(params, parents, offsets, rest, rest_is_identity, axes, axis_params, mirror, active, out):
    """params (N, P) -> out (N, J, 3) mm: forward kinematics of a KinematicTree.

    Only joints with ``active[j]`` are computed (the others are NaN); the active set must
    contain the parents of its joints. Works on blocks of hypotheses with the hypothesis as
    the innermost, contiguous axis (:func:`block_frames`)."""
    N, P = params.shape
    J = parents.shape[0]
    A = axes.shape[1]
    pB = np.empty((P, BLOCK))
    sinB = np.empty((P, BLOCK))
    cosB = np.empty((P, BLOCK))
    WB = np.empty((J, 3, 3, BLOCK))
    WpB = np.empty((J, 3, BLOCK))
    GB = np.empty((3, 3, BLOCK))
    order = np.empty(J, dtype=np.int64)
    count = 0
    for j in range(J):
        if active[j]:
            order[count] = j
            count += 1
    oriented = np.ones(J, dtype=np.bool_)
    rows = np.empty(P, dtype=np.int64)  # the parameters that are angles of active joints
    angle = np.zeros(P, dtype=np.bool_)
    for j in range(J):
        for a in range(A):
            if active[j] and axes[j, a] >= 0:
                angle[axis_params[j, a]] = True
    n_rows = 0
    for k in range(P):
        if angle[k]:
            rows[n_rows] = k
            n_rows += 1
    for n0 in range(0, N, BLOCK):
        B = min(BLOCK, N - n0)
        for i in range(B):
            for k in range(P):
                pB[k, i] = params[n0 + i, k]
        sincos_rows(rows, n_rows, pB, sinB, cosB, B)
        block_frames(B, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_is_identity, axes,
                     axis_params, mirror, WB, WpB, GB)
        for i in range(B):
            for j in range(J):
                for c in range(3):
                    out[n0 + i, j, c] = WpB[j, c, i] if active[j] else np.nan
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
            parents = np.ascontiguousarray(self._tree.parents, dtype=np.int64)
            active = np.zeros(len(parents), dtype=np.bool_)
            # each joint is its own point: the identity point map
            mark_needed(parents, np.arange(len(parents) + 1, dtype=np.int64), np.arange(len(parents), dtype=np.int64),
                        joints, active)
            self._active_cache[key] = active
        return active

    def _forward(self, params: np.ndarray, joints=None) -> np.ndarray:
        t = self._tree
        active = self._all_active if joints is None else self.active_joints(joints)
        out = np.empty((params.shape[0], len(t.parents), 3))
        return tree_forward(params, t.parents, t.offsets, t.rest, t.rest_is_identity, t.axes, t.axis_params,
                            float(t.mirror), active, out)
def scratch_size(P: int, J: int, Q: int) -> int:
    """Floats of :func:`tree_points`' working space for P parameters, J joints and Q points."""
    return BLOCK * (3 * P + 12 * J + 9 + 3 * Q)


@nb.njit(cache=True, nogil=True)
def tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                order, count, oriented, rows, n_rows, params, subset, out, scratch):
    """out (Q, 3, N) mm = the points ``subset`` of params (N, P), the hypothesis innermost (a
    compiled kernel's input): forward kinematics of the joints ``order[:count]`` (their
    rotations where ``oriented``, angles ``rows[:n_rows]``), in blocks of ``BLOCK``; scratch:
    working space of :func:`scratch_size` (P, J, Q) floats."""
    N, P = params.shape
    J = parents.shape[0]
    Q = out.shape[0]
    at = 0
    pB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    sinB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    cosB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    WB = scratch[at:at + J * 9 * BLOCK].reshape((J, 3, 3, BLOCK))
    at += J * 9 * BLOCK
    WpB = scratch[at:at + J * 3 * BLOCK].reshape((J, 3, BLOCK))
    at += J * 3 * BLOCK
    GB = scratch[at:at + 9 * BLOCK].reshape((3, 3, BLOCK))
    at += 9 * BLOCK
    pts = scratch[at:at + Q * 3 * BLOCK].reshape((Q, 3, BLOCK))
    for n0 in range(0, N, BLOCK):
        B = min(BLOCK, N - n0)
        for i in range(B):
            for k in range(P):
                pB[k, i] = params[n0 + i, k]
        sincos_rows(rows, n_rows, pB, sinB, cosB, B)
        block_frames(B, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_identity, axes,
                     axis_params, mirror, WB, WpB, GB)
        if N <= BLOCK:  # one block: straight into out
            block_points(B, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out)
            return
        block_points(B, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts)
        for t in range(subset.shape[0]):
            q = subset[t]
            for c in range(3):
                for i in range(B):
                    out[q, c, n0 + i] = pts[q, c, i]
