"""Hand models described as data: a kinematic tree, and its batched forward kinematics.

A :class:`KinematicTree` is the model's one kinematic description. The numba kernel here
evaluates it for N parameter vectors at once, and other consumers (the CasADi inverse
kinematics, calibration) build on the same description, so there is never a second
hand-written copy of a model's kinematics.

One kernel, one walker, one block entry, shared by the model, the Problem and the driver:
:func:`block_frames` computes the listed joints of a block of hypotheses (the hypothesis the
innermost axis); :func:`mark_needed` finds the joints a set of points needs;
:func:`block_setup` lays out a block computation (which joints and angles move, which are
fixed at a base, the buffers) and :func:`block_kinematics` runs it for one or several frames'
hypotheses. :func:`tree_points` is that entry with all parameters moving (``model.forward``,
laid out once per thread and tree, and the derivatives); the driver's scorers
(:mod:`hybridfit.fitting.evaluator`) use it with a stage's parameters moving.

Frames: joint j's frame is ``R_j = R_parent @ rest_j @ Rot(axis_1, theta_1) @ ...``; its
position ``p_j = p_parent + R_parent @ offset_j``; the root's parent is the hand frame.
Hand-frame points are mirrored (x negated) for a left hand, then rotated by the global
quaternion (parameters 3..6) and translated by parameters 0..2.
"""

from __future__ import annotations

import threading
import weakref
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


@nb.njit(cache=True, fastmath=True)
def block_frames(m, pB, sinB, cosB, joints, count, oriented, parents, offsets, rest, rest_identity, axes,
                  axis_params, mirror, WB, WpB, GB):
    """Camera-frame rotations and positions of the joints ``joints[:count]`` (parents first)
    for the first m hypotheses at once, the hypothesis the innermost axis (every loop
    vectorises): parameters pB (P, n), their sines and cosines sinB, cosB (P, n) (needed for
    the listed joints' angles), rotations WB (J, 3, 3, n) (mirror included; only where bit 1
    of ``oriented[j]`` is set: the joints whose rotation a listed child reads) and positions
    WpB (J, 3, n) mm. The entries of joints not listed are read as they are (fixed joints).
    Bit 2 of ``oriented[j]`` marks a listed joint as *preset*: its position and its frame
    before its own rotations are already in WpB, WB (a joint whose parent is fixed: they are
    the same for every hypothesis of a frame), so only its rotations are applied. GB (3, 3, n)
    is scratch space for the global rotation, computed when the root is listed."""
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
        if oriented[j] & 2:
            if not oriented[j] & 1:
                continue
        elif par < 0:
            for r in range(3):
                for i in range(m):
                    WpB[j, r, i] = GB[r, 0, i] * o0 + GB[r, 1, i] * o1 + GB[r, 2, i] * o2 + pB[r, i]
            if not oriented[j] & 1:
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
            if not oriented[j] & 1:
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
def block_points(m, WpB, pm_ptr, pm_joint, pm_weight, indices, lo, hi, out, first=0, at=0):
    """Points indices[lo:hi] of the m hypotheses in columns first, first + 1, ... of WpB:
    out[q, :, at + i] = sum_j point_map[q, j] WpB[j, :, first + i] (out (Q, 3, n) mm)."""
    for t in range(lo, hi):
        q = indices[t]
        e0 = pm_ptr[q]
        j0 = pm_joint[e0]
        w0 = pm_weight[e0]
        for i in range(m):  # one loop per point and joint, not per coordinate: a swarm is short
            out[q, 0, at + i] = w0 * WpB[j0, 0, first + i]
            out[q, 1, at + i] = w0 * WpB[j0, 1, first + i]
            out[q, 2, at + i] = w0 * WpB[j0, 2, first + i]
        for e in range(e0 + 1, pm_ptr[q + 1]):
            j = pm_joint[e]
            w = pm_weight[e]
            for i in range(m):
                out[q, 0, at + i] += w * WpB[j, 0, first + i]
                out[q, 1, at + i] += w * WpB[j, 1, first + i]
                out[q, 2, at + i] += w * WpB[j, 2, first + i]


@nb.njit(cache=True, inline="always")
def mark_with_ancestors(parents, j, needed):
    """The one walk up the tree: sets ``needed`` (J,) bool for joint j (none if j < 0) and its
    ancestors, stopping at a joint already set (so every joint set has its ancestors set)."""
    while j >= 0 and not needed[j]:
        needed[j] = True
        j = parents[j]


@nb.njit(cache=True)
def mark_needed(parents, pm_ptr, pm_joint, points, needed):
    """The one "which joints are needed" walker: sets ``needed[j]`` (J,) bool for every joint
    that the points ``points`` (m,) read (the point map (Q, J) in CSR form: pm_ptr (Q + 1,),
    pm_joint) and for all their ancestors."""
    for t in range(points.shape[0]):
        q = points[t]
        for e in range(pm_ptr[q], pm_ptr[q + 1]):
            mark_with_ancestors(parents, pm_joint[e], needed)


#: the tree's first parameters: position x, y, z (mm) and the quaternion w, x, y, z
GLOBAL_PARAMS = 7


#: header of a stage's integer array: counts of listed joints, joints copied from base, stage angle
#: rows, fixed parameter rows read; batch n, frames F, parameters P, joints J, points Q, frames
#: per block G
_HEADER = 10

#: hypotheses (of several frames) per block of the kinematics: the loops over a block are long
#: enough to vectorise well and its buffers stay in cache
COLUMNS = 256


@nb.njit(cache=True, nogil=True, inline="always")
def block_lists(ints, J, P):
    """The index lists of a block computation's ints (after its header): the joints to
    recompute in order, the joints whose rotation is read (bit 1) and the preset ones (bit 2,
    see :func:`block_frames`), the joints copied from base per frame (the fixed joints a point
    reads and the preset joints) (J, each); the stage's angle rows, the fixed parameter rows
    read and each parameter's position in the stage or -1 (P, each)."""
    return (ints[_HEADER:_HEADER + J], ints[_HEADER + J:_HEADER + 2 * J], ints[_HEADER + 2 * J:_HEADER + 3 * J],
            ints[_HEADER + 3 * J:_HEADER + 3 * J + P], ints[_HEADER + 3 * J + P:_HEADER + 3 * J + 2 * P],
            ints[_HEADER + 3 * J + 2 * P:])


@nb.njit(cache=True, nogil=True)
def block_setup(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                base, pidx, subset, owned, n, work=None):
    """A block computation of F frames whose parameters ``pidx`` (d,) move from ``base`` (F, P),
    for the points ``subset`` and ``owned`` (the point map (Q, J) in CSR form: pm_ptr,
    pm_joint, pm_weight), as (ints, floats): the joints to recompute per hypothesis (those the
    points need, :func:`mark_needed`, and the parameters move, parents first), the joints and
    parameters read but fixed, the angles to take sines of, every frame's fixed joints at
    ``base`` and, for a recomputed joint whose parent is fixed (preset), its position and
    frame below its own rotations (the other joints' rows of W0, Wp0 are left unset), and
    block buffers for G frames' batches of up to n hypotheses side by side (G = COLUMNS // n,
    at least 1; see :func:`block_views`). ``work``: a float64 buffer whose start becomes
    ``floats`` where it is large enough (one buffer for a run's stages: a fresh one each stage
    costs page faults), else a new one."""
    F, P = base.shape
    J = parents.shape[0]
    Q = pm_ptr.shape[0] - 1
    A = axes.shape[1]
    n = max(n, 1)
    needed = np.zeros(J, dtype=np.bool_)
    mark_needed(parents, pm_ptr, pm_joint, subset, needed)
    mark_needed(parents, pm_ptr, pm_joint, owned, needed)
    ints = np.zeros(_HEADER + 3 * J + 3 * P, dtype=np.int64)
    order, oriented, fixed, rows, frows, stage_pos = block_lists(ints, J, P)
    stage_pos[:] = -1
    is_global = False
    for t in range(pidx.shape[0]):
        stage_pos[pidx[t]] = t
        if pidx[t] < GLOBAL_PARAMS:
            is_global = True
    is_angle = np.zeros(P, dtype=np.bool_)
    for j in range(J):
        for a in range(A):
            if axes[j, a] >= 0:
                is_angle[axis_params[j, a]] = True
    for j in range(J):
        if needed[j] and parents[j] >= 0:
            oriented[parents[j]] = 1
    listed = np.zeros(J, dtype=np.bool_)
    variable = np.zeros(J, dtype=np.bool_)
    count = 0
    for j in range(J):
        v = is_global or (parents[j] >= 0 and variable[parents[j]])
        for a in range(A):
            if axes[j, a] >= 0 and stage_pos[axis_params[j, a]] >= 0:
                v = True
        variable[j] = v
        if v and needed[j]:
            order[count] = j
            listed[j] = True
            count += 1
    # a listed joint whose parent is fixed is preset: its position and frame before its own
    # rotations are the same for all of a frame's hypotheses, copied per frame like a fixed
    # joint's; its parent is then read only at base (unless a point reads it)
    preset = np.zeros(J, dtype=np.bool_)
    for c in range(count):
        preset[order[c]] = parents[order[c]] >= 0 and not listed[parents[order[c]]]
    read = np.zeros(J, dtype=np.bool_)  # fixed joints that a point reads, and the preset joints
    for c in range(count):
        read[order[c]] = preset[order[c]]
    for t in range(subset.shape[0]):
        for e in range(pm_ptr[subset[t]], pm_ptr[subset[t] + 1]):
            read[pm_joint[e]] = True
    for t in range(owned.shape[0]):
        for e in range(pm_ptr[owned[t]], pm_ptr[owned[t] + 1]):
            read[pm_joint[e]] = True
    n_fixed = 0
    for j in range(J):
        if read[j] and (preset[j] or not listed[j]):
            fixed[n_fixed] = j
            n_fixed += 1
    # parameters the listed joints read: a joint's angles turn only its own frame, so those of a
    # joint whose rotation nothing reads (a point's joint at the end of a chain) are not read
    reads_param = np.zeros(P, dtype=np.bool_)
    if count and parents[order[0]] < 0:
        for k in range(GLOBAL_PARAMS):
            reads_param[k] = True
    for c in range(count):
        if not oriented[order[c]] & 1:
            continue
        for a in range(A):
            if axes[order[c], a] >= 0:
                reads_param[axis_params[order[c], a]] = True
    n_rows = 0
    n_frows = 0
    for k in range(P):
        if stage_pos[k] >= 0 and is_angle[k] and reads_param[k]:
            rows[n_rows] = k
            n_rows += 1
        elif stage_pos[k] < 0 and reads_param[k]:
            frows[n_frows] = k
            n_frows += 1
    for j in range(J):
        if preset[j]:
            oriented[j] |= 2
    ints[0], ints[1], ints[2], ints[3] = count, n_fixed, n_rows, n_frows
    G = max(1, min(F, COLUMNS // n))
    ints[4], ints[5], ints[6], ints[7], ints[8], ints[9] = n, F, P, J, Q, G
    C = G * n
    size = 3 * F * P + 12 * F * J + 3 * P * C + 12 * J * C + 9 * C + 3 * Q * C
    floats = work[:size] if work is not None and work.shape[0] >= size else np.empty(size)
    (b, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts) = block_views(ints, floats)
    b[:] = base
    # the frames' joints at base: the fixed joints copied, the preset joints' parents and
    # their ancestors; then the preset joints with their own angles at 0
    at_base = np.zeros(J, dtype=np.bool_)
    for t in range(n_fixed):
        j = fixed[t]
        mark_with_ancestors(parents, parents[j] if preset[j] else j, at_base)
    base_joints = np.flatnonzero(at_base)
    preset_joints = np.flatnonzero(preset)
    copied = np.flatnonzero(at_base | preset)
    all_oriented = np.ones(J, dtype=np.int64)
    for f0 in range(0, F, C):  # the fixed joints at base, C frames at once, by the same code as the hypotheses'
        B = min(C, F - f0)
        for k in range(P):
            for i in range(B):
                v = base[f0 + i, k]
                sv, cv = 0.0, 1.0
                if is_angle[k]:
                    sv, cv = sincos1(v)
                pB[k, i], sinB[k, i], cosB[k, i] = v, sv, cv
                bsin[f0 + i, k], bcos[f0 + i, k] = sv, cv
        block_frames(B, pB, sinB, cosB, base_joints, base_joints.shape[0], all_oriented, parents, offsets, rest,
                     rest_identity, axes, axis_params, mirror, WB, WpB, GB)
        for j in preset_joints:  # turned by 0: their frames before their own rotations
            for a in range(A):
                if axes[j, a] >= 0:
                    for i in range(B):
                        sinB[axis_params[j, a], i], cosB[axis_params[j, a], i] = 0.0, 1.0
        block_frames(B, pB, sinB, cosB, preset_joints, preset_joints.shape[0], all_oriented, parents, offsets, rest,
                     rest_identity, axes, axis_params, mirror, WB, WpB, GB)
        for i in range(B):
            for j in copied:
                for r in range(3):
                    Wp0[f0 + i, j, r] = WpB[j, r, i]
                    for c in range(3):
                        W0[f0 + i, j, r, c] = WB[j, r, c, i]
    return ints, floats


@nb.njit(cache=True, nogil=True, inline="always")
def block_views(ints, floats):
    """The arrays of a stage's floats: base, bsin, bcos (F, P); W0 (F, J, 3, 3), Wp0 (F, J, 3)
    the frames' joints at base (see :func:`block_setup`); block buffers pB, sinB, cosB (P, C), WB (J, 3, 3, C), WpB
    (J, 3, C), GB (3, 3, C) and points pts (Q, 3, C) with C = G n columns (frame g's
    hypothesis i in column g n + i)."""
    n, F, P, J, Q = ints[4], ints[5], ints[6], ints[7], ints[8]
    C = ints[9] * n
    a = 0
    b = floats[a:a + F * P].reshape((F, P))
    a += F * P
    bsin = floats[a:a + F * P].reshape((F, P))
    a += F * P
    bcos = floats[a:a + F * P].reshape((F, P))
    a += F * P
    W0 = floats[a:a + F * J * 9].reshape((F, J, 3, 3))
    a += F * J * 9
    Wp0 = floats[a:a + F * J * 3].reshape((F, J, 3))
    a += F * J * 3
    pB = floats[a:a + P * C].reshape((P, C))
    a += P * C
    sinB = floats[a:a + P * C].reshape((P, C))
    a += P * C
    cosB = floats[a:a + P * C].reshape((P, C))
    a += P * C
    WB = floats[a:a + J * 9 * C].reshape((J, 3, 3, C))
    a += J * 9 * C
    WpB = floats[a:a + J * 3 * C].reshape((J, 3, C))
    a += J * 3 * C
    GB = floats[a:a + 9 * C].reshape((3, 3, C))
    a += 9 * C
    pts = floats[a:a + Q * 3 * C].reshape((Q, 3, C))
    return b, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts


@nb.njit(cache=True, nogil=True, fastmath=True)
def block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X,
                     first=0, m=-1, particles_last=False):
    """The joints of frames f0 <= f < f1 (at most G) with hypotheses X[f, first:first + m]
    (X (F, >= first + m, d); m < 0: the rest of X) into the block buffers WpB, WB: frame f's
    hypothesis first + i in column (f - f0) m + i. With ``particles_last`` X is (F, d, >=
    first + m), the hypotheses innermost (copied into the block along its rows)."""
    (base, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts) = block_views(ints, floats)
    J, P = ints[7], ints[6]
    order, oriented, fixed, rows, frows, stage_pos = block_lists(ints, J, P)
    if m < 0:
        m = X.shape[2 if particles_last else 1] - first
    count, n_fixed, n_rows, n_frows = ints[0], ints[1], ints[2], ints[3]
    for f in range(f0, f1):
        at = (f - f0) * m
        for k in range(P):
            t = stage_pos[k]
            if t >= 0:
                if particles_last:
                    for i in range(m):
                        pB[k, at + i] = X[f, t, first + i]
                else:
                    for i in range(m):
                        pB[k, at + i] = X[f, first + i, t]
        for r in range(n_frows):
            k = frows[r]
            v, s, c = base[f, k], bsin[f, k], bcos[f, k]
            for i in range(at, at + m):
                pB[k, i] = v
                sinB[k, i] = s
                cosB[k, i] = c
        for t in range(n_fixed):  # one loop per fixed joint, not per entry: a swarm is short
            j = fixed[t]
            p0, p1, p2 = Wp0[f, j, 0], Wp0[f, j, 1], Wp0[f, j, 2]
            a00, a01, a02 = W0[f, j, 0, 0], W0[f, j, 0, 1], W0[f, j, 0, 2]
            a10, a11, a12 = W0[f, j, 1, 0], W0[f, j, 1, 1], W0[f, j, 1, 2]
            a20, a21, a22 = W0[f, j, 2, 0], W0[f, j, 2, 1], W0[f, j, 2, 2]
            for i in range(at, at + m):
                WpB[j, 0, i], WpB[j, 1, i], WpB[j, 2, i] = p0, p1, p2
                WB[j, 0, 0, i], WB[j, 0, 1, i], WB[j, 0, 2, i] = a00, a01, a02
                WB[j, 1, 0, i], WB[j, 1, 1, i], WB[j, 1, 2, i] = a10, a11, a12
                WB[j, 2, 0, i], WB[j, 2, 1, i], WB[j, 2, 2, i] = a20, a21, a22
    columns = (f1 - f0) * m
    for r in range(n_rows):
        k = rows[r]
        for i in range(columns):
            sinB[k, i], cosB[k, i] = sincos1(pB[k, i])
    block_frames(columns, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_identity, axes,
                 axis_params, mirror, WB, WpB, GB)


@nb.njit(cache=True, nogil=True)
def tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                ints, floats, params, subset, out):
    """out (Q, 3, N) mm = the points ``subset`` of params (N, P), the hypothesis innermost (a
    layout of the scoring loops), by the block kinematics of a :func:`block_setup` of all
    parameters moving, for ``subset``, over up to n columns (``ints``, ``floats``)."""
    N, P = params.shape
    n = ints[4]
    WpB = block_views(ints, floats)[9]
    X = params.reshape((1, N, P))
    for n0 in range(0, N, n):
        B = min(n, N - n0)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, 0, 1, X, n0, B)
        block_points(B, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out, 0, n0)


#: per thread (a setup holds working buffers), per kinematic tree: ``model.forward``'s
#: :func:`block_setup` (all parameters moving, every joint, :data:`COLUMNS` hypotheses a block)
_FORWARD_SETUPS = threading.local()


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

    def _forward(self, params: np.ndarray) -> np.ndarray:
        """:func:`tree_points` of every joint (the identity point map), as (N, J, 3)."""
        t = self._tree
        trees = getattr(_FORWARD_SETUPS, "trees", None)
        if trees is None:
            trees = _FORWARD_SETUPS.trees = weakref.WeakKeyDictionary()
        entry = trees.get(t)
        if entry is None:
            J, P = len(t.parents), self.n_params
            every = np.arange(J + 1, dtype=np.int64)
            arrays = (np.ascontiguousarray(t.parents, dtype=np.int64), np.ascontiguousarray(t.offsets, dtype=np.float64),
                      np.ascontiguousarray(t.rest, dtype=np.float64), np.ascontiguousarray(t.rest_is_identity),
                      np.ascontiguousarray(t.axes, dtype=np.int64), np.ascontiguousarray(t.axis_params, dtype=np.int64),
                      float(t.mirror), every, every[:J], np.ones(J))
            setup = block_setup(*arrays, np.zeros((0, P)), np.arange(P, dtype=np.int64), every[:J], every[:J], COLUMNS)
            entry = trees[t] = (arrays + setup, every[:J])
        arrays, joints = entry
        out = np.empty((len(joints), 3, len(params)))
        tree_points(*arrays, np.ascontiguousarray(params, dtype=np.float64), joints, out)
        return np.ascontiguousarray(out.transpose(2, 0, 1))
