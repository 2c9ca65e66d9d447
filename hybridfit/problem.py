"""One frame's fitting problem: a model, an objective bound to the frame's proposals, the
mapping of proposal points onto model points, the search box and an initial guess."""

from __future__ import annotations

from typing import Sequence

import numba as nb
import numpy as np

from .errors import HybridfitError
from .model.base import ORIENTATION, POSITION, HandModel
from .model.kinematics import BLOCK, block_frames, block_points, sincos_rows
from .model.rotations import quaternion_matrix
from .objective import KERNEL_SIGNATURE, Objective, Observation, compiled_kernel_of, normalise_confidences  # noqa: F401


class Problem:
    """Minimise ``loss(points(params))`` for one frame.

    proposals: (Q, K, 3) mm for the Q points named by ``point_names`` (default: the
    model's joints); confidences: (Q, K) non-negative. The search box is the model's
    bounds, with the position limited to ``search_radius_mm`` around the initial guess.
    observation: the frame's depth (needed by objectives that ``observes_depth``); x0: (P,)
    an initial guess (tracking: the previous frame's fit) instead of the proposals' one.
    When the model has a ``kinematic_tree`` and the objective a valid ``compiled_kernel``
    (:func:`hybridfit.objective.capability`), :meth:`evaluate` runs compiled (:func:`tree_points`).
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
        # a kinematic tree and a compiled kernel: points by :func:`tree_points`, then the kernel
        self._kernel = compiled_kernel_of(objective) if callable(getattr(model, "kinematic_tree", None)) else None
        self._compiled_parts = None
        self.x0 = initial_guess(self) if x0 is None else model.clip(np.asarray(x0, dtype=float)[None])[0]
        lower, upper = search_boxes(self._structure(), self.x0[None], search_radius_mm)
        self.lower, self.upper = lower[0], upper[0]

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
        if self._kernel is not None and getattr(params, "ndim", 0) == 2 and params.shape[1] == self.model.n_params:
            return self._evaluate_compiled(params, subset)
        if self.observed:  # an image term needs the whole hand
            joints = self.model.forward(params)
            return self.loss(self._from_joints(joints), subset, joints)
        return self.loss(self.points(params, subset), subset)

    def _evaluate_compiled(self, params: np.ndarray, subset: np.ndarray) -> np.ndarray:
        """:meth:`evaluate` by :func:`tree_points` and the objective's compiled kernel (in
        this problem's working buffer: one thread at a time per problem)."""
        kernel, consts, tree, points_of = self._compiled()
        if subset is not self.all_points:
            subset = np.ascontiguousarray(subset, dtype=np.int64)
        key = subset.tobytes()
        joints = points_of.get(key)
        if joints is None:
            joints = points_of[key] = tree.joints_for(subset)
        points = np.empty((len(self.point_names), 3, len(params)))
        out = np.empty(len(params))
        tree_points(*tree.arrays, *tree.point_map, *joints, np.ascontiguousarray(params, dtype=np.float64), subset,
                    points, self._scratch)
        kernel(points, subset, self.proposals, self.weights, consts, out)
        return out

    def _compiled(self):
        if self._compiled_parts is None:
            tree = self._structure().tree()
            self._compiled_parts = (*self._kernel, tree, tree._joints)
            self._scratch = np.empty(scratch_size(self.model.n_params, len(tree.parents), len(self.point_names)))
        return self._compiled_parts

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
        return self._structure().stages

    def _structure(self) -> "_Structure":
        """What depends only on the model and the point names (shared by every frame)."""
        return structure_of(self.model, self.point_names, self.point_matrix)


def structure_of(model: HandModel, point_names: tuple[str, ...], point_matrix: np.ndarray | None) -> "_Structure":
    """The model's :class:`_Structure` over these points (point_matrix: None for the model's
    joints, else ``model.point_matrix(point_names)``), computed once."""
    key = (id(model), point_names)
    found = _STRUCTURES.get(key)
    if found is None or found.model is not model:
        if len(_STRUCTURES) >= 32:
            _STRUCTURES.clear()
        found = _STRUCTURES[key] = _Structure(model, point_matrix)
    return found


class _Structure:
    """A model's stages over a set of points, the points' depths in the kinematic tree and
    their positions in the model's neutral pose (mm), computed once per model and points."""

    def __init__(self, model: HandModel, point_matrix: np.ndarray | None) -> None:
        self.model = model
        owner = model.stage_of_joint()
        M = np.eye(model.n_joints) if point_matrix is None else point_matrix
        point_stage = np.array([owner[np.flatnonzero(row)].max() for row in M])
        self.stages = [
            (st.name, np.asarray(st.parameters, dtype=np.int64), np.flatnonzero(point_stage == s).astype(np.int64))
            for s, st in enumerate(model.stages())
        ]
        self.depths = point_depths(model.parents, M)
        self.neutral = np.einsum("qj,jc->qc", M, model.forward(model.default_params()))
        self.guides: dict[tuple, np.ndarray] = {}
        self.alignments: dict[bytes, np.ndarray | None] = {}
        lower, upper = model.bounds()
        self.bounds = lower.astype(float).copy(), upper.astype(float).copy()
        self.default_params = model.default_params().astype(float).copy()
        # the points in the default pose, as Problem.points gives them
        joints = model.forward(self.default_params[None])
        self.canonical = np.ascontiguousarray(
            joints[0] if point_matrix is None else np.einsum("qj,njc->nqc", M, np.nan_to_num(joints, nan=0.0))[0])
        self.point_matrix = point_matrix
        self._tree: _Tree | None = None

    def tree(self) -> "_Tree":
        """The model's kinematic tree and point map as :func:`tree_points` reads them."""
        if self._tree is None:
            self._tree = _Tree(self.model.kinematic_tree(), self.point_matrix, self.model.n_joints)
        return self._tree


class _Tree:
    """A kinematic tree's arrays, a point map (Q, J) in CSR form and, per subset of points,
    the joints to compute (cached)."""

    def __init__(self, tree, point_matrix: np.ndarray | None, n_joints: int) -> None:
        req = lambda a, dtype: np.require(a, dtype=dtype, requirements=["C", "W"])  # noqa: E731
        self.parents = req(tree.parents, np.int64)
        self.axes, self.axis_params = req(tree.axes, np.int64), req(tree.axis_params, np.int64)
        self.arrays = (self.parents, req(tree.offsets, np.float64), req(tree.rest, np.float64),
                       req(tree.rest_is_identity, np.bool_), self.axes, self.axis_params, float(tree.mirror))
        M = np.eye(n_joints) if point_matrix is None else point_matrix
        rows, cols = np.nonzero(M)
        self.point_map = (req(np.searchsorted(rows, np.arange(len(M) + 1)), np.int64), req(cols, np.int64),
                          req(M[rows, cols], np.float64))
        self._joints: dict[bytes, tuple] = {}

    def joints_for(self, subset: np.ndarray) -> tuple:
        """(order (J,), count, oriented (J,), angle rows (P,), angle count): the joints the
        points ``subset`` need, parents first, those whose rotation a needed child reads, and
        the parameters that are their angles."""
        key = np.asarray(subset, dtype=np.int64).tobytes()
        found = self._joints.get(key)
        if found is None:
            ptr, joint = self.point_map[0], self.point_map[1]
            needed = np.zeros(len(self.parents), dtype=bool)
            for q in np.asarray(subset, dtype=np.int64):
                for j in joint[ptr[q]:ptr[q + 1]]:
                    while j >= 0 and not needed[j]:
                        needed[j] = True
                        j = self.parents[j]
            order = np.flatnonzero(needed).astype(np.int64)
            oriented = np.zeros(len(self.parents), dtype=np.bool_)
            oriented[self.parents[order][self.parents[order] >= 0]] = True
            rows = np.unique(self.axis_params[order][self.axes[order] >= 0]).astype(np.int64)
            order_full = np.zeros(len(self.parents), dtype=np.int64)
            order_full[:len(order)] = order
            found = self._joints[key] = (order_full, len(order), oriented, rows, len(rows))
        return found


_STRUCTURES: dict[tuple, _Structure] = {}


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


def guide_points(problem: "Problem", root_points: np.ndarray, later: list[np.ndarray],
                 min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """The points that guide an ill-posed root stage: each later stage's observed points
    nearest to the root in the kinematic tree (``later``: each stage's points); none when
    the root's own observed points (fewer than ``min_points``, or nearly collinear) suffice."""
    return _guides(problem._structure(), problem.weights.sum(axis=-1) > 0, root_points, later, min_points,
                   min_lever_mm)


def _guides(structure: "_Structure", observed: np.ndarray, root_points: np.ndarray, later: list[np.ndarray],
            min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """:func:`guide_points` for the points ``observed`` (Q,) bool (cached per structure)."""
    key = (observed.tobytes(), root_points.tobytes(), tuple(p.tobytes() for p in later), min_points, min_lever_mm)
    if key not in structure.guides:
        own = root_points[observed[root_points]]
        if len(own) >= min_points and rotation_lever_mm(structure.neutral[own]) >= min_lever_mm:
            structure.guides[key] = np.zeros(0, dtype=np.int64)
        else:
            depth = structure.depths
            later = [p[observed[p]] for p in later]
            structure.guides[key] = np.concatenate(
                [p[depth[p] == depth[p].min()] for p in later if len(p)] + [np.zeros(0)]).astype(np.int64)
    return structure.guides[key]


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


#: a root point is consistent with an alignment when one of its proposals lies this close, mm
INLIER_MM = 20.0


def initial_guess(problem: Problem) -> np.ndarray:
    """Default articulation with the global pose from a weighted rigid alignment (Kabsch) of
    the model's root-stage points onto their proposals.

    The alignment is robust to one wrong top proposal: besides the most confident proposal
    of every point, each alternative proposal of each point is tried in its place, and the
    alignment that puts the most points within ``INLIER_MM`` of one of their proposals wins
    (ties: the smaller summed distance). One decoy on the point that alone fixes the palm's
    tilt (ICVL's palm point beside its row of knuckles) otherwise flips the hand. An
    ill-posed root (``guide_points``) is aligned together with its guide points.
    Falls back to all points, then to a translation only, when too few root points have
    proposals.
    """
    structure = problem._structure()
    x = structure.default_params.copy()
    use = alignment_points(structure, problem.weights.sum(axis=-1) > 0)
    if use is not None:
        _aligned_guess(structure.canonical, problem.proposals, problem.weights, use, INLIER_MM, x)
        return x
    target, w = top_proposals(problem.proposals, problem.weights)
    use = np.flatnonzero(w > 0)
    if len(use) == 0:
        raise HybridfitError("the frame has no proposals with positive confidence")
    x[POSITION] = np.average(target[use] - structure.canonical[use], axis=0, weights=w[use])
    return x


def alignment_points(structure: "_Structure", observed: np.ndarray) -> np.ndarray | None:
    """The points :func:`initial_guess` aligns when the points ``observed`` (Q,) bool have
    proposals: the root stage's and its guide points, else all, if at least 3 of them are
    observed; None when it falls back to a translation (cached per structure)."""
    key = observed.tobytes()
    if key not in structure.alignments:
        stages = structure.stages
        root_points = stages[0][2]
        root_points = np.union1d(root_points, _guides(structure, observed, root_points, [s[2] for s in stages[1:]]))
        structure.alignments[key] = None
        for candidates in (root_points, np.arange(len(observed))):
            use = candidates[observed[candidates]].astype(np.int64)
            if len(use) >= 3:
                structure.alignments[key] = use
                break
    return structure.alignments[key]


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
                   point_names: Sequence[str], search_radius_mm: float = 60.0):
    """What :class:`Problem` computes, for F frames at once: proposals (F, Q, K, 3) mm and
    confidences (F, Q, K) -> (weights (F, Q, K), x0 (F, P), lower (F, P), upper (F, P), errors
    {frame position: message} for frames that cannot be fitted, whose rows are unspecified).
    Frames whose guess is not an alignment (fewer than 3 observed points) get a Problem each."""
    proposals = np.ascontiguousarray(proposals, dtype=np.float64)
    weights = np.ascontiguousarray(normalise_confidences(confidences))
    F = len(proposals)
    if F == 0:
        P = model.n_params
        return weights, np.empty((0, P)), np.empty((0, P)), np.empty((0, P)), {}
    names = tuple(point_names)
    structure = structure_of(model, names, None if names == tuple(model.joint_names) else model.point_matrix(names))
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


@nb.njit(cache=True, nogil=True)
def _aligned_guesses(canonical, proposals, weights, at, flat, inlier_mm, x):
    """:func:`_aligned_guess` of each frame f with points flat[at[f]:at[f + 1]] (none: kept)."""
    for f in range(x.shape[0]):
        if at[f + 1] > at[f]:
            _aligned_guess(canonical, proposals[f], weights[f], flat[at[f]:at[f + 1]], inlier_mm, x[f])


@nb.njit(cache=True)
def _aligned_guess(canonical, proposals, weights, use, inlier_mm, x):
    """x[POSITION], x[ORIENTATION] = the robust alignment of canonical[use] (n, 3) mm onto
    their proposals (Q, K, 3) with weights (Q, K)."""
    n = use.shape[0]
    k = proposals.shape[1]
    source = np.empty((n, 3))
    props = np.empty((n, k, 3))
    w = np.empty((n, k))
    for i in range(n):
        source[i] = canonical[use[i]]
        props[i] = proposals[use[i]]
        w[i] = weights[use[i]]
    R, t = np.empty((3, 3)), np.empty(3)
    _robust_alignment(source, props, w, inlier_mm, R, t)
    x[0], x[1], x[2] = t[0], t[1], t[2]
    _matrix_quaternion(R, x[3:7])


@nb.njit(cache=True)
def _matrix_quaternion(R, q):
    """q (4,) = the unit quaternion (w, x, y, z), w >= 0, of the rotation matrix R (3, 3)
    (Shepperd's method: the largest of the trace and the diagonal picks the formula)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    c = 3
    best = tr
    for i in range(3):
        if R[i, i] > best:
            best, c = R[i, i], i
    v = np.empty(4)  # x, y, z, w
    if c == 3:
        v[0] = R[2, 1] - R[1, 2]
        v[1] = R[0, 2] - R[2, 0]
        v[2] = R[1, 0] - R[0, 1]
        v[3] = 1.0 + tr
    else:
        i, j, m = c, (c + 1) % 3, (c + 2) % 3
        v[i] = 1.0 - tr + 2.0 * R[i, i]
        v[j] = R[j, i] + R[i, j]
        v[m] = R[m, i] + R[i, m]
        v[3] = R[m, j] - R[j, m]
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3])
    sign = 1.0 if v[3] >= 0 else -1.0
    q[0] = sign * v[3] / norm
    q[1] = sign * v[0] / norm
    q[2] = sign * v[1] / norm
    q[3] = sign * v[2] / norm


def robust_alignment(source: np.ndarray, proposals: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (3, 3), t (3,) aligning source (n, 3) onto one proposal per point, proposals (n, k, 3)
    with weights (n, k): the most confident ones, or with one point's choice swapped for an
    alternative, whichever puts the most points within ``INLIER_MM`` of a proposal (ties:
    the smaller sum of distances, each capped at twice that)."""
    R, t = np.empty((3, 3)), np.empty(3)
    _robust_alignment(np.ascontiguousarray(source, dtype=np.float64), np.ascontiguousarray(proposals, dtype=np.float64),
                      np.ascontiguousarray(weights, dtype=np.float64), INLIER_MM, R, t)
    return R, t


@nb.njit(cache=True)
def _weighted_kabsch(source, target, w, R, t, scratch):
    """Weighted least-squares rotation and translation of source (n, 3) onto target (n, 3),
    w (n,) >= 0 (not all 0), into R, t: Horn's closed form (J. Opt. Soc. Am. A 4(4), 1987),
    the unit quaternion that is the top eigenvector of a symmetric 4 x 4 matrix (Jacobi
    rotations here: a proper rotation always, and 20x faster than LAPACK's 3 x 3 SVD).
    scratch: (4, 4, 4) working space."""
    n = source.shape[0]
    total = 0.0
    ms, mt, S, N, V = scratch[0, 0, :3], scratch[0, 1, :3], scratch[1, :3, :3], scratch[2], scratch[3]
    ms[:] = 0.0
    mt[:] = 0.0
    S[:] = 0.0
    for i in range(n):
        total += w[i]
        for a in range(3):
            ms[a] += w[i] * source[i, a]
            mt[a] += w[i] * target[i, a]
    for a in range(3):
        ms[a] /= total
        mt[a] /= total
    for i in range(n):
        for a in range(3):
            for b in range(3):
                S[a, b] += w[i] * (source[i, a] - ms[a]) * (target[i, b] - mt[b])
    N[0, 0] = S[0, 0] + S[1, 1] + S[2, 2]
    N[1, 1] = S[0, 0] - S[1, 1] - S[2, 2]
    N[2, 2] = -S[0, 0] + S[1, 1] - S[2, 2]
    N[3, 3] = -S[0, 0] - S[1, 1] + S[2, 2]
    N[0, 1] = N[1, 0] = S[1, 2] - S[2, 1]
    N[0, 2] = N[2, 0] = S[2, 0] - S[0, 2]
    N[0, 3] = N[3, 0] = S[0, 1] - S[1, 0]
    N[1, 2] = N[2, 1] = S[0, 1] + S[1, 0]
    N[1, 3] = N[3, 1] = S[2, 0] + S[0, 2]
    N[2, 3] = N[3, 2] = S[1, 2] + S[2, 1]
    V[:] = 0.0
    for a in range(4):
        V[a, a] = 1.0
    _jacobi_eigen(N, V)
    top = 0
    for c in range(1, 4):
        if N[c, c] > N[top, top]:
            top = c
    quaternion_matrix(V[0, top], V[1, top], V[2, top], V[3, top], R)
    for a in range(3):
        t[a] = mt[a] - (R[a, 0] * ms[0] + R[a, 1] * ms[1] + R[a, 2] * ms[2])


@nb.njit(cache=True)
def _jacobi_eigen(A, V):
    """Diagonalise the symmetric A (m, m) in place by cyclic Jacobi rotations: afterwards its
    diagonal holds the eigenvalues and the columns of V (start: identity) the eigenvectors."""
    m = A.shape[0]
    for _ in range(50):
        off = 0.0
        scale = 0.0
        for p in range(m):
            scale += A[p, p] * A[p, p]
            for q in range(p + 1, m):
                off += A[p, q] * A[p, q]
        if off <= 1e-30 * scale or off == 0.0:
            return
        for p in range(m - 1):
            for q in range(p + 1, m):
                if A[p, q] == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
                tt = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(tt * tt + 1.0)
                sn = tt * c
                for k in range(m):  # A <- A J (columns p, q)
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - sn * akq
                    A[k, q] = sn * akp + c * akq
                for k in range(m):  # A <- J^T A (rows p, q)
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - sn * aqk
                    A[q, k] = sn * apk + c * aqk
                for k in range(m):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq


@nb.njit(cache=True)
def _robust_alignment(source, proposals, weights, inlier_mm, R_out, t_out):
    n, k = weights.shape
    best = np.empty(n, np.int64)
    for q in range(n):
        best[q] = np.argmax(weights[q])
    choice = best.copy()
    target, w = np.empty((n, 3)), np.empty(n)
    R, t = np.empty((3, 3)), np.empty(3)
    scratch = np.empty((4, 4, 4))
    best_inliers, best_cost = -1, np.inf
    for h in range(1 + n * k):  # h = 0: the top proposals; then point (h-1)//k takes proposal (h-1)%k
        if h > 0:
            q, r = (h - 1) // k, (h - 1) % k
            if r == best[q] or weights[q, r] <= 0.0:
                continue
            choice[:] = best
            choice[q] = r
        for i in range(n):
            for a in range(3):
                target[i, a] = proposals[i, choice[i], a]
            w[i] = weights[i, choice[i]]
        _weighted_kabsch(source, target, w, R, t, scratch)
        inliers, cost, agree = 0, 0.0, True
        for i in range(n):
            s0, s1, s2 = source[i, 0], source[i, 1], source[i, 2]
            p0 = R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * s2 + t[0]
            p1 = R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * s2 + t[1]
            p2 = R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * s2 + t[2]
            nearest = np.inf
            for r2 in range(k):
                if weights[i, r2] > 0.0:
                    e0, e1, e2 = p0 - proposals[i, r2, 0], p1 - proposals[i, r2, 1], p2 - proposals[i, r2, 2]
                    nearest = min(nearest, np.sqrt(e0 * e0 + e1 * e1 + e2 * e2))
            e0, e1, e2 = p0 - target[i, 0], p1 - target[i, 1], p2 - target[i, 2]
            if np.sqrt(e0 * e0 + e1 * e1 + e2 * e2) >= 0.5 * inlier_mm:
                agree = False
            inliers += nearest < inlier_mm
            cost += min(nearest, 2.0 * inlier_mm)
        if inliers > best_inliers or (inliers == best_inliers and cost < best_cost):
            best_inliers, best_cost = inliers, cost
            for a in range(3):
                t_out[a] = t[a]
                for b in range(3):
                    R_out[a, b] = R[a, b]
        if h == 0 and agree:  # every top proposal agrees closely: nothing to try
            return




def scratch_size(P: int, J: int, Q: int) -> int:
    """Floats of :func:`tree_points`' working space for P parameters, J joints and Q points."""
    return BLOCK * (3 * P + 12 * J + 9 + 3 * Q)


@nb.njit(cache=True, nogil=True)
def tree_points(parents, offsets, rest, rest_identity, axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight,
                order, count, oriented, rows, n_rows, params, subset, out, scratch):
    """out (Q, 3, N) mm = the points ``subset`` of params (N, P), the hypothesis innermost (a
    compiled kernel's input): forward kinematics of the joints ``order[:count]`` (their
    rotations where ``oriented``, angles ``rows[:n_rows]``), in blocks of ``BLOCK``; scratch:
    working space of :func:`scratch_size` (P, J, Q) floats."""
    N, P = params.shape
    J = parents.shape[0]
    Q = out.shape[0]
    at = 0
    pB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    sinB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    cosB = scratch[at:at + P * BLOCK].reshape((P, BLOCK))
    at += P * BLOCK
    WB = scratch[at:at + J * 9 * BLOCK].reshape((J, 3, 3, BLOCK))
    at += J * 9 * BLOCK
    WpB = scratch[at:at + J * 3 * BLOCK].reshape((J, 3, BLOCK))
    at += J * 3 * BLOCK
    GB = scratch[at:at + 9 * BLOCK].reshape((3, 3, BLOCK))
    at += 9 * BLOCK
    pts = scratch[at:at + Q * 3 * BLOCK].reshape((Q, 3, BLOCK))
    for n0 in range(0, N, BLOCK):
        B = min(BLOCK, N - n0)
        for i in range(B):
            for k in range(P):
                pB[k, i] = params[n0 + i, k]
        sincos_rows(rows, n_rows, pB, sinB, cosB, B)
        block_frames(B, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_identity, axes,
                     axis_params, mirror, WB, WpB, GB)
        if N <= BLOCK:  # one block: straight into out
            block_points(B, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], out)
            return
        block_points(B, WpB, pm_ptr, pm_joint, pm_weight, subset, 0, subset.shape[0], pts)
        for t in range(subset.shape[0]):
            q = subset[t]
            for c in range(3):
                for i in range(B):
                    out[q, c, n0 + i] = pts[q, c, i]
