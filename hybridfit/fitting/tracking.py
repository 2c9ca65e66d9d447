"""Tracking: fit a sequence frame by frame, each frame starting from the previous frame's fit.

Frame t's initial guess (the centre of the optimiser's search) is frame t-1's fitted
parameters; frame 0 starts from ``first_params`` (the paper's FORTH set-up: the ground
truth) or, without them, from its proposals (``hybridfit.alignment.initial_guess``). Frame
t draws as frame t of ``hybridfit.fit`` does, through the same driver with its start given;
frames depend on each other, so a sequence runs in one process.

Lost track: a fit is *lost* when its points lie, in the median over the points that have
proposals, further than ``lost_distance_mm`` from their nearest proposal (frames without
any proposal are never called lost). The default, 20 mm, is about three times the forest's
mean top-1 error on the synthetic sequence (the docs' results page) and was not tuned. ``on_lost = "reinit"`` starts the next frame from its own
proposals instead of the lost fit; ``"continue"`` (FORTH) keeps tracking from it.
"""

from __future__ import annotations

import json

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Mapping, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from tqdm.auto import tqdm

from .. import registry
from ..errors import HybridfitError
from .driver import Driver
from .frames import INLIER_DISTANCE_MM, FitResult, _first_problem, check_fit_options, model_label, schedules
from ..io import validate_proposals
from ..keys import frame_indices
from ..metrics import inliers
from ..task import Task

if TYPE_CHECKING:
    from ..model.base import HandModel
    from ..names import ModelName, ObjectiveName, OptimizerName
    from ..objective import Objective
    from ..optimizer import Optimizer


class TrackingSettings(BaseModel):
    """How a sequence is tracked (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    on_lost: Literal["continue", "reinit"] = Field("reinit", description="when a fit is lost: keep tracking from it "
                                                   "(continue, FORTH) or start the next frame from its proposals")
    lost_distance_mm: float = Field(20.0, gt=0, description="a fit whose points' median distance to their "
                                    "nearest proposal exceeds this is lost, mm")


@dataclass
class TrackResult(FitResult):
    """A FitResult plus per frame: lost (F,) bool, the fit was lost; started_from_proposals
    (F,) bool, the frame's initial guess came from its proposals (frame 0 without
    first_params, and every frame after a lost one under ``reinit``)."""

    lost: np.ndarray | None = None
    started_from_proposals: np.ndarray | None = None


def nearest_proposal_distance(points: np.ndarray, proposals: np.ndarray, confidences: np.ndarray) -> float:
    """Median over the points with proposals of the distance (mm) from each point (Q, 3) to
    its nearest proposal (Q, K, 3) of positive confidence (Q, K); 0 when no point has any."""
    d = np.linalg.norm(proposals - points[:, None], axis=-1)
    d = np.where(confidences > 0, d, np.inf).min(axis=-1)
    d = d[np.isfinite(d)]
    return float(np.median(d)) if len(d) else 0.0


def track(
    proposals: np.ndarray,
    confidences: np.ndarray,
    *,
    model: ModelName | str | HandModel = "hand26",
    objective: ObjectiveName | str | Objective = "clamped-then-soft-l1",
    optimizer: OptimizerName | str | Optimizer = "stepwise-pso",
    budget: int = 3400,
    seed: int = 0,
    joint_names: Sequence[str] | None = None,
    model_config: Mapping[str, Any] | None = None,
    objective_config: Mapping[str, Any] | None = None,
    optimizer_config: Mapping[str, Any] | None = None,
    search_radius_mm: float = 60.0,
    observations: Sequence[Any] | None = None,
    first_params: np.ndarray | None = None,
    settings: TrackingSettings | Mapping[str, Any] | None = None,
    progress: bool = False,
    frames: Sequence[int] | None = None,
) -> TrackResult:
    """Track a sequence: arguments as ``hybridfit.fit`` (proposals (F, Q, K, 3) mm in frame
    order; ``frames``: their indices in the data set, which key their random streams), plus
    first_params (P,) frame 0's initial guess and the tracking ``settings``."""
    check_fit_options(budget, seed, search_radius_mm, 1)
    settings = settings if isinstance(settings, TrackingSettings) else TrackingSettings(**(settings or {}))
    model = registry.create("model", model, model_config)
    objective = registry.create("objective", objective, objective_config)
    optimizer = registry.create("optimizer", optimizer, optimizer_config)
    names = tuple(str(n) for n in joint_names) if joint_names is not None else tuple(model.joint_names)
    proposals, confidences = validate_proposals(proposals, confidences, names)
    F, P, Q, J = len(proposals), model.n_params, len(names), model.n_joints
    if objective.observes_depth and observations is None:
        raise HybridfitError(f"objective {objective.name or type(objective).__name__} compares hypotheses with the "
                             f"depth image: give the frames' depth (observations)")
    if observations is not None and len(observations) != F:
        raise HybridfitError(f"{len(observations)} observations for {F} frames of proposals")
    if first_params is not None:
        first_params = np.asarray(first_params, dtype=float)
        if first_params.shape != (P,) or not np.isfinite(first_params).all():
            raise HybridfitError(f"first_params must be {P} finite model parameters, got shape {first_params.shape}")
    result = TrackResult(params=np.full((F, P), np.nan), joints=np.full((F, Q, 3), np.nan),
                         model_joints=np.full((F, J, 3), np.nan), objective=np.full(F, np.nan),
                         evaluations=np.zeros(F, np.int64), joint_names=names, failed=np.ones(F, bool),
                         lost=np.zeros(F, bool), started_from_proposals=np.zeros(F, bool),
                         parameter_names=tuple(model.parameter_names), **model_label(model))
    problem = _first_problem(model, objective, proposals, confidences, names, search_radius_mm, observations)
    if problem is not None:  # a budget too small would fail every frame: raised at once
        optimizer.check_budget(Task(problem, budget))
    fitter = Driver(model, objective, optimizer, names, budget, seed, search_radius_mm, frame_indices(frames, F))
    start = first_params
    t = 0
    try:
        for t in tqdm(range(F), disable=not progress, unit="frame", desc="track"):
            result.started_from_proposals[t] = start is None
            fitted = fitter.fit_chunk([t], proposals[t:t + 1], confidences[t:t + 1],
                                      observations=None if observations is None else [observations[t]],
                                      x0=None if start is None else start[None])
            if fitted.errors:  # this frame cannot be fitted: recorded, tracking goes on
                result.errors[t] = fitted.errors[t]
                continue
            params = fitted.params[0]
            result.params[t], result.joints[t], result.model_joints[t] = params, fitted.points[0], fitted.joints[0]
            result.objective[t], result.evaluations[t] = fitted.loss[0], fitted.evaluations[0]
            result.failed[t] = False
            result.lost[t] = nearest_proposal_distance(result.joints[t], proposals[t], confidences[t]) > \
                settings.lost_distance_mm
            start = None if result.lost[t] and settings.on_lost == "reinit" else params
    except KeyboardInterrupt:
        result.interrupted = True
        for f in range(t, F):
            if result.failed[f]:
                result.errors.setdefault(f, "interrupted")
    result.inlier_distance_mm = float(objective.get_params().get("d_max_mm", INLIER_DISTANCE_MM))
    result.inliers = inliers(result.joints, proposals, confidences, result.inlier_distance_mm)
    result.schedule = json.dumps(schedules(fitter, model, objective, proposals, confidences, names, search_radius_mm,
                                           ~result.failed, observations))
    return result
