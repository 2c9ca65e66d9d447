"""Scoring a stage's hypotheses for many frames at once: forward kinematics of the joints the
stage moves (:mod:`hybridfit.model.kinematics`' block entry: :func:`block_setup` per stage,
:func:`block_kinematics` per block of frames), then the objective.

A *scorer* has two methods the driver (:mod:`.driver`) calls: ``prepare(base (F, P),
parameters (d,), points (m,), owned (o,), batch) -> stage`` once per stage, and ``score(stage,
X (F, m, d), points, losses (F, >= m))`` per generation: ``losses[:, :m]`` = each frame's
hypotheses (the parameters outside the stage at ``base``) scored over ``points``.

- :class:`KernelScorer`: a kinematic tree and an objective's compiled frames kernel (one kernel
  call per block of frames) or compiled kernel (one per frame): one numba call per generation
  for all frames of a group.
- :class:`NumpyScorer`: a kinematic tree's points by the same numba kinematics (or, for a model
  without a kinematic tree, its ``forward``), scored by the objective's ``score_frames`` (one
  call per generation for all frames) or ``bind`` (one call per frame). Neither copies the
  points: ``score_frames`` gets the scored points only, in the frame-batched layout
  (:func:`frames_innermost`, with the proposals and weights cut to the same points once per
  point set, and at least two frames: a single frame is scored beside a copy of itself);
  ``bind``'s loss gets a view of an (F, Q, 3, n) buffer, the hypothesis innermost.
"""

from __future__ import annotations

import functools
import warnings

import numba as nb
from numba import types as T
from numba.core import cgutils
from numba.experimental.function_type import _get_wrapper_address
from numba.extending import intrinsic
from numba.core.dispatcher import Dispatcher
from numba.core.errors import NumbaWarning
import numpy as np

from ..errors import PluginError
from ..objective import FRAMES_KERNEL_SIGNATURE, KERNEL_SIGNATURE
from ..problem import checked_losses, objective_label
from ..model.kinematics import block_kinematics, block_points, block_setup, block_views


def function_at(signature):
    """An intrinsic ``at(address) -> function``: the first-class function of ``signature`` whose
    C callback is at ``address`` (int64), as numba unboxes a callback argument (no jitted
    entry, so calls go through the callback). Passing the address instead of the callback
    spares numba's unboxing of a Python function object on every call (about 9 us). With
    numba's JIT disabled (``NUMBA_DISABLE_JIT``) the "address" is the kernel itself, returned."""
    if nb.config.DISABLE_JIT:
        return lambda kernel: kernel
    ftype = T.FunctionType(signature)

    @intrinsic
    def at(typingctx, address):
        if not isinstance(address, T.Integer):
            return None

        def codegen(context, builder, sig, args):
            voidptr = context.get_value_type(T.voidptr)
            function = cgutils.create_struct_proxy(ftype)(context, builder)
            function.c_addr = builder.inttoptr(args[0], voidptr)
            function.py_addr = voidptr(None)
            function.jit_addr = voidptr(None)
            return function._getvalue()

        return ftype(address), codegen

    return at


_KERNEL_AT, _FRAMES_KERNEL_AT = function_at(KERNEL_SIGNATURE), function_at(FRAMES_KERNEL_SIGNATURE)


def callback_address(kernel, signature=KERNEL_SIGNATURE) -> int:
    """The address of a compiled kernel's C callback of ``signature`` (a ``cfunc``, or an
    object with numba's ``__wrapper_address__``, as :func:`as_cfunc` returns; the caller keeps
    it alive); with numba's JIT disabled, the kernel itself (see :func:`function_at`)."""
    if nb.config.DISABLE_JIT:
        return kernel
    return int(_get_wrapper_address(kernel, T.FunctionType(signature).signature))


def _kernel_frames(kernel_address, consts, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params,
                   mirror, pm_ptr, pm_joint, pm_weight, ints, floats, X, subset, losses):
    """losses[f, :m] = the kernel's loss over ``subset`` of frame f's hypotheses X[f] (m, d)
    (the kernel: its callback's address, :func:`callback_address`)."""
    kernel = _KERNEL_AT(kernel_address)
    F, m = X.shape[0], X.shape[1]
    G = ints[9]
    views = block_views(ints, floats)
    WpB, pts = views[9], views[11]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X)
        for f in range(f0, f1):
            block_points(m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts, (f - f0) * m)
            kernel(pts, subset, proposals[f], weights[f], consts, losses[f, :m])


_KERNEL_FRAMES = T.void(
    T.int64, T.float64[::1], T.float64[:, :, :, ::1], T.float64[:, :, ::1],
    T.int64[::1], T.float64[:, ::1], T.float64[:, :, ::1], T.boolean[::1], T.int64[:, ::1], T.int64[:, ::1], T.float64,
    T.int64[::1], T.int64[::1], T.float64[::1], T.int64[::1], T.float64[::1], T.float64[:, :, :], T.int64[::1],
    T.float64[:, ::1])


def _frames_kernel_blocks(kernel_address, consts, proposals, weights, parents, offsets, rest, rest_identity, axes,
                          axis_params, mirror, pm_ptr, pm_joint, pm_weight, joints_are_points, ints, floats, X,
                          particles_last, subset, losses):
    """losses[f, :m] as :func:`_kernel_frames`, by a frames kernel: one call per block of frames.
    X (F, m, d), or with ``particles_last`` X (F, d, m) C-contiguous, the hypotheses innermost
    (copied into the kinematics' block along its rows, a loop that vectorises). With
    ``joints_are_points`` (the point map is the identity) the kernel reads the joints' block
    buffer itself, else the block's points are gathered first. The kernel: its callback's
    address (:func:`callback_address`)."""
    kernel = _FRAMES_KERNEL_AT(kernel_address)
    F, m = X.shape[0], X.shape[2 if particles_last else 1]
    G = ints[9]
    views = block_views(ints, floats)
    WpB, pts = views[9], views[11]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X,
                         0, m, particles_last)
        if joints_are_points:
            kernel(WpB, subset, proposals, weights, consts, f0, f1, m, losses)
        else:
            block_points((f1 - f0) * m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts)
            kernel(pts, subset, proposals, weights, consts, f0, f1, m, losses)


_FRAMES_KERNEL_BLOCKS = [T.void(
    T.int64, T.float64[::1], T.float64[:, :, :, ::1], T.float64[:, :, ::1],
    T.int64[::1], T.float64[:, ::1], T.float64[:, :, ::1], T.boolean[::1], T.int64[:, ::1], T.int64[:, ::1], T.float64,
    T.int64[::1], T.int64[::1], T.float64[::1], T.boolean, T.int64[::1], T.float64[::1], hypotheses, T.boolean,
    T.int64[::1], T.float64[:, ::1]) for hypotheses in (T.float64[:, :, ::1], T.float64[:, :, :])]


@functools.cache
def frames_kernel_blocks():
    """:func:`_frames_kernel_blocks` compiled for :data:`FRAMES_KERNEL_SIGNATURE` kernels and
    hypotheses C-contiguous (particles last) or of any strides (on first use)."""
    return nb.njit(_FRAMES_KERNEL_BLOCKS, cache=True, nogil=True)(_frames_kernel_blocks)


@functools.cache
def kernel_frames():
    """:func:`_kernel_frames` compiled for :data:`KERNEL_SIGNATURE` kernels (on first use)."""
    return nb.njit(_KERNEL_FRAMES, cache=True, nogil=True)(_kernel_frames)


@nb.njit(cache=True, nogil=True)
def _sum_points(m, G, WpB, pm_ptr, pm_joint, pm_weight, subset, out, f0):
    """out[c, i, t, f0 + g] = sum_j point_map[subset[t], j] WpB[j, c, g m + i] for the G frames'
    m hypotheses (the block's columns), summed in the order :func:`block_points` sums."""
    for t in range(subset.shape[0]):
        q = subset[t]
        e0 = pm_ptr[q]
        j0, w0 = pm_joint[e0], pm_weight[e0]
        for c in range(3):
            for i in range(m):
                for g in range(G):
                    out[c, i, t, f0 + g] = w0 * WpB[j0, c, g * m + i]
        for e in range(e0 + 1, pm_ptr[q + 1]):
            j, w = pm_joint[e], pm_weight[e]
            for c in range(3):
                for i in range(m):
                    for g in range(G):
                        out[c, i, t, f0 + g] += w * WpB[j, c, g * m + i]


@nb.njit(cache=True, nogil=True, fastmath=True)
def write_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                 ints, floats, X, subset, out, particles_last=False, frames_innermost=False):
    """The points ``subset`` of every frame's hypotheses X (F, m, d), or with ``particles_last``
    X (F, d, m) C-contiguous (as :func:`block_kinematics` reads it), into ``out`` (mm):
    - the hypothesis innermost: out (F, Q, 3, n >= m), out[f, :, :, :m] frame f's points (the
      other points are left as they are);
    - with ``frames_innermost``: out (3, n >= m, >= len(subset), F), out[c, i, t, f] coordinate
      c of point subset[t] of frame f's hypothesis i."""
    F, m = X.shape[0], X.shape[2 if particles_last else 1]
    G = ints[9]
    WpB = block_views(ints, floats)[9]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X,
                         0, m, particles_last)
        if frames_innermost:
            _sum_points(m, f1 - f0, WpB, pm_ptr, pm_joint, pm_weight, subset, out, f0)
        else:
            for f in range(f0, f1):
                block_points(m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out[f], (f - f0) * m)


def along_rows(X: np.ndarray) -> tuple[np.ndarray, bool]:
    """Hypotheses X (F, m, d) as the block kinematics read them fastest: (X (F, d, m), True)
    where that view is C-contiguous (PSO's swarm is: no copy), else (X, False)."""
    XT = X.transpose(0, 2, 1)
    return (XT, True) if XT.flags.c_contiguous else (X, False)


def stage_setup(work, tree, point_map, base, pidx, subset, owned, n):
    """:func:`block_setup` of a stage in ``work``, a scorer's buffer for all its stages (a fresh
    one each stage costs page faults; None: none yet) -> (ints, floats, the buffer to keep:
    ``work``, or ``floats`` where the stage needed more)."""
    ints, floats = block_setup(*tree, *point_map, base, pidx, subset, owned, n, work)
    return ints, floats, (floats if work is None or floats.shape[0] > work.shape[0] else work)


def frames_innermost(a: np.ndarray, point_axis: int) -> np.ndarray:
    """The same array (F, ...), laid out as the driver hands ``score_frames`` its arrays: a view
    of a C-contiguous copy whose last two axes are ``point_axis`` and the frame axis 0, so each
    coordinate (and proposal) of each hypothesis is one contiguous (points, frames) block."""
    inner = np.ascontiguousarray(np.moveaxis(np.asarray(a, dtype=np.float64), (point_axis, 0), (-2, -1)))
    return np.moveaxis(inner, (-2, -1), (point_axis, 0))


def frames_innermost_points(points: np.ndarray) -> np.ndarray:
    """Points (F, N, m, 3) laid out as the driver hands them to ``score_frames``: a view of a
    C-contiguous (3, N, m, F) array (a copy unless ``points`` already is such a view), so each
    coordinate of a run of hypotheses is one contiguous (hypotheses, points, frames) block."""
    return np.ascontiguousarray(np.asarray(points, dtype=np.float64).transpose(3, 1, 2, 0)).transpose(3, 1, 2, 0)


class _KernelAddress:
    """A C callback of a known signature as numba's first-class function protocol sees it
    (``__wrapper_address__``), with its numba type made once (``_numba_type_``): typing a
    numba ``cfunc`` argument builds its type on every call (about 16 us, once per generation)."""

    def __init__(self, callback, signature) -> None:
        self.callback = callback  # keeps the compiled code alive
        self.address = int(callback.address)
        self._numba_type_ = T.FunctionType(signature)

    def __wrapper_address__(self) -> int:
        return self.address


@functools.cache
def as_cfunc(kernel, signature=KERNEL_SIGNATURE):
    """A numba kernel (a dispatcher of ``signature``: :data:`~hybridfit.objective.KERNEL_SIGNATURE`
    or :data:`~hybridfit.objective.FRAMES_KERNEL_SIGNATURE`) as a C callback with the same
    compiler options (cached on disk where numba can), typed once (:class:`_KernelAddress`):
    passing it to :func:`kernel_frames` costs a fraction of passing the dispatcher, once per
    generation."""
    if not isinstance(kernel, Dispatcher):
        return kernel
    options = {k: v for k, v in kernel.targetoptions.items() if k in ("fastmath", "error_model", "boundscheck")}
    with warnings.catch_warnings():  # a kernel defined in a closure cannot be cached: compiled per process
        warnings.simplefilter("ignore", NumbaWarning)
        return _KernelAddress(nb.cfunc(signature, cache=True, **options)(kernel.py_func), signature)


def joints_are_points(tree, point_map) -> bool:
    """Whether the point map (pm_ptr, pm_joint, pm_weight) is the identity of the tree's joints."""
    J = len(tree[0])
    pm_ptr, pm_joint, pm_weight = point_map
    return (len(pm_ptr) == J + 1 and np.array_equal(pm_ptr, np.arange(J + 1))
            and np.array_equal(pm_joint, np.arange(J)) and bool(np.all(pm_weight == 1.0)))


class KernelScorer:
    """Scores by an objective's compiled kernel on a kinematic tree (see the module doc).
    tree: (parents, offsets, rest, rest_identity, axes, axis_params, mirror); point_map:
    (pm_ptr, pm_joint, pm_weight), the (Q, J) point matrix in CSR form; kernel: (function,
    constants), a compiled kernel, or with ``frames`` a compiled frames kernel (one call per
    block of frames); proposals (F, Q, K, 3) mm, weights (F, Q, K). ``objective`` is named in
    errors."""

    def __init__(self, tree, point_map, kernel, proposals, weights, frames: bool = False, objective=None) -> None:
        signature = FRAMES_KERNEL_SIGNATURE if frames else KERNEL_SIGNATURE
        self.tree, self.point_map, self.kernel = tree, point_map, (as_cfunc(kernel[0], signature), kernel[1])
        self.address = callback_address(self.kernel[0], signature)  # self.kernel keeps the callback alive
        self.proposals, self.weights = proposals, weights
        self.frames, self.objective = frames, objective
        self.identity = joints_are_points(tree, point_map)
        self._run = frames_kernel_blocks() if frames else kernel_frames()
        self._work = None  # the stages' block buffers, one after the other (block_setup's work)

    def prepare(self, base, pidx, subset, owned, n):
        ints, floats, self._work = stage_setup(self._work, self.tree, self.point_map, base, pidx, subset, owned, n)
        return ints, floats

    def score(self, stage, X, subset, losses):
        if self.frames:
            self._run(self.address, self.kernel[1], self.proposals, self.weights, *self.tree, *self.point_map,
                      self.identity, *stage, *along_rows(X), subset, losses)
        else:
            self._run(self.address, self.kernel[1], self.proposals, self.weights, *self.tree, *self.point_map,
                      *stage, X, subset, losses)


class NumpyScorer:
    """Scores by the objective's ``score_frames`` or ``bind`` (plain numpy allowed).

    tree: as :class:`KernelScorer`'s, or None (then the model's ``forward`` gives the joints);
    point_map, point_matrix: the (Q, J) point matrix in CSR form and dense (None: the model's
    joints); proposals (F, Q, K, 3) mm, weights (F, Q, K); score_frames: the objective's valid
    capability or None, then ``losses`` (one bound loss per frame) are called one frame at a
    time. ``objective`` is named in errors."""

    def __init__(self, model, tree, point_map, point_matrix, proposals, weights, score_frames=None, losses=None,
                 objective=None) -> None:
        self.model, self.tree, self.point_map, self.point_matrix = model, tree, point_map, point_matrix
        # score_frames scores at least two frames: over a single frame numpy orders some loops
        # otherwise (a sum over the points becomes a pairwise sum), so a frame scored alone would
        # differ in the last bits from the same frame scored beside others; one is scored twice
        self.twin = score_frames is not None and len(proposals) == 1
        if self.twin:
            proposals, weights = np.concatenate([proposals, proposals]), np.concatenate([weights, weights])
        self.proposals, self.weights = proposals, weights
        self.score_frames, self.losses, self.objective = score_frames, losses, objective
        self.Q = len(point_map[0]) - 1
        self._cuts: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        self._work = self._flat = None  # block buffers and score_frames' points, reused by later stages

    def prepare(self, base, pidx, subset, owned, n):
        if self.twin:
            base = np.concatenate([base, base])
        F, n = len(base), max(n, 1)
        if self.score_frames is not None:  # (3, m, len(subset), F) at its start: see write_points
            if self._flat is None or self._flat.shape[0] < 3 * n * self.Q * F:
                self._flat = np.empty(3 * n * self.Q * F)
            buffer = self._flat
        elif self.tree is not None:  # the hypothesis innermost; points outside the subset stay 0
            buffer = np.zeros((F, self.Q, 3, n))
        else:
            buffer = None
        if self.tree is not None:
            ints, floats, self._work = stage_setup(self._work, self.tree, self.point_map, base, pidx, subset, owned, n)
            return (ints, floats), buffer
        return (base.copy(), pidx), buffer

    def cut(self, subset):
        """(proposals (F, m, K, 3), weights (F, m, K)) of the points ``subset`` (m,), laid out
        as :func:`frames_innermost` (computed once per point set)."""
        key = subset.tobytes()
        if key not in self._cuts:
            self._cuts[key] = (frames_innermost(self.proposals[:, subset], 1),
                               frames_innermost(self.weights[:, subset], 1))
        return self._cuts[key]

    def _forward_points(self, stage, X):
        """(F, m, Q, 3) points of hypotheses X (F, m, d) by the model's ``forward``."""
        base, pidx = stage
        F, m = X.shape[:2]
        full = np.repeat(base[:, None], m, axis=1)
        full[:, :, pidx] = X
        joints = self.model.forward(full.reshape(F * m, -1)).reshape(F, m, -1, 3)
        return joints if self.point_matrix is None else np.einsum("qj,fnjc->fnqc", self.point_matrix, joints)

    def subset_points(self, stage, X, subset):
        """(F, m, len(subset), 3) the points ``subset`` of hypotheses X (F, m, d): a view of a
        C-contiguous (3, m, len(subset), F) array at the start of the stage's buffer, the frame
        innermost (:func:`frames_innermost_points`, no copy): each coordinate of the scored
        points is one contiguous block, whatever the subset and batch."""
        stage, buffer = stage
        F, m, s = X.shape[0], X.shape[1], len(subset)
        out = buffer[:3 * m * s * F].reshape(3, m, s, F)
        if self.tree is not None:
            hypotheses, rows = along_rows(X)
            write_points(*self.tree, *self.point_map, *stage, hypotheses, subset, out, rows, True)
        else:
            out[...] = self._forward_points(stage, X)[:, :, subset].transpose(3, 1, 2, 0)
        return frames_innermost_points(out.transpose(3, 1, 2, 0))

    def points(self, stage, X, subset):
        """(F, m, Q, 3) points of hypotheses X (F, m, d) (those in ``subset`` guaranteed). From
        the kinematic tree they are a view of the (F, Q, 3, n) buffer, the hypothesis innermost
        in memory as the kinematics compute them: no copy, and numpy's elementwise operations
        on them run along the hypotheses (the objective's contract allows any strides)."""
        stage, buffer = stage
        if self.tree is not None:
            hypotheses, rows = along_rows(X)
            write_points(*self.tree, *self.point_map, *stage, hypotheses, subset, buffer, rows)
            return buffer[..., :X.shape[1]].transpose(0, 3, 1, 2)
        return self._forward_points(stage, X)

    def score(self, stage, X, subset, losses):
        m = X.shape[1]
        if self.score_frames is not None:
            if self.twin:
                X = np.concatenate([X, X])
            proposals, weights = self.cut(subset)
            out = np.asarray(self.score_frames(self.subset_points(stage, X, subset), subset, proposals, weights),
                             dtype=np.float64)
            if out.shape != (len(X), m):
                raise PluginError(f"{objective_label(self.objective)}: score_frames returned shape {out.shape}, "
                                  f"expected {(len(X), m)}")
            losses[:, :m] = out[:len(losses)]
            return
        points = self.points(stage, X, subset)
        out = [loss(frame, subset) for loss, frame in zip(self.losses, points)]
        try:  # one conversion for all frames; the frame-by-frame check names the objective
            scored = np.array(out, dtype=np.float64)
        except (ValueError, TypeError):
            scored = None
        if scored is None or scored.shape != (len(out), m):
            scored = [checked_losses(o, m, self.objective) for o in out]
        losses[:, :m] = scored
