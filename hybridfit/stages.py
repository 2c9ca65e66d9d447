"""A model's stages over a set of points, and the guide points of an ill-posed root stage.

Computed once per model and point names (:func:`structure_of`): the stages (parameters and
the points each scores), the points' depths in the kinematic tree and positions in the neutral
pose, and the tree's arrays for compiled scoring (the joints a set of points needs are found
by :func:`~hybridfit.model.kinematics.block_setup`, with the one walker). When a root stage's own
observed points cannot determine the global rotation (too few, or nearly collinear), it is
also scored on each later stage's observed points nearest to the root (:func:`guide_points`).
"""

from __future__ import annotations

import numpy as np

from .errors import PluginError
from .model.base import HandModel


def structure_of(model: HandModel, point_names) -> _Structure:
    """The model's :class:`_Structure` over these points, computed once per model and points: a
    model equal to one seen before (the same class and equal settings, which a plugin's
    structure depends on only) shares its structure, so a model created again by name for
    every fit does not rebuild it."""
    settings = getattr(model, "settings", None)
    point_names = tuple(point_names)
    last = _LAST.get((id(model), point_names))  # this model instance's, found before
    if last is not None and last[0] is model and last[1] is settings:
        return last[2]
    bucket = _STRUCTURES.setdefault((type(model), point_names), [])
    for found in bucket:
        if found.model is model and found.settings is settings or (settings is not None and found.settings == settings):
            break
    else:
        if sum(len(b) for b in _STRUCTURES.values()) >= 32:
            _STRUCTURES.clear()
            bucket = _STRUCTURES.setdefault((type(model), point_names), [])
        found = _Structure(model, None if point_names == tuple(model.joint_names) else model.point_matrix(point_names))
        bucket.append(found)
    if len(_LAST) >= 32:
        _LAST.clear()
    _LAST[(id(model), point_names)] = (model, settings, found)
    return found


class _Structure:
    """A model's stages over a set of points (``point_matrix`` (Q, J), None: the joints), the
    points' depths in the kinematic tree and their positions in the default pose (mm), computed
    once per model and points."""

    def __init__(self, model: HandModel, point_matrix: np.ndarray | None) -> None:
        self.model = model
        self.settings = getattr(model, "settings", None)  # the settings it was computed for
        check_model(model)
        owner = model.stage_of_joint()
        M = np.eye(model.n_joints) if point_matrix is None else point_matrix
        if not np.isfinite(M).all():
            raise PluginError(f"model {_name(model)}: its derived points have NaN or inf joint weights")
        point_stage = np.array([owner[np.flatnonzero(row)].max() for row in M])
        self.stages = [
            (st.name, np.asarray(st.parameters, dtype=np.int64), np.flatnonzero(point_stage == s).astype(np.int64))
            for s, st in enumerate(model.stages())
        ]
        self.depths = point_depths(model.parents, M)
        self.guides: dict[tuple, np.ndarray] = {}
        self.alignments: dict[bytes, np.ndarray | None] = {}
        lower, upper = model.bounds()
        self.bounds = lower.astype(float), upper.astype(float)  # copies
        self.default_params = model.default_params().astype(float)
        # the points in the default pose (Q, 3) mm, as Problem.points gives them
        joints = model.forward(self.default_params[None])
        if not np.isfinite(joints).all():
            raise PluginError(f"model {_name(model)}: its default pose has non-finite joints (NaN or inf)")
        #: the median distance of the neutral pose's joints from their centre, mm (the model's size)
        self.spread_mm = float(np.median(np.linalg.norm(joints[0] - np.median(joints[0], axis=0), axis=-1)))
        self.canonical = np.ascontiguousarray(
            joints[0] if point_matrix is None else np.einsum("qj,njc->nqc", M, np.nan_to_num(joints, nan=0.0))[0])
        self.point_matrix = point_matrix
        rows, cols = np.nonzero(M)
        self._point_map = (_require(np.searchsorted(rows, np.arange(len(M) + 1)), np.int64),
                           _require(cols, np.int64), _require(M[rows, cols], np.float64))
        self._tree: _Tree | None = None

    def point_map(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The point map (Q, J) in CSR form (row starts (Q + 1,), joints, weights), as the block
        kinematics (:mod:`hybridfit.model.kinematics`) read it."""
        return self._point_map

    def tree(self) -> _Tree | None:
        """The model's kinematic tree and point map as the block kinematics read them (None
        when its ``kinematic_tree`` returns None)."""
        if self._tree is None:
            tree = self.model.kinematic_tree()
            if tree is None:  # the model has none after all
                return None
            self._tree = _Tree(tree, self.point_map())
        return self._tree


class _Tree:
    """A kinematic tree's arrays and a point map (Q, J) in CSR form, as the block kinematics
    (:mod:`hybridfit.model.kinematics`) read them."""

    def __init__(self, tree, point_map: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
        self.parents = _require(tree.parents, np.int64)
        self.axes, self.axis_params = _require(tree.axes, np.int64), _require(tree.axis_params, np.int64)
        self.arrays = (self.parents, _require(tree.offsets, np.float64), _require(tree.rest, np.float64),
                       _require(tree.rest_is_identity, np.bool_), self.axes, self.axis_params, float(tree.mirror))
        self.point_map = point_map


def check_model(model: HandModel) -> None:
    """What the core reads of a model before it fits with it, checked once per model and points
    (a model's bug is a PluginError naming it): parents (J,), bounds two (P,) arrays with
    lower <= upper, default_params (P,) within them, stages naming parameters and joints it has."""
    name, P, J = _name(model), model.n_params, model.n_joints

    def named(indices) -> str:
        return ", ".join(repr(model.parameter_names[i]) for i in indices[:5]) + (" ..." if len(indices) > 5 else "")

    parents = np.asarray(model.parents)
    if parents.shape != (J,):
        raise PluginError(f"model {name}: parents has shape {parents.shape}, expected ({J},) (one per joint)")
    lower, upper = (np.asarray(b) for b in model.bounds())
    if lower.shape != (P,) or upper.shape != (P,) or lower.dtype.kind not in "fiu" or upper.dtype.kind not in "fiu":
        raise PluginError(f"model {name}: bounds() gave arrays of shapes {lower.shape} and {upper.shape} "
                          f"({lower.dtype}, {upper.dtype}), expected two ({P},) float arrays (one entry per parameter)")
    crossed = np.flatnonzero(~(lower <= upper))
    if len(crossed):
        raise PluginError(f"model {name}: bounds() has lower > upper (or NaN) for {named(crossed)}")
    x0 = np.asarray(model.default_params())
    if x0.shape != (P,):
        raise PluginError(f"model {name}: default_params() has shape {x0.shape}, expected ({P},)")
    outside = np.flatnonzero(~((x0 >= lower) & (x0 <= upper)))
    if len(outside):
        raise PluginError(f"model {name}: default_params() is outside its bounds for {named(outside)}")
    for stage in model.stages():
        for kind, indices, n in (("parameter", stage.parameters, P), ("joint", stage.joints, J)):
            beyond = [int(i) for i in indices if not 0 <= int(i) < n]
            if beyond:
                raise PluginError(f"model {name}: stage {stage.name!r} names {kind} {beyond[0]}, beyond its {n} "
                                  f"{kind}s")


def _name(model) -> str:
    return getattr(model, "name", None) or type(model).__name__


def _require(a, dtype) -> np.ndarray:
    """``a`` as a C-contiguous, writable array of ``dtype`` (as the compiled kinematics take it)."""
    return np.require(a, dtype=dtype, requirements=["C", "W"])


#: structures by (model class, point names): those of models with distinct settings
_STRUCTURES: dict[tuple, list[_Structure]] = {}
#: the structure last found for (a model instance's id, point names), with the model and its
#: settings (the id is that model's only while it is held here)
_LAST: dict[tuple, tuple] = {}


def point_depths(parents: np.ndarray, point_matrix: np.ndarray) -> np.ndarray:
    """(Q,) each point's depth in the kinematic tree (root joint 0): that of the deepest joint
    it depends on. parents (J,), point_matrix (Q, J) as ``HandModel.point_matrix``."""
    depth = np.zeros(len(parents), dtype=np.int64)
    for j, p in enumerate(parents):  # parents precede children
        depth[j] = 0 if p < 0 else depth[p] + 1
    return np.array([depth[np.flatnonzero(row)].max() for row in point_matrix], dtype=np.int64)


#: a root stage with fewer observed points than this cannot determine the global rotation
#: robustly (one wrong proposal of three moves it freely) ...
MIN_ROOT_POINTS = 4
#: ... nor one whose observed points are nearly collinear (``rotation_lever_mm`` below this, mm)
MIN_ROOT_LEVER_MM = 10.0


def rotation_lever_mm(points: np.ndarray) -> float:
    """How well (Q, 3) points determine a rotation: the root-mean-square distance of the points
    from the axis (through their centroid) about which they constrain a rotation least, mm.
    0 for collinear points; a rotation error is about noise / (lever * sqrt(Q)) radians."""
    if len(points) < 3:
        return 0.0
    c = points - points.mean(axis=0)
    inertia = np.eye(3) * (c * c).sum() - c.T @ c
    return float(np.sqrt(max(np.linalg.eigvalsh(inertia)[0], 0.0) / len(points)))


def guide_points(problem, root_points: np.ndarray, later: list[np.ndarray],
                 min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """The points that guide an ill-posed root stage: each later stage's observed points
    nearest to the root in the kinematic tree (``later``: each stage's points); none when the
    root's own observed points suffice (at least ``min_points``, not nearly collinear)."""
    return _guides(problem._structure(), problem.weights.sum(axis=-1) > 0, root_points, later, min_points,
                   min_lever_mm)


def _guides(structure: _Structure, observed: np.ndarray, root_points: np.ndarray, later: list[np.ndarray],
            min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """:func:`guide_points` for the points ``observed`` (Q,) bool (cached per structure)."""
    key = (observed.tobytes(), root_points.tobytes(), tuple(p.tobytes() for p in later), min_points, min_lever_mm)
    if key not in structure.guides:
        own = root_points[observed[root_points]]
        if len(own) >= min_points and rotation_lever_mm(structure.canonical[own]) >= min_lever_mm:
            structure.guides[key] = np.zeros(0, dtype=np.int64)
        else:
            depth = structure.depths
            later = [p[observed[p]] for p in later]
            structure.guides[key] = np.concatenate(
                [p[depth[p] == depth[p].min()] for p in later if len(p)] + [np.zeros(0)]).astype(np.int64)
    return structure.guides[key]
