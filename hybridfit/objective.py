"""The abstract objective: scores N hypotheses at once against one frame's proposals.

Direction, everywhere in hybridfit: **optimisers minimise**. An objective returns a loss
(lower is better). The paper's objective E (to be maximised) is therefore returned as -E.

Contract: the loss is a sum of per-point terms, so the loss on a subset of points (one
stage of stepwise optimisation) is the sum of those points' terms, and the stage losses of
a stepwise fit add up to the full loss. A point with no proposals (all confidences 0)
contributes nothing.

Objectives that look at the depth image (``observes_depth = True``) bind to the frame's
:class:`Observation` and the model as well (``bind_observed``), and score the model's
joints too: loss(points, subset, joints (N, J, 3)). An image term is not a sum over points
(``additive = False``): on a stage's subset it still scores the whole rendered hand, with the
parameters outside the stage at their current values, so the stage losses of a stepwise fit
do not add up to the full loss.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Any, Callable, ClassVar

import numba as nb
import numpy as np

from .datasets.camera import Intrinsics
from .errors import HybridfitError
from .plugin import Plugin, defining_class

#: an objective's compiled kernel: (points (Q, 3, N) mm, the hypothesis innermost, subset
#: (m,) point indices, proposals (Q, K, 3) mm, weights (Q, K), constants (c,), out (n,),
#: n <= N) -> None; writes into ``out`` the loss of each of the first n hypotheses over the
#: points in ``subset``.
KERNEL_SIGNATURE = nb.types.void(nb.types.float64[:, :, ::1], nb.types.int64[::1], nb.types.float64[:, :, ::1],
                                 nb.types.float64[:, ::1], nb.types.float64[::1], nb.types.float64[::1])

#: an objective's compiled frames kernel: the same loss for the hypotheses of several frames
#: side by side, in one call: (points (Q, 3, C) mm, the hypothesis innermost, subset (m,),
#: proposals (F, Q, K, 3) mm, weights (F, Q, K), constants (c,), f0, f1, n, out (F, >= n))
#: -> None; writes out[f, i] for f0 <= f < f1 and i < n, the loss of frame f's hypothesis in
#: column (f - f0) n + i over the points in ``subset`` against frame f's proposals.
FRAMES_KERNEL_SIGNATURE = nb.types.void(nb.types.float64[:, :, ::1], nb.types.int64[::1],
                                        nb.types.float64[:, :, :, ::1], nb.types.float64[:, :, ::1],
                                        nb.types.float64[::1], nb.types.int64, nb.types.int64, nb.types.int64,
                                        nb.types.float64[:, ::1])

#: loss(points (N, Q, 3) mm, subset (m,) int64 point indices) -> (N,) float64 losses; points
#: may be any strided view (the driver's has the hypothesis innermost in memory)
Loss = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: loss(points (N, Q, 3) mm, subset (m,), joints (N, J, 3) mm model joints) -> (N,) float64 losses
ObservedLoss = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Observation:
    """One frame as the sensor saw it, cut to the hand.

    depth_mm: (h, w) float32 depth in mm of the hand region ``box`` = (u0, v0, u1, v1)
    (pixels of the full image, end exclusive), 0 where there is no measurement or no hand;
    intrinsics: of the full image.
    """

    depth_mm: np.ndarray
    box: tuple[int, int, int, int]
    intrinsics: Intrinsics

    @classmethod
    def from_depth(cls, depth: np.ndarray, intrinsics: Intrinsics, mask: np.ndarray | None = None,
                   margin: float = 0.15, where: str = "frame") -> "Observation":
        """A full depth image (H, W) mm and its hand mask (H, W) bool (default: depth > 0) ->
        the hand's bounding box grown by ``margin`` of its size on each side, the depth
        outside the mask set to 0. ``where`` names the frame in errors."""
        depth = np.asarray(depth)
        if depth.ndim != 2 or depth.shape != (intrinsics.height, intrinsics.width):
            raise HybridfitError(f"{where}: depth image of shape {depth.shape}, the intrinsics say "
                                 f"{intrinsics.height}x{intrinsics.width}")
        hand = depth > 0 if mask is None else np.asarray(mask, bool) & (depth > 0)
        if not hand.any():
            raise HybridfitError(f"{where}: no hand pixels in the depth image")
        vs, us = np.nonzero(hand)
        grow_u, grow_v = margin * (us.max() + 1 - us.min()), margin * (vs.max() + 1 - vs.min())
        u0, u1 = max(int(us.min() - grow_u), 0), min(int(np.ceil(us.max() + 1 + grow_u)), depth.shape[1])
        v0, v1 = max(int(vs.min() - grow_v), 0), min(int(np.ceil(vs.max() + 1 + grow_v)), depth.shape[0])
        crop = np.where(hand, depth, 0)[v0:v1, u0:u1].astype(np.float32)
        return cls(np.ascontiguousarray(crop), (u0, v0, u1, v1), intrinsics)


def dataset_observations(ds, indices, where: str = "data") -> list[Observation | None]:
    """Observations of frames ``indices`` of a data set in camera coordinates (a
    ``hybridfit.datasets.folder`` folder): the hand masked as the forest masks it
    (``hybridfit.forest.dataset_masks``); None for a frame without hand pixels."""
    from .forest.segment import dataset_masks

    idx = np.asarray(indices, dtype=np.int64)
    depths = np.asarray(ds.depths(idx))
    masks = dataset_masks(ds, idx, depths)
    return [Observation.from_depth(d, ds.intrinsics, m, where=f"{where}, frame {i}") if (m & (d > 0)).any() else None
            for i, d, m in zip(idx, depths, masks)]


class Objective(Plugin, abc.ABC):
    """Scores hypotheses' points against a frame's proposals; lower is better.

    ``bind`` is the contract. ``compiled_kernel``, ``compiled_frames_kernel``, ``score_frames``
    and ``casadi_loss`` are optional capabilities (faster or symbolic forms of the same loss), used by the core only
    through :func:`capability`; ``hybridfit.testing`` checks that they agree with ``bind``.
    """

    #: capability: bind_observed needs the frame's depth Observation and the model
    observes_depth: ClassVar[bool] = False
    #: capability: the loss is a sum of per-point terms (stage losses add up)
    additive: ClassVar[bool] = True

    @abc.abstractmethod
    def bind(self, proposals: np.ndarray, weights: np.ndarray) -> Loss:
        """Fix the objective to one frame.

        proposals: (Q, K, 3) mm; weights: (Q, K) confidences normalised per point to sum to
        1 (or all 0 for a point without proposals). Returns loss(points, subset).
        """

    def bind_observed(self, proposals: np.ndarray, weights: np.ndarray, observation: Observation,
                      model: Any) -> ObservedLoss:
        """Fix an objective that ``observes_depth`` to one frame: its proposals and weights
        as in ``bind``, its depth ``observation`` and the hand ``model`` (for its surface).
        Returns loss(points, subset, joints)."""
        raise NotImplementedError(f"objective {self.name or type(self).__name__} does not observe depth")

    def lower_bound(self, weights: np.ndarray) -> float:
        """A lower bound of the loss for these weights (-inf when unknown)."""
        return -np.inf

    # ---- optional capabilities: faster ways to compute what ``bind`` computes. The core
    # uses one only where :func:`capability` finds it valid for this object's ``bind``.

    def compiled_kernel(self) -> tuple[Callable, np.ndarray] | None:
        """Capability: (kernel, constants (c,) float64), a numba function of
        :data:`KERNEL_SIGNATURE` scoring exactly as ``bind`` does; None (the default): none."""
        return None

    def compiled_frames_kernel(self) -> tuple[Callable, np.ndarray] | None:
        """Capability: (kernel, constants (c,) float64), a numba function of
        :data:`FRAMES_KERNEL_SIGNATURE` scoring several frames' hypotheses in one call exactly
        as ``bind`` does (the driver calls it once per block of frames instead of a
        ``compiled_kernel`` once per frame); None (the default): none."""
        return None

    def score_frames(self, points: np.ndarray, subset: np.ndarray, proposals: np.ndarray,
                     weights: np.ndarray) -> np.ndarray | None:
        """Capability: the losses of many frames at once, plain numpy allowed, given only the
        scored points: points (F, N, m, 3) mm, the points ``subset`` (m,) int64 of F frames' N
        hypotheses, and proposals (F, m, K, 3) mm and weights (F, m, K) (normalised) of the
        same m points -> (F, N) float64, row f equal to ``bind(P[f], W[f])(X[f], subset)`` for
        the frame's whole proposals P, weights W and any points X whose rows ``subset`` are
        points[f]. The driver hands views with the frame axis innermost in memory, then the
        point axis (not C-contiguous; any strides must work): numpy's elementwise operations
        between points and proposals then run in long contiguous loops, and arrays made by
        them or by ``np.empty_like`` keep that layout. F >= 2 (a single frame is scored beside a
        copy of itself: numpy sums over one frame's points pairwise, over several frames' one
        by one), and row f must not depend on the other frames, bit for bit. None (the
        default): not offered."""
        return None

    def casadi_loss(self, points: Any, proposals: np.ndarray, weights: np.ndarray, subset: np.ndarray) -> Any:
        """Capability: the loss as CasADi symbols of points (Q, 3) SX for gradient-based
        solvers (``casadi-ik``); None (the default): not offered."""
        return None


#: the optional capabilities of :class:`Objective` (each overrides a base method returning None)
CAPABILITIES = ("compiled_kernel", "compiled_frames_kernel", "score_frames", "casadi_loss")


def capability(objective: Any, name: str) -> Callable | None:
    """The objective's bound method ``name`` (one of :data:`CAPABILITIES`) when it may stand in
    for its ``bind``, else None.

    A capability is valid only when the class that defines it is the class that defines the
    ``bind`` in effect, or a subclass of it: a subclass that overrides ``bind`` never runs its
    parent's kernel. Objects that are not :class:`Objective` subclasses offer nothing."""
    if name not in CAPABILITIES:
        raise ValueError(f"unknown objective capability {name!r}; choose from {CAPABILITIES}")
    if not isinstance(objective, Objective):
        return None
    cls = type(objective)
    provider = defining_class(cls, name)
    if provider is Objective:
        return None
    binder = defining_class(cls, "bind_observed" if objective.observes_depth else "bind")
    if not issubclass(provider, binder):
        return None
    return getattr(objective, name)


def compiled_kernel_of(objective: Any, name: str = "compiled_kernel") -> tuple[Callable, np.ndarray] | None:
    """The objective's valid compiled kernel (``name``: ``compiled_kernel`` or
    ``compiled_frames_kernel``) and constants (see :func:`capability`), or None."""
    method = capability(objective, name)
    found = None if method is None or objective.observes_depth else method()
    if found is None:
        return None
    return found[0], np.ascontiguousarray(found[1], dtype=np.float64)


def kernel_loss(kernel: Callable, *frame_data) -> Loss:
    """A Loss calling a batched numba ``kernel(points (N, Q, 3), subset (m,), *frame_data) -> (N,)``."""

    def loss(points: np.ndarray, subset: np.ndarray) -> np.ndarray:
        return kernel(np.ascontiguousarray(points, dtype=np.float64), np.asarray(subset, dtype=np.int64), *frame_data)

    return loss


def normalise_confidences(confidences: np.ndarray) -> np.ndarray:
    """(..., K) non-negative confidences -> weights summing to 1 over K (0 stays all-0). A point
    whose confidences' sum overflows (confidences near the largest float, 1.7e308) has them
    divided by their largest first, so its weights do not all become 0."""
    c = np.asarray(confidences, dtype=np.float64)
    with np.errstate(over="ignore"):
        total = c.sum(axis=-1, keepdims=True)
    overflow = np.isinf(total)
    if overflow.any() and np.isfinite(c).all():
        top = np.where(overflow, c.max(axis=-1, keepdims=True), 1.0)
        c = c / top
        total = c.sum(axis=-1, keepdims=True)
    return np.divide(c, total, out=np.zeros_like(c), where=total > 0)
