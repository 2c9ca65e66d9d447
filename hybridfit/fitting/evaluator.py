"""Scoring a stage's hypotheses for many frames at once: forward kinematics of the joints the
stage moves (:mod:`hybridfit.model.kinematics`' block kernel and walker), then the objective.

A *scorer* has two methods the driver (:mod:`.driver`) calls: ``prepare(base (F, P),
parameters (d,), points (m,), owned (o,), batch) -> stage`` once per stage, and ``score(stage,
X (F, m, d), points, losses (F, >= m))`` per generation: ``losses[:, :m]`` = each frame's
hypotheses (the parameters outside the stage at ``base``) scored over ``points``.

- :class:`KernelScorer`: a kinematic tree and an objective's compiled kernel: one numba call
  per generation for all frames of a group.
- :class:`NumpyScorer`: a kinematic tree's points by the same numba kinematics (or, for a model
  without a kinematic tree, its ``forward``), scored by the objective's ``score_frames`` (one
  call per generation for all frames) or ``bind`` (one call per frame). The points are handed
  over as a view of the kinematics' buffer, the hypothesis innermost in memory (no copy).
"""

from __future__ import annotations

import functools
import warnings

import numba as nb
from numba import types as T
from numba.core.dispatcher import Dispatcher
from numba.core.errors import NumbaWarning
import numpy as np

from ..errors import PluginError
from ..objective import KERNEL_SIGNATURE
from ..model.kinematics import block_frames, block_points, mark_needed, sincos1

#: the tree's first parameters: position x, y, z (mm) and the quaternion w, x, y, z
GLOBAL_PARAMS = 7


#: header of a stage's integer array: counts of listed joints, fixed joints read, stage angle
#: rows, fixed parameter rows read; batch n, frames F, parameters P, joints J, points Q, frames
#: per block G
_HEADER = 10

#: hypotheses (of several frames) per block of the kinematics: the loops over a block are long
#: enough to vectorise well and its buffers stay in cache
COLUMNS = 256


@nb.njit(cache=True, nogil=True)
def stage_setup(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                base, pidx, subset, owned, n):
    """What a stage's scoring reuses, as (ints, floats): the joints to recompute per hypothesis
    (those that the stage's points or owned points need and its parameters move, parents first;
    :func:`~hybridfit.model.kinematics.mark_needed`), the joints and parameters read but fixed,
    every frame's joints at ``base`` (F, P), and block buffers for G frames' batches of up to n
    hypotheses side by side (G = COLUMNS // n, at least 1; see :func:`_views`)."""
    F, P = base.shape
    J = parents.shape[0]
    Q = pm_ptr.shape[0] - 1
    A = axes.shape[1]
    n = max(n, 1)
    needed = np.zeros(J, dtype=np.bool_)
    mark_needed(parents, pm_ptr, pm_joint, subset, needed)
    mark_needed(parents, pm_ptr, pm_joint, owned, needed)
    ints = np.zeros(_HEADER + 3 * J + 3 * P, dtype=np.int64)
    order = ints[_HEADER:_HEADER + J]
    oriented = ints[_HEADER + J:_HEADER + 2 * J]
    fixed = ints[_HEADER + 2 * J:_HEADER + 3 * J]
    rows = ints[_HEADER + 3 * J:_HEADER + 3 * J + P]
    frows = ints[_HEADER + 3 * J + P:_HEADER + 3 * J + 2 * P]
    stage_pos = ints[_HEADER + 3 * J + 2 * P:]
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
    read = np.zeros(J, dtype=np.bool_)  # fixed joints that a listed joint or a point reads
    for c in range(count):
        if parents[order[c]] >= 0:
            read[parents[order[c]]] = True
    for t in range(subset.shape[0]):
        for e in range(pm_ptr[subset[t]], pm_ptr[subset[t] + 1]):
            read[pm_joint[e]] = True
    for t in range(owned.shape[0]):
        for e in range(pm_ptr[owned[t]], pm_ptr[owned[t] + 1]):
            read[pm_joint[e]] = True
    n_fixed = 0
    for j in range(J):
        if read[j] and not listed[j]:
            fixed[n_fixed] = j
            n_fixed += 1
    reads_param = np.zeros(P, dtype=np.bool_)  # parameters the listed joints read
    if count and parents[order[0]] < 0:
        for k in range(GLOBAL_PARAMS):
            reads_param[k] = True
    for c in range(count):
        for a in range(A):
            if axes[order[c], a] >= 0:
                reads_param[axis_params[order[c], a]] = True
    n_rows = 0
    n_frows = 0
    for k in range(P):
        if stage_pos[k] >= 0 and is_angle[k]:
            rows[n_rows] = k
            n_rows += 1
        elif stage_pos[k] < 0 and reads_param[k]:
            frows[n_frows] = k
            n_frows += 1
    ints[0], ints[1], ints[2], ints[3] = count, n_fixed, n_rows, n_frows
    G = max(1, min(F, COLUMNS // n))
    ints[4], ints[5], ints[6], ints[7], ints[8], ints[9] = n, F, P, J, Q, G
    C = G * n
    floats = np.zeros(3 * F * P + 12 * F * J + 3 * P * C + 12 * J * C + 9 * C + 3 * Q * n)
    (b, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts) = _views(ints, floats)
    b[:] = base
    every = np.arange(J)
    all_oriented = np.ones(J, dtype=np.int64)
    for f in range(F):  # every frame's joints at base, by the same code as the hypotheses'
        for k in range(P):
            pB[k, 0] = base[f, k]
            bcos[f, k] = 1.0
            if is_angle[k]:
                bsin[f, k], bcos[f, k] = sincos1(base[f, k])
            sinB[k, 0], cosB[k, 0] = bsin[f, k], bcos[f, k]
        block_frames(1, pB, sinB, cosB, every, J, all_oriented, parents, offsets, rest, rest_identity, axes,
                     axis_params, mirror, WB, WpB, GB)
        for j in range(J):
            for r in range(3):
                Wp0[f, j, r] = WpB[j, r, 0]
                for c in range(3):
                    W0[f, j, r, c] = WB[j, r, c, 0]
    return ints, floats


@nb.njit(cache=True, nogil=True, inline="always")
def _views(ints, floats):
    """The arrays of a stage's floats: base, bsin, bcos (F, P); W0 (F, J, 3, 3), Wp0 (F, J, 3)
    the frames' joints at base; block buffers pB, sinB, cosB (P, C), WB (J, 3, 3, C), WpB
    (J, 3, C), GB (3, 3, C) with C = G n columns (frame g's hypothesis i in column g n + i),
    and one frame's points pts (Q, 3, n)."""
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
    pts = floats[a:a + Q * 3 * n].reshape((Q, 3, n))
    return b, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts


@nb.njit(cache=True, nogil=True, fastmath=True)
def block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X):
    """The joints of frames f0 <= f < f1 (at most G) with hypotheses X[f] (m, d) into the
    stage's block buffers WpB, WB: frame f's hypothesis i in column (f - f0) m + i."""
    (base, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts) = _views(ints, floats)
    J, P = ints[7], ints[6]
    order = ints[_HEADER:_HEADER + J]
    oriented = ints[_HEADER + J:_HEADER + 2 * J]
    fixed = ints[_HEADER + 2 * J:_HEADER + 3 * J]
    rows = ints[_HEADER + 3 * J:_HEADER + 3 * J + P]
    frows = ints[_HEADER + 3 * J + P:_HEADER + 3 * J + 2 * P]
    stage_pos = ints[_HEADER + 3 * J + 2 * P:]
    m = X.shape[1]
    count, n_fixed, n_rows, n_frows = ints[0], ints[1], ints[2], ints[3]
    for f in range(f0, f1):
        at = (f - f0) * m
        for k in range(P):
            t = stage_pos[k]
            if t >= 0:
                for i in range(m):
                    pB[k, at + i] = X[f, i, t]
        for r in range(n_frows):
            k = frows[r]
            v, s, c = base[f, k], bsin[f, k], bcos[f, k]
            for i in range(at, at + m):
                pB[k, i] = v
                sinB[k, i] = s
                cosB[k, i] = c
        for t in range(n_fixed):
            j = fixed[t]
            for r in range(3):
                w = Wp0[f, j, r]
                for i in range(at, at + m):
                    WpB[j, r, i] = w
                for c in range(3):
                    w = W0[f, j, r, c]
                    for i in range(at, at + m):
                        WB[j, r, c, i] = w
    columns = (f1 - f0) * m
    for r in range(n_rows):
        k = rows[r]
        for i in range(columns):
            sinB[k, i], cosB[k, i] = sincos1(pB[k, i])
    block_frames(columns, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_identity, axes,
                 axis_params, mirror, WB, WpB, GB)


def _kernel_frames(kernel, consts, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params,
                   mirror, pm_ptr, pm_joint, pm_weight, ints, floats, X, subset, losses):
    """losses[f, :m] = the kernel's loss over ``subset`` of frame f's hypotheses X[f] (m, d)."""
    F, m = X.shape[0], X.shape[1]
    G = ints[9]
    WpB, pts = _views(ints, floats)[9], _views(ints, floats)[11]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X)
        for f in range(f0, f1):
            block_points(m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts, (f - f0) * m)
            kernel(pts, subset, proposals[f], weights[f], consts, losses[f, :m])


_KERNEL_FRAMES = T.void(
    T.FunctionType(KERNEL_SIGNATURE), T.float64[::1], T.float64[:, :, :, ::1], T.float64[:, :, ::1],
    T.int64[::1], T.float64[:, ::1], T.float64[:, :, ::1], T.boolean[::1], T.int64[:, ::1], T.int64[:, ::1], T.float64,
    T.int64[::1], T.int64[::1], T.float64[::1], T.int64[::1], T.float64[::1], T.float64[:, :, :], T.int64[::1],
    T.float64[:, ::1])


@functools.cache
def kernel_frames():
    """:func:`_kernel_frames` compiled for :data:`KERNEL_SIGNATURE` kernels (on first use)."""
    return nb.njit(_KERNEL_FRAMES, cache=True, nogil=True)(_kernel_frames)


@nb.njit(cache=True, nogil=True, fastmath=True)
def frame_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                 ints, floats, X, subset, out):
    """out (F, Q, 3, n >= m) mm, the hypothesis innermost: out[f, :, :, :m] the points
    ``subset`` of frame f's hypotheses X[f] (m, d) (the other points are left as they are)."""
    F, m = X.shape[0], X.shape[1]
    G = ints[9]
    WpB = _views(ints, floats)[9]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X)
        for f in range(f0, f1):
            block_points(m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out[f], (f - f0) * m)


@functools.cache
def as_cfunc(kernel):
    """A numba kernel (a dispatcher of :data:`~hybridfit.objective.KERNEL_SIGNATURE`) as a C
    callback with the same compiler options (cached on disk where numba can): passing it to
    :func:`kernel_frames` costs a fraction of passing the dispatcher, once per generation."""
    if not isinstance(kernel, Dispatcher):
        return kernel
    options = {k: v for k, v in kernel.targetoptions.items() if k in ("fastmath", "error_model", "boundscheck")}
    with warnings.catch_warnings():  # a kernel defined in a closure cannot be cached: compiled per process
        warnings.simplefilter("ignore", NumbaWarning)
        return nb.cfunc(KERNEL_SIGNATURE, cache=True, **options)(kernel.py_func)


class KernelScorer:
    """Scores by an objective's compiled kernel on a kinematic tree (see the module doc).
    tree: (parents, offsets, rest, rest_identity, axes, axis_params, mirror); point_map:
    (pm_ptr, pm_joint, pm_weight), the (Q, J) point matrix in CSR form; kernel: (function,
    constants); proposals (F, Q, K, 3) mm, weights (F, Q, K)."""

    def __init__(self, tree, point_map, kernel, proposals, weights) -> None:
        self.tree, self.point_map, self.kernel = tree, point_map, (as_cfunc(kernel[0]), kernel[1])
        self.proposals, self.weights = proposals, weights
        self._run = kernel_frames()

    def prepare(self, base, pidx, subset, owned, n):
        return stage_setup(*self.tree, *self.point_map, base, pidx, subset, owned, n)

    def score(self, stage, X, subset, losses):
        self._run(self.kernel[0], self.kernel[1], self.proposals, self.weights, *self.tree, *self.point_map, *stage,
                  X, subset, losses)


class NumpyScorer:
    """Scores by the objective's ``score_frames`` or ``bind`` (plain numpy allowed).

    tree: as :class:`KernelScorer`'s, or None (then the model's ``forward`` gives the joints);
    point_map, point_matrix: the (Q, J) point matrix in CSR form and dense (None: the model's
    joints); score_frames: the objective's valid capability or None, then ``losses`` (one bound
    loss per frame) are called one frame at a time. ``where`` names the objective in errors."""

    def __init__(self, model, tree, point_map, point_matrix, proposals, weights, score_frames=None, losses=None,
                 where: str = "objective") -> None:
        self.model, self.tree, self.point_map, self.point_matrix = model, tree, point_map, point_matrix
        self.proposals, self.weights = proposals, weights
        self.score_frames, self.losses, self.where = score_frames, losses, where
        self.Q = len(point_map[0]) - 1

    def prepare(self, base, pidx, subset, owned, n):
        if self.tree is not None:
            stage = stage_setup(*self.tree, *self.point_map, base, pidx, subset, owned, n)
            return stage, np.zeros((len(base), self.Q, 3, max(n, 1)))
        return (base.copy(), pidx), None

    def points(self, stage, X, subset):
        """(F, m, Q, 3) points of hypotheses X (F, m, d) (those in ``subset`` guaranteed). From
        the kinematic tree they are a view of an (F, Q, 3, n) buffer, the hypothesis innermost
        in memory as the kinematics compute them: no copy, and numpy's elementwise operations
        on them run along the hypotheses (the objective's contract allows any strides)."""
        stage, buffer = stage
        F, m = X.shape[:2]
        if self.tree is not None:
            frame_points(*self.tree, *self.point_map, *stage, X, subset, buffer)
            return buffer[..., :m].transpose(0, 3, 1, 2)
        base, pidx = stage
        full = np.repeat(base[:, None], m, axis=1)
        full[:, :, pidx] = X
        joints = self.model.forward(full.reshape(F * m, -1)).reshape(F, m, -1, 3)
        return joints if self.point_matrix is None else np.einsum("qj,fnjc->fnqc", self.point_matrix, joints)

    def score(self, stage, X, subset, losses):
        m = X.shape[1]
        points = self.points(stage, X, subset)
        if self.score_frames is not None:
            out = np.asarray(self.score_frames(points, subset, self.proposals, self.weights), dtype=np.float64)
            if out.shape != (len(X), m):
                raise PluginError(f"{self.where}: score_frames returned shape {out.shape}, expected {(len(X), m)}")
            losses[:, :m] = out
            return
        for f, loss in enumerate(self.losses):
            out = loss(points[f], subset)
            if type(out) is not np.ndarray or out.shape != (m,):
                out = np.asarray(out, dtype=np.float64)
            if out.shape != (m,):
                raise PluginError(f"{self.where}: its bound loss returned shape {out.shape}, expected {(m,)}")
            losses[f, :m] = out
