"""The abstract hand model: batched forward kinematics with anatomical bounds and stages.

Contract shared by every model (the core relies on it):

- parameters 0..2 are the position (millimetres) of the model's origin and parameters
  3..6 the global orientation as a quaternion (w, x, y, z), normalised inside the model so
  any 4-vector is valid; the remaining parameters are articulation (joint) angles in
  radians; ``parameter_names`` names all P of them (a joint angle's name is its column in
  ``hybridfit export-angles``);
- ``forward(params (N, P)) -> joints (N, J, 3)`` in millimetres, camera coordinates;
- with the identity quaternion and zero position, ``forward`` gives the model's pose in
  its own frame (used to initialise the global pose by rigid alignment);
- ``stages()`` partitions the parameters into groups and the joints into the joints each
  group moves that no later group moves (the paper's stepwise optimisation: the palm's 7
  parameters on the palm joints first, then each finger's angles on that finger's joints).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import HybridfitError, PluginError
from ..plugin import Plugin

GLOBAL_POSE = slice(0, 7)
POSITION = slice(0, 3)
ORIENTATION = slice(3, 7)
ANGLES = slice(7, None)  # the joint angles, radians


@dataclass(frozen=True)
class Stage:
    """A group of parameters optimised together and the joints it is scored on.

    parameters: indices into the parameter vector; joints: indices of the joints that this
    group moves and no later stage moves, so stage objectives add up to the full one.
    """

    name: str
    parameters: tuple[int, ...]
    joints: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class Geometry:
    """The geometry of a configured model that calibration may change, as a flat vector.

    All arrays are (G,). ``values``: the model's current geometry, lengths in mm, weights
    unitless; ``prior_mean`` and ``prior_std``: an anatomical prior for a hand of the
    model's reference size (lengths at scale 1; ``scaled`` marks the entries, lengths, that
    grow with the whole hand, whose prior is ``scale * prior_mean`` with std
    ``scale * prior_std`` for a free scale); ``lower``/``upper``: hard limits. ``ends``: per
    entry the two model points whose relation it sets: ``(parent joint, child joint)`` of
    a length or an offset along the kinematic tree, or ``(derived point, joint)`` for the
    weight of a joint in a derived point; calibration keeps an entry at its prior when the
    given points cannot determine it.
    """

    names: tuple[str, ...]
    values: np.ndarray
    prior_mean: np.ndarray
    prior_std: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scaled: np.ndarray
    ends: tuple[tuple[str, str], ...]

    def __post_init__(self) -> None:
        G = len(self.names)
        for field in ("values", "prior_mean", "prior_std", "lower", "upper", "scaled"):
            if np.shape(getattr(self, field)) != (G,):
                raise HybridfitError(f"Geometry.{field} must have shape ({G},), got {np.shape(getattr(self, field))}")
        if len(self.ends) != G:
            raise HybridfitError(f"Geometry.ends must name {G} pairs of points, got {len(self.ends)}")
        if not (np.all(self.prior_std > 0) and np.all(self.lower <= self.upper)):
            raise HybridfitError("Geometry: prior_std must be positive and lower <= upper")

    def __len__(self) -> int:
        return len(self.names)


def missing_points_message(model: str, missing: Sequence[str], of: int, points: Sequence[str]) -> str:
    """The one message for points to fit that a model lacks, naming every one of them."""
    return (f"model {model} lacks {len(missing)} of the {of} points to fit: {', '.join(map(repr, missing))} "
            f"(neither a joint nor a derived point of it; its points: {', '.join(points)})")


class HandModel(Plugin, abc.ABC):
    """A kinematic hand model mapping (N, P) parameter vectors to (N, J, 3) joints in mm."""

    #: names of the P parameters, in order: the 7 of the global pose, then the joint angles
    #: (unique, no whitespace, commas or quotes: they name the columns of exported angles)
    parameter_names: tuple[str, ...]
    #: names of the J joints, in order
    joint_names: tuple[str, ...]
    #: name of a boolean setting choosing the mirror-image (left) hand; None: the model has none
    mirror_setting: str | None = None
    #: name of a setting {point: {joint: weight}} adding derived points; None: the model has none
    derived_points_setting: str | None = None

    @property
    @abc.abstractmethod
    def parents(self) -> np.ndarray:
        """(J,) index of each joint's parent joint, -1 for the root."""

    @property
    def derived_points(self) -> Mapping[str, Mapping[str, float]]:
        """Named points that are fixed linear combinations of joints, {name: {joint: weight}}.

        They let datasets whose annotations are not joints (a palm centre, say) be mapped
        onto the model.
        """
        return {}

    @abc.abstractmethod
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower (P,), upper (P,)) limits; angles in radians, +-inf where unbounded."""

    @abc.abstractmethod
    def default_params(self) -> np.ndarray:
        """(P,) a neutral pose at the origin with the identity orientation."""

    @abc.abstractmethod
    def stages(self) -> tuple[Stage, ...]:
        """The parameter groups for stepwise optimisation, root (global pose) first."""

    @abc.abstractmethod
    def _forward(self, params: np.ndarray) -> np.ndarray:
        """(N, P) float64 C-contiguous -> (N, J, 3) joints in mm."""

    def named_poses_deg(self) -> Mapping[str, np.ndarray]:
        """Named hand shapes, {name: (P - 7,) articulation angles in degrees, in parameter
        order}: the key poses of the synthetic test sequence's motions
        (``hybridfit.synthetic.poses.MOTIONS``). Default: none; the sequence then takes a
        random shape within the bounds for every pose the model does not name."""
        return {}

    def grid_articulations_deg(self) -> Mapping[str, Sequence[Sequence[float]]]:
        """The synthetic training grid's articulations, {stage name: [(that stage's angles in
        degrees), ...]}; every combination across stages is one hand shape. Default: none; a
        stage not given gets ``hybridfit.synthetic.poses.FALLBACK_SHARES`` of its ranges."""
        return {}

    def geometry(self) -> Geometry:
        """The geometry calibration may change (see :class:`Geometry`); a model without
        calibratable geometry raises."""
        raise HybridfitError(f"model {self.name or type(self).__name__} declares no calibratable geometry")

    def with_geometry(self, values: np.ndarray) -> dict[str, Any]:
        """The complete settings of this model with geometry ``values`` (G,) (a config
        ``registry.create`` and ``type(self)(**settings)`` accept)."""
        raise HybridfitError(f"model {self.name or type(self).__name__} declares no calibratable geometry")

    # ----------------------------------------------------------------- derived API
    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def forward(self, params: np.ndarray) -> np.ndarray:
        """Batched forward kinematics: params (N, P) or (P,) -> joints (N, J, 3) or (J, 3), mm.
        ``_forward`` giving anything but float64 (N, J, 3) is a PluginError naming the model."""
        params = np.asarray(params, dtype=np.float64)
        single = params.ndim == 1
        batch = np.ascontiguousarray(params[None] if single else params)
        if batch.ndim != 2 or batch.shape[1] != self.n_params:
            raise HybridfitError(
                f"{self.name or type(self).__name__}: parameters must have shape (N, {self.n_params}), "
                f"got {params.shape}"
            )
        out = self._forward(batch)
        shape = (len(batch), self.n_joints, 3)
        if not (isinstance(out, np.ndarray) and out.dtype == np.float64 and out.shape == shape):
            raise PluginError(f"model {self.name or type(self).__name__}: forward((N, {self.n_params})) returned "
                              f"{getattr(out, 'dtype', type(out).__name__)} {getattr(out, 'shape', '')}, expected "
                              f"float64 {shape} (N, J, 3) joints in mm")
        return out[0] if single else out

    @property
    def point_names(self) -> tuple[str, ...]:
        """Joint names followed by the derived point names."""
        return tuple(self.joint_names) + tuple(self.derived_points)

    def point_matrix(self, names: Sequence[str]) -> np.ndarray:
        """(Q, J) weights so that points = point_matrix @ joints for the named points."""
        index = {n: i for i, n in enumerate(self.joint_names)}
        missing = [str(n) for n in names if n not in index and n not in self.derived_points]
        if missing:
            raise HybridfitError(missing_points_message(self.name or type(self).__name__, missing, len(names),
                                                        self.point_names))
        M = np.zeros((len(names), self.n_joints))
        for q, name in enumerate(names):
            if name in index:
                M[q, index[name]] = 1.0
            else:
                for joint, weight in self.derived_points[name].items():
                    M[q, index[joint]] += weight
        return M

    def points(self, params: np.ndarray, names: Sequence[str]) -> np.ndarray:
        """Named joints or derived points: params (N, P) -> (N, Q, 3) mm."""
        return np.einsum("qj,njc->nqc", self.point_matrix(names), self.forward(np.atleast_2d(params)))

    def stage_of_joint(self) -> np.ndarray:
        """(J,) index of the stage whose `joints` contain each joint."""
        owner = np.full(self.n_joints, -1)
        for s, stage in enumerate(self.stages()):
            owner[list(stage.joints)] = s
        if (owner < 0).any():
            missing = [self.joint_names[j] for j in np.flatnonzero(owner < 0)]
            raise HybridfitError(f"model {self.name}: joints {missing} belong to no stage")
        return owner

    def clip(self, params: np.ndarray) -> np.ndarray:
        """params clipped into the model's bounds."""
        lower, upper = self.bounds()
        return np.clip(params, lower, upper)
