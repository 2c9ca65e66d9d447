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
from ..objective import FRAMES_KERNEL_SIGNATURE, KERNEL_SIGNATURE
from ..problem import checked_losses, objective_label
from ..model.kinematics import block_kinematics, block_points, block_setup, block_views


def _kernel_frames(kernel, consts, proposals, weights, parents, offsets, rest, rest_identity, axes, axis_params,
                   mirror, pm_ptr, pm_joint, pm_weight, ints, floats, X, subset, losses):
    """losses[f, :m] = the kernel's loss over ``subset`` of frame f's hypotheses X[f] (m, d)."""
    F, m = X.shape[0], X.shape[1]
    G = ints[9]
    WpB, pts = block_views(ints, floats)[9], block_views(ints, floats)[11]
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


def _frames_kernel_blocks(kernel, consts, proposals, weights, parents, offsets, rest, rest_identity, axes,
                          axis_params, mirror, pm_ptr, pm_joint, pm_weight, joints_are_points, ints, floats, X,
                          subset, losses):
    """losses[f, :m] as :func:`_kernel_frames`, by a frames kernel: one call per block of frames.
    With ``joints_are_points`` (the point map is the identity) the kernel reads the joints'
    block buffer itself, else the block's points are gathered first."""
    F, m = X.shape[0], X.shape[1]
    G = ints[9]
    WpB, pts = block_views(ints, floats)[9], block_views(ints, floats)[11]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X)
        if joints_are_points:
            kernel(WpB, subset, proposals, weights, consts, f0, f1, m, losses)
        else:
            block_points((f1 - f0) * m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts)
            kernel(pts, subset, proposals, weights, consts, f0, f1, m, losses)


_FRAMES_KERNEL_BLOCKS = T.void(
    T.FunctionType(FRAMES_KERNEL_SIGNATURE), T.float64[::1], T.float64[:, :, :, ::1], T.float64[:, :, ::1],
    T.int64[::1], T.float64[:, ::1], T.float64[:, :, ::1], T.boolean[::1], T.int64[:, ::1], T.int64[:, ::1], T.float64,
    T.int64[::1], T.int64[::1], T.float64[::1], T.boolean, T.int64[::1], T.float64[::1], T.float64[:, :, :],
    T.int64[::1], T.float64[:, ::1])


@functools.cache
def frames_kernel_blocks():
    """:func:`_frames_kernel_blocks` compiled for :data:`FRAMES_KERNEL_SIGNATURE` kernels (on first use)."""
    return nb.njit(_FRAMES_KERNEL_BLOCKS, cache=True, nogil=True)(_frames_kernel_blocks)


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
    WpB = block_views(ints, floats)[9]
    for f0 in range(0, F, G):
        f1 = min(F, f0 + G)
        block_kinematics(parents, offsets, rest, rest_identity, axes, axis_params, mirror, ints, floats, f0, f1, X)
        for f in range(f0, f1):
            block_points(m, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out[f], (f - f0) * m)


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
    block of frames); proposals (F, Q, K, 3) mm, weights (F, Q, K)."""

    def __init__(self, tree, point_map, kernel, proposals, weights, frames: bool = False) -> None:
        signature = FRAMES_KERNEL_SIGNATURE if frames else KERNEL_SIGNATURE
        self.tree, self.point_map, self.kernel = tree, point_map, (as_cfunc(kernel[0], signature), kernel[1])
        self.proposals, self.weights = proposals, weights
        self.frames = frames
        self.identity = joints_are_points(tree, point_map)
        self._run = frames_kernel_blocks() if frames else kernel_frames()

    def prepare(self, base, pidx, subset, owned, n):
        return block_setup(*self.tree, *self.point_map, base, pidx, subset, owned, n)

    def score(self, stage, X, subset, losses):
        if self.frames:
            self._run(self.kernel[0], self.kernel[1], self.proposals, self.weights, *self.tree, *self.point_map,
                      self.identity, *stage, X, subset, losses)
        else:
            self._run(self.kernel[0], self.kernel[1], self.proposals, self.weights, *self.tree, *self.point_map,
                      *stage, X, subset, losses)


class NumpyScorer:
    """Scores by the objective's ``score_frames`` or ``bind`` (plain numpy allowed).

    tree: as :class:`KernelScorer`'s, or None (then the model's ``forward`` gives the joints);
    point_map, point_matrix: the (Q, J) point matrix in CSR form and dense (None: the model's
    joints); score_frames: the objective's valid capability or None, then ``losses`` (one bound
    loss per frame) are called one frame at a time. ``objective`` is named in errors."""

    def __init__(self, model, tree, point_map, point_matrix, proposals, weights, score_frames=None, losses=None,
                 objective=None) -> None:
        self.model, self.tree, self.point_map, self.point_matrix = model, tree, point_map, point_matrix
        self.proposals, self.weights = proposals, weights
        self.score_frames, self.losses, self.objective = score_frames, losses, objective
        self.Q = len(point_map[0]) - 1

    def prepare(self, base, pidx, subset, owned, n):
        if self.tree is not None:
            stage = block_setup(*self.tree, *self.point_map, base, pidx, subset, owned, n)
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
                raise PluginError(f"{objective_label(self.objective)}: score_frames returned shape {out.shape}, "
                                  f"expected {(len(X), m)}")
            losses[:, :m] = out
            return
        for f, loss in enumerate(self.losses):
            losses[f, :m] = checked_losses(loss(points[f], subset), m, self.objective)
