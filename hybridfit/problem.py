"""One frame's fitting problem: a model, an objective bound to the frame's proposals, the
mapping of proposal points onto model points, the search box and an initial guess; and the
same set-up for many frames at once (:func:`prepare_frames`).

Its parts live by job: the model's stages over the points and guide points (:mod:`.stages`),
the initial alignment (:mod:`.alignment`)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .alignment import INLIER_MM, _aligned_guesses, alignment_points, initial_guess
from .errors import HybridfitError
from .model.base import ORIENTATION, POSITION, HandModel
from .objective import Objective, Observation, checked_losses, normalise_confidences
from .stages import _Structure, structure_of


class Problem:
    """Minimise ``loss(points(params))`` for one frame.

    proposals: (Q, K, 3) mm for the Q points named by ``point_names`` (default: the
    model's joints); confidences: (Q, K) non-negative. The search box is the model's
    bounds, with the position limited to ``search_radius_mm`` around the initial guess.
    observation: the frame's depth (needed by objectives that ``observes_depth``); x0: (P,)
    an initial guess (tracking: the previous frame's fit) instead of the proposals' one.
    """

    def __init__(
        self,
        model: HandModel,
        objective: Objective,
        proposals: np.ndarray,
        confidences: np.ndarray,
        point_names: Sequence[str] | None = None,
        search_radius_mm: float = 60.0,
        observation: Observation | None = None,
        x0: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.objective = objective
        self.observation = observation
        self.search_radius_mm = float(search_radius_mm)
        self.proposals = np.ascontiguousarray(proposals, dtype=np.float64)
        self.weights = np.ascontiguousarray(normalise_confidences(confidences))
        self.point_names = tuple(point_names) if point_names is not None else tuple(model.joint_names)
        if len(self.point_names) != self.proposals.shape[0]:
            raise HybridfitError(
                f"{len(self.point_names)} point names for {self.proposals.shape[0]} proposal points"
            )
        self.point_matrix = self._structure().point_matrix  # the structure derives it once per model and points
        self.observed = bool(getattr(objective, "observes_depth", False))
        if self.observed:
            if observation is None:
                raise HybridfitError(f"objective {objective.name or type(objective).__name__} compares hypotheses "
                                     f"with the depth image, and this frame has none")
            self.loss = objective.bind_observed(self.proposals, self.weights, observation, model)
        else:
            self.loss = objective.bind(self.proposals, self.weights)
        self.all_points = np.arange(len(self.point_names), dtype=np.int64)
        self.x0 = initial_guess(self) if x0 is None else model.clip(np.asarray(x0, dtype=float)[None])[0]
        lower, upper = search_boxes(self._structure(), self.x0[None], search_radius_mm)
        self.lower, self.upper = lower[0], upper[0]

    def evaluate(self, params: np.ndarray, subset: np.ndarray | None = None) -> np.ndarray:
        """(N, P) -> (N,) loss over the points in ``subset`` (all by default). A bound loss
        returning another shape is a PluginError naming the objective."""
        subset = self.all_points if subset is None else subset
        joints = self.model.forward(params)
        points = joints if self.point_matrix is None else np.einsum("qj,njc->nqc", self.point_matrix, joints)
        # an image term (observed) scores the whole hand's joints too
        out = self.loss(points, subset, joints) if self.observed else self.loss(points, subset)
        return checked_losses(out, len(params), self.objective)

    def stage_points(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The model's stages as (name, parameter indices, point indices).

        A point is scored in the latest stage that moves any joint it depends on, so the
        stages' point sets partition the points.
        """
        return self._structure().stages

    def _structure(self) -> "_Structure":
        """What depends only on the model and the point names (shared by every frame)."""
        return structure_of(self.model, self.point_names)


def search_boxes(structure: "_Structure", x0: np.ndarray, search_radius_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) (F, P) of frames with initial guesses x0 (F, P): the model's bounds, the
    position within ``search_radius_mm`` of the guess, the quaternion within [-1, 1]."""
    lower = np.repeat(structure.bounds[0][None], len(x0), axis=0)
    upper = np.repeat(structure.bounds[1][None], len(x0), axis=0)
    lower[:, POSITION] = x0[:, POSITION] - search_radius_mm
    upper[:, POSITION] = x0[:, POSITION] + search_radius_mm
    lower[:, ORIENTATION] = np.maximum(lower[:, ORIENTATION], -1.0)
    upper[:, ORIENTATION] = np.minimum(upper[:, ORIENTATION], 1.0)
    return lower, upper


def prepare_frames(model: HandModel, objective: Objective, proposals: np.ndarray, confidences: np.ndarray,
                   point_names: Sequence[str], search_radius_mm: float = 60.0, x0: np.ndarray | None = None):
    """What :class:`Problem` computes, for F frames at once: proposals (F, Q, K, 3) mm and
    confidences (F, Q, K) -> (weights (F, Q, K), x0 (F, P), lower (F, P), upper (F, P), errors
    {frame position: message} for frames that cannot be fitted, whose rows are unspecified).
    Frames whose guess is not an alignment (fewer than 3 observed points) get a Problem each.
    With ``x0`` (F, P) given (tracking's start) the guesses are it, clipped to the model's bounds."""
    proposals = np.ascontiguousarray(proposals, dtype=np.float64)
    weights = np.ascontiguousarray(normalise_confidences(confidences))
    F = len(proposals)
    if F == 0:
        P = model.n_params
        return weights, np.empty((0, P)), np.empty((0, P)), np.empty((0, P)), {}
    structure = structure_of(model, point_names)
    if x0 is not None:
        x0 = model.clip(np.asarray(x0, dtype=np.float64).reshape(F, -1))
        return (weights, x0, *search_boxes(structure, x0, search_radius_mm), {})
    observed = weights.sum(axis=-1) > 0
    uses = [alignment_points(structure, observed[f]) for f in range(F)]
    at = np.cumsum([0] + [0 if u is None else len(u) for u in uses]).astype(np.int64)
    flat = np.concatenate([u for u in uses if u is not None] + [np.zeros(0, dtype=np.int64)])
    x0 = np.repeat(structure.default_params[None], F, axis=0)
    _aligned_guesses(structure.canonical, proposals, weights, at, flat, INLIER_MM, x0)
    errors = {}
    for f in range(F):
        if uses[f] is None:
            try:
                x0[f] = initial_guess(Problem(model, objective, proposals[f], confidences[f], point_names,
                                              search_radius_mm))
            except HybridfitError as err:
                errors[f] = str(err)
    lower, upper = search_boxes(structure, x0, search_radius_mm)
    return weights, x0, lower, upper, errors
