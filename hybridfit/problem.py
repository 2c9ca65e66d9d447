"""One frame's fitting problem: a model, an objective bound to the frame's proposals, the
mapping of proposal points onto model points, the search box and an initial guess."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .errors import HybridfitError
from .geometry import kabsch, matrix_to_quaternion
from .model import ORIENTATION, POSITION, HandModel
from .objective import Objective, Observation, normalise_confidences


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
        self.proposals = np.ascontiguousarray(proposals, dtype=np.float64)
        self.weights = np.ascontiguousarray(normalise_confidences(confidences))
        self.point_names = tuple(point_names) if point_names is not None else tuple(model.joint_names)
        if len(self.point_names) != self.proposals.shape[0]:
            raise HybridfitError(
                f"{len(self.point_names)} point names for {self.proposals.shape[0]} proposal points"
            )
        if self.point_names == tuple(model.joint_names):
            self.point_matrix = None
        else:
            self.point_matrix = model.point_matrix(self.point_names)
        self.observed = bool(getattr(objective, "observes_depth", False))
        if self.observed:
            if observation is None:
                raise HybridfitError(f"objective {objective.name or type(objective).__name__} compares hypotheses "
                                     f"with the depth image, and this frame has none")
            self.loss = objective.bind_observed(self.proposals, self.weights, observation, model)
        else:
            self.loss = objective.bind(self.proposals, self.weights)
        self.all_points = np.arange(len(self.point_names), dtype=np.int64)
        self._needed: dict[bytes, np.ndarray | None] = {}
        self.x0 = initial_guess(self) if x0 is None else model.clip(np.asarray(x0, dtype=float)[None])[0]
        lower, upper = model.bounds()
        lower, upper = lower.astype(float).copy(), upper.astype(float).copy()
        lower[POSITION] = self.x0[POSITION] - search_radius_mm
        upper[POSITION] = self.x0[POSITION] + search_radius_mm
        lower[ORIENTATION] = np.maximum(lower[ORIENTATION], -1.0)
        upper[ORIENTATION] = np.minimum(upper[ORIENTATION], 1.0)
        self.lower, self.upper = lower, upper

    def points(self, params: np.ndarray, subset: np.ndarray | None = None) -> np.ndarray:
        """(N, P) -> (N, Q, 3) model points matching the proposals' points, mm.

        With a ``subset`` of point indices only those points are guaranteed (the model may
        skip joints that no point of the subset depends on)."""
        joints = self.model.forward(params, None if subset is None else self._joints_for(subset))
        if self.point_matrix is None:
            return joints
        M = self.point_matrix if subset is None else self.point_matrix[subset]
        pts = np.zeros((len(params), len(self.point_names), 3))
        pts[:, self.all_points if subset is None else subset] = np.einsum(
            "qj,njc->nqc", M, np.nan_to_num(joints, nan=0.0))
        return pts

    def _joints_for(self, subset: np.ndarray) -> np.ndarray | None:
        """The joints the points in ``subset`` depend on (cached per subset)."""
        key = np.asarray(subset, dtype=np.int64).tobytes()
        if key not in self._needed:
            if self.point_matrix is None:
                self._needed[key] = np.asarray(subset, dtype=np.int64)
            else:
                self._needed[key] = np.flatnonzero(np.abs(self.point_matrix[subset]).sum(axis=0) > 0)
        return self._needed[key]

    def evaluate(self, params: np.ndarray, subset: np.ndarray | None = None) -> np.ndarray:
        """(N, P) -> (N,) loss over the points in ``subset`` (all by default)."""
        subset = self.all_points if subset is None else subset
        if self.observed:  # an image term needs the whole hand
            joints = self.model.forward(params)
            return self.loss(self._from_joints(joints), subset, joints)
        return self.loss(self.points(params, subset), subset)

    def _from_joints(self, joints: np.ndarray) -> np.ndarray:
        """All model joints (N, J, 3) -> (N, Q, 3) points."""
        if self.point_matrix is None:
            return joints
        return np.einsum("qj,njc->nqc", self.point_matrix, joints)

    def stage_points(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The model's stages as (name, parameter indices, point indices).

        A point is scored in the latest stage that moves any joint it depends on, so the
        stages' point sets partition the points.
        """
        stages = self.model.stages()
        owner = self.model.stage_of_joint()
        M = np.eye(self.model.n_joints) if self.point_matrix is None else self.point_matrix
        point_stage = np.array([owner[np.flatnonzero(row)].max() for row in M])
        return [
            (st.name, np.asarray(st.parameters, dtype=np.int64), np.flatnonzero(point_stage == s).astype(np.int64))
            for s, st in enumerate(stages)
        ]


def point_depths(parents: np.ndarray, point_matrix: np.ndarray) -> np.ndarray:
    """(Q,) each point's depth in the kinematic tree (root joint 0): that of the deepest joint
    it depends on. parents (J,), point_matrix (Q, J) as ``HandModel.point_matrix``."""
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):  # parents precede children
        depth[j] = 0 if p < 0 else depth[p] + 1
    return np.array([depth[np.flatnonzero(row)].max() for row in point_matrix], dtype=np.int64)


def top_proposals(proposals: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The most confident proposal per point and its weight: (Q, 3), (Q,)."""
    best = weights.argmax(axis=-1)
    q = np.arange(proposals.shape[0])
    return proposals[q, best], weights[q, best]


def initial_guess(problem: Problem) -> np.ndarray:
    """Default articulation with the global pose from a weighted rigid alignment (Kabsch)
    of the model's root-stage points onto their most confident proposals.

    Falls back to all points, then to a translation only, when too few root points have
    proposals.
    """
    model = problem.model
    x = model.default_params().astype(float).copy()
    canonical = problem.points(x[None])[0]
    target, w = top_proposals(problem.proposals, problem.weights)
    root_points = problem.stage_points()[0][2]
    for candidates in (root_points, problem.all_points):
        use = candidates[w[candidates] > 0]
        if len(use) >= 3:
            R, t = kabsch(canonical[use], target[use], w[use])
            x[POSITION] = t
            x[ORIENTATION] = matrix_to_quaternion(R)
            return x
    use = np.flatnonzero(w > 0)
    if len(use) == 0:
        raise HybridfitError("the frame has no proposals with positive confidence")
    x[POSITION] = np.average(target[use] - canonical[use], axis=0, weights=w[use])
    return x
