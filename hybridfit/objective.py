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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numba as nb
import numpy as np

from .datasets.camera import Intrinsics
from .errors import HybridfitError, PluginError
from .plugin import Plugin, declare_offers
from .point_loss import bound_point_loss

#: an objective's fast form, its per-point loss: point_loss(x (n,), y (n,), z (n,) mm, the
#: coordinates of one point in n hypotheses, proposals (K, 3) mm and weights (K,) of that
#: point, constants (c,), out (n,)) -> None, writing each hypothesis's loss of this point
#: into out[i]. Called only for points with proposals (a weight > 0).
POINT_LOSS_SIGNATURE = nb.types.void(nb.types.float64[::1], nb.types.float64[::1], nb.types.float64[::1],
                                     nb.types.float64[:, ::1], nb.types.float64[::1], nb.types.float64[::1],
                                     nb.types.float64[::1])

#: loss(points (N, Q, 3) mm, subset (m,) int64 point indices) -> (N,) float64 losses; points
#: may be any strided view (the driver's has the hypothesis innermost in memory)
Loss = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: loss(points (N, Q, 3) mm, subset (m,), joints (N, J, 3) mm model joints) -> (N,) float64 losses. Of an
#: objective with ``observed_derivatives``, the loss also has ``loss.derivatives(points, subset, joints) ->
#: (losses (N,), point_gradients (N, Q, 3), point_curvatures (N, Q, 3, 3), joint_gradients (N, J, 3),
#: joint_curvatures (N, 3J, 3J))``: its partial derivatives with respect to the points and to the joints taken
#: apart (the scorer chains both through the kinematics: the points are fixed combinations of the joints), each
#: curvature a positive semi-definite Gauss-Newton matrix, joint j's coordinate c at row 3 j + c
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
                   margin: float = 0.15, where: str = "frame") -> Observation:
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

    An objective offers its loss in one of two forms: the fast one, ``point_loss`` (a numba
    function of one point, which hybridfit compiles into every loop it needs), or ``bind``
    (plain numpy, any loss over a frame's points). With a ``point_loss``, ``bind`` comes
    built from it. Objectives that see the depth image offer ``bind_observed``; ``casadi_loss``
    is an optional symbolic form for gradient solvers (``casadi-ik``).

    ``offers`` (data the core reads) names the forms the class offers (:data:`FORMS`). It is
    set when the class is created, from the methods the class defines itself: a subclass that
    defines its own ``bind`` (or ``bind_observed``) offers no ``point_loss`` or ``casadi_loss``
    of its parent, which would score otherwise than its ``bind``
    (:func:`~hybridfit.plugin.declare_offers`); a class may declare ``offers`` outright.
    """

    offers: ClassVar[frozenset[str]] = frozenset()

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        declare_offers(cls, FORMS, SUPERSEDES)

    #: capability: bind_observed needs the frame's depth Observation and the model
    observes_depth: ClassVar[bool] = False
    #: capability: the loss is a sum of per-point terms (stage losses add up)
    additive: ClassVar[bool] = True
    #: capability: bind_observed's loss offers ``derivatives`` (:data:`ObservedLoss`), so a schedule's local
    #: stage can take gradient steps on it
    observed_derivatives: ClassVar[bool] = False

    def point_loss(self) -> tuple[Callable, np.ndarray] | None:
        """The fast form: (function, constants (c,) float64), the function a ``numba.njit``
        function of :data:`POINT_LOSS_SIGNATURE` (hybridfit compiles it into its loops, once
        per process and cached on disk); None (the default): only ``bind``."""
        return None

    def bind(self, proposals: np.ndarray, weights: np.ndarray) -> Loss:
        """Fix the objective to one frame.

        proposals: (Q, K, 3) mm; weights: (Q, K) confidences normalised per point to sum to
        1 (or all 0 for a point without proposals). Returns loss(points (N, Q, 3), subset
        (m,)) -> (N,). The default sums ``point_loss`` over the subset."""
        found = self.point_loss()  # its own, also when a subclass's bind calls this one
        if found is None:
            raise NotImplementedError(f"{objective_label(self)} offers neither point_loss nor bind")
        return bound_point_loss((found[0], np.ascontiguousarray(found[1], dtype=np.float64)), proposals, weights)

    def bind_observed(self, proposals: np.ndarray, weights: np.ndarray, observation: Observation,
                      model: Any) -> ObservedLoss:
        """Fix an objective that ``observes_depth`` to one frame: its proposals and weights
        as in ``bind``, its depth ``observation`` and the hand ``model`` (for its surface).
        Returns loss(points, subset, joints)."""
        raise NotImplementedError(f"{objective_label(self)} does not observe depth")

    def lower_bound(self, weights: np.ndarray) -> float:
        """A lower bound of the loss for these weights (-inf when unknown)."""
        return -np.inf

    def local_objective(self) -> Objective | None:
        """Form ``local_objective``: the objective a schedule's local stage minimises when the
        schedule names none for it (a pair, as ``clamped-then-soft-l1``); None (the default):
        this objective itself."""
        return None

    def casadi_loss(self, points: Any, proposals: np.ndarray, weights: np.ndarray, subset: np.ndarray) -> Any:
        """Capability: the loss as CasADi symbols of points (Q, 3) SX for gradient-based
        solvers (``casadi-ik``); None (the default): not offered."""
        return None


#: the forms an objective may offer (``Objective.offers``): ``point_loss`` and ``casadi_loss``
#: stand in for its ``bind`` (:data:`CAPABILITIES`)
FORMS = ("point_loss", "bind", "bind_observed", "casadi_loss", "local_objective")
CAPABILITIES = ("point_loss", "casadi_loss", "local_objective")
#: a form a class defines replaces these forms of its parent (a class with a loss of its own
#: offers no local objective of its parent's)
SUPERSEDES = {"bind": ("point_loss", "casadi_loss", "local_objective"),
              "bind_observed": ("point_loss", "casadi_loss", "local_objective"),
              "point_loss": ("local_objective",)}


def capability(objective: Any, name: str) -> Callable | None:
    """The objective's bound method ``name`` (one of :data:`CAPABILITIES`) when its class offers
    it (``offers``), else None. Objects that are not :class:`Objective` subclasses offer nothing."""
    if name not in CAPABILITIES:
        raise ValueError(f"unknown objective capability {name!r}; choose from {CAPABILITIES}")
    if not isinstance(objective, Objective) or name not in type(objective).offers:
        return None
    return getattr(objective, name)


def point_loss_of(objective: Any) -> tuple[Callable, np.ndarray] | None:
    """The objective's valid ``point_loss`` (function, constants (c,) float64), or None (an
    objective that observes depth scores the whole hand: never per point)."""
    method = capability(objective, "point_loss")
    found = None if method is None or objective.observes_depth else method()
    return None if found is None else (found[0], np.ascontiguousarray(found[1], dtype=np.float64))


def objective_label(objective) -> str:
    """How errors name an objective: ``objective NAME``."""
    return f"objective {getattr(objective, 'name', None) or type(objective).__name__}"


def checked_losses(out, n: int, objective) -> np.ndarray:
    """A bound loss's result as (n,) float64, or a PluginError naming the objective."""
    if type(out) is not np.ndarray or out.dtype != np.float64:
        out = np.asarray(out, dtype=np.float64)
    if out.shape != (n,):
        raise PluginError(f"{objective_label(objective)}: its bound loss returned shape {out.shape}, expected {(n,)}")
    require_finite(out, objective)
    return out


def require_finite(losses: np.ndarray, objective) -> None:
    """A PluginError naming the objective when any of ``losses`` is NaN or infinite: a plugin's
    bug, never a fit (a NaN is never the best loss, and a -inf would win over every real one)."""
    if not np.isfinite(losses).all():
        bad = np.asarray(losses)[~np.isfinite(losses)]
        raise PluginError(f"{objective_label(objective)}: its loss is not finite ({float(bad.flat[0])} for "
                          f"{bad.size} of {np.size(losses)} hypotheses); a loss must be a finite number")


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
