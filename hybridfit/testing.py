"""Conformance checks that every hybridfit plugin, built-in or third-party, must pass.

In the spirit of scikit-learn's ``check_estimator``: each check is a separate public
function taking a configured plugin and raising ``AssertionError`` with a message naming
the plugin and what is wrong, so a test suite can parametrize over (plugin, check) with
one test id each::

    from hybridfit import registry, testing

    @pytest.mark.parametrize("check", testing.checks("optimizer"), ids=lambda c: c.__name__)
    def test_my_optimizer(check):
        check(registry.create("optimizer", "my-optimizer"))

``check_model``, ``check_objective`` and ``check_optimizer`` run all checks of a kind. A check
that does not apply to a plugin (a capability it does not declare) is skipped with its
reason (``unittest.SkipTest``, which pytest reports as skipped), never passed.
Optimiser checks fit small synthetic frames of the suite's own :class:`ToyHand` (a wrist and
two 3-joint fingers, 13 parameters, 7 joints) with its own objectives (:class:`ToyClamped`,
the paper's, and :class:`ToyLeastSquares`), so they take seconds and depend on no plugin. (The checks of objectives that observe depth render
the suite's ToyHand too.)
"""

from __future__ import annotations

import json
import pickle
import unittest
from typing import Callable

import numpy as np

from pydantic import Field

from .errors import HybridfitError
from .fitting.angles import PARAMETER_NAME
from .fitting.evaluator import frames_innermost, frames_innermost_points
from .model.kinematics import NO_AXIS, X_AXIS, Z_AXIS, KinematicTree, TreeHandModel
from .model.base import ANGLES, HandModel, Stage
from .objective import Objective, capability, compiled_kernel_of, normalise_confidences
from .optimizer import Optimizer, Task
from .plugin import Settings
from .problem import Problem
from .synthetic.proposals import synthetic_proposals

__all__ = [
    "ToyHand", "ToyClamped", "ToyLeastSquares", "RecordingTask", "check_config_round_trip", "check_pickle", "check_unknown_setting", "checks",
    "check_model", "check_objective", "check_optimizer", "check_plugin",
]

#: evaluations per optimiser check (raised to the optimiser's min_budget when that is larger)
CHECK_BUDGET = 150


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise AssertionError(message)


def not_applicable(plugin, reason: str) -> None:
    """Skip a check that does not apply to this plugin, saying why: raises
    ``unittest.SkipTest``, which pytest and unittest report as skipped (never passed)."""
    raise unittest.SkipTest(f"{_label(plugin)}: {reason}")


def _label(plugin) -> str:
    return f"{type(plugin).__name__} ({plugin.name or 'unregistered'})"


# ------------------------------------------------------------------ the suite's own model
class ToyHandSettings(Settings):
    bone_mm: float = Field(30.0, gt=0, description="length of every finger bone, mm")


class ToyHand(TreeHandModel):
    """A toy hand for the checks: a wrist and two fingers of 3 joints (13 parameters).

    Each finger's base sits 60 mm from the wrist; its base joint turns about z (abduction)
    then x (flexion), its middle joint about x. Stages: the palm (global pose; wrist and
    finger bases), then each finger's 3 angles on its middle joint and tip.
    """

    Settings = ToyHandSettings
    parameter_names = ("x", "y", "z", "qw", "qx", "qy", "qz",
                       "a_abduct", "a_flex1", "a_flex2", "b_abduct", "b_flex1", "b_flex2")
    joint_names = ("wrist", "a1", "a2", "a3", "b1", "b2", "b3")

    def kinematic_tree(self) -> KinematicTree:
        L = self.settings.bone_mm
        parents = np.array([-1, 0, 1, 2, 0, 4, 5], dtype=np.int64)
        offsets = np.array([[0, 0, 0], [-20, -60, 0], [0, -L, 0], [0, -L, 0],
                            [20, -60, 0], [0, -L, 0], [0, -L, 0]], dtype=float)
        axes = np.full((7, 2), NO_AXIS, dtype=np.int64)
        axis_params = np.zeros((7, 2), dtype=np.int64)
        for base, first in ((1, 7), (4, 10)):
            axes[base], axis_params[base] = (Z_AXIS, X_AXIS), (first, first + 1)
            axes[base + 1, 0], axis_params[base + 1, 0] = X_AXIS, first + 2
        return KinematicTree(parents, offsets, np.tile(np.eye(3), (7, 1, 1)), axes, axis_params)

    def bounds(self):
        lower, upper = np.full(13, -np.inf), np.full(13, np.inf)
        lower[3:7], upper[3:7] = -1.0, 1.0
        lower[7:], upper[7:] = np.tile([-0.35, -0.3, 0.0], 2), np.tile([0.35, 1.6, 1.8], 2)
        return lower, upper

    def default_params(self):
        return np.array([0, 0, 0, 1, 0, 0, 0, 0, 0.2, 0.2, 0, 0.2, 0.2], dtype=float)

    def stages(self):
        return (Stage("palm", tuple(range(7)), (0, 1, 4)), Stage("a", (7, 8, 9), (2, 3)),
                Stage("b", (10, 11, 12), (5, 6)))


# ------------------------------------------------------------------ the suite's own objectives
class ToyClampedSettings(Settings):
    d_max_mm: float = Field(40.0, gt=0, description="clamping distance d_max in millimetres")


class ToyClamped(Objective):
    """The paper's clamped, confidence-weighted objective in a few lines of numpy, for the
    optimiser checks: loss = -sum_j max_r w_jr (1 - min(1, ||p_jr - h_j|| / d_max)^2), in
    [-Q, 0] for weights that sum to 1 per point."""

    Settings = ToyClampedSettings

    def bind(self, proposals, weights):
        proposals, weights = np.asarray(proposals, dtype=np.float64), np.asarray(weights, dtype=np.float64)
        scale = 1.0 / self.settings.d_max_mm**2

        def loss(points, subset):  # points (N, Q, 3), subset (m,) -> (N,)
            d2 = np.square(np.asarray(points)[:, subset, None, :] - proposals[subset]).sum(axis=-1)  # (N, m, K)
            return -np.maximum(weights[subset] * (1.0 - d2 * scale), 0.0).max(axis=-1).sum(axis=-1)

        return loss

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())


class ToyLeastSquares(Objective):
    """Squared distance (mm^2) from each point to its most confident proposal, summed, for
    the optimiser checks with a known optimum (0 where every point is on its proposal); a
    point without proposals (all weights 0) contributes 0."""

    def bind(self, proposals, weights):
        proposals, weights = np.asarray(proposals, dtype=np.float64), np.asarray(weights, dtype=np.float64)
        targets = np.take_along_axis(proposals, weights.argmax(axis=-1)[:, None, None], axis=1)[:, 0]  # (Q, 3)
        active = weights.max(axis=-1) > 0

        def loss(points, subset):
            d2 = np.square(np.asarray(points)[:, subset] - targets[subset]).sum(axis=-1)  # (N, m)
            return (d2 * active[subset]).sum(axis=-1)

        return loss

    def lower_bound(self, weights):
        return 0.0


# ------------------------------------------------------------------ every plugin
def check_config_round_trip(plugin) -> None:
    """``type(p)(**p.get_params()) == p``, through JSON too, and ``with_params()`` equals p."""
    params = plugin.get_params()
    _require(type(plugin)(**params) == plugin, f"{_label(plugin)}: rebuilding from get_params() gives a different plugin")
    again = json.loads(json.dumps(params))
    _require(type(plugin)(**again) == plugin, f"{_label(plugin)}: get_params() does not survive a JSON round trip")
    _require(plugin.with_params() == plugin, f"{_label(plugin)}: with_params() without changes is not equal")
    _require(isinstance(repr(plugin), str), f"{_label(plugin)}: repr failed")


def check_unknown_setting(plugin) -> None:
    """An unknown setting is refused with a HybridfitError naming it."""
    try:
        type(plugin)(**plugin.get_params(), no_such_setting_xyz=1)
    except HybridfitError as err:
        _require("no_such_setting_xyz" in str(err), f"{_label(plugin)}: the error does not name the setting: {err}")
    else:
        raise AssertionError(f"{_label(plugin)}: an unknown setting was accepted")


def check_pickle(plugin) -> None:
    """Plugins travel to worker processes (``fit(jobs=...)``): pickling keeps them equal."""
    _require(pickle.loads(pickle.dumps(plugin)) == plugin, f"{_label(plugin)}: not equal after pickling")


# ------------------------------------------------------------------ models
def _random_params(model: HandModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, P) parameters within the model's bounds (infinite bounds: +-100 around the default)."""
    lower, upper = model.bounds()
    x0 = model.default_params()
    lower = np.where(np.isfinite(lower), lower, x0 - 100.0)
    upper = np.where(np.isfinite(upper), upper, x0 + 100.0)
    X = rng.uniform(lower, upper, size=(n, model.n_params))
    X[:, 3:7] = rng.normal(size=(n, 4))
    return X


def check_model_shapes(model: HandModel) -> None:
    """Names, parents, bounds and forward() have the documented shapes; bad shapes are refused."""
    P, J = model.n_params, model.n_joints
    _require(P >= 7, f"{_label(model)}: needs at least the 7 global pose parameters, has {P}")
    parents = np.asarray(model.parents)
    _require(parents.shape == (J,), f"{_label(model)}: parents has shape {parents.shape}, expected ({J},)")
    _require(int((parents < 0).sum()) == 1 and all(p < j for j, p in enumerate(parents)),
             f"{_label(model)}: parents must have one root (-1) and list parents before children")
    lower, upper = model.bounds()
    _require(lower.shape == (P,) and upper.shape == (P,), f"{_label(model)}: bounds must be two ({P},) arrays")
    _require(bool((lower <= upper).all()), f"{_label(model)}: some lower bounds exceed the upper bounds")
    X = _random_params(model, np.random.default_rng(0), 4)
    out = model.forward(X)
    _require(out.shape == (4, J, 3) and out.dtype == np.float64, f"{_label(model)}: forward((4, P)) gave {out.shape}")
    _require(model.forward(X[0]).shape == (J, 3), f"{_label(model)}: forward((P,)) must give (J, 3)")
    _require(model.forward(X[:0]).shape == (0, J, 3), f"{_label(model)}: forward((0, P)) must give (0, J, 3)")
    try:
        model.forward(np.zeros((2, P + 1)))
    except HybridfitError:
        pass
    else:
        raise AssertionError(f"{_label(model)}: forward accepted parameters of the wrong length")


def check_model_parameter_names(model: HandModel) -> None:
    """The P parameter names are unique strings that can name a column (no whitespace,
    commas or quotes), and the joint angles (every parameter after the global pose's 7) are
    in radians: their finite bounds lie within +-2 pi."""
    names = tuple(model.parameter_names)
    bad = [n for n in names if not (isinstance(n, str) and PARAMETER_NAME.fullmatch(n))]
    _require(not bad, f"{_label(model)}: parameter names must be strings without whitespace, commas or quotes: {bad}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    _require(not repeated, f"{_label(model)}: parameter names repeat: {repeated}")
    lower, upper = (np.asarray(b, dtype=float)[ANGLES] for b in model.bounds())
    limits = np.abs(np.concatenate([lower[np.isfinite(lower)], upper[np.isfinite(upper)]]))
    _require(bool((limits <= 2 * np.pi).all()), f"{_label(model)}: joint angle bounds beyond +-2 pi "
             f"(largest {limits.max() if len(limits) else 0:.4g}): angles must be radians")


def check_model_batching(model: HandModel) -> None:
    """A batch gives the same joints as its rows one at a time."""
    X = _random_params(model, np.random.default_rng(1), 8)
    batch = model.forward(X)
    rows = np.stack([model.forward(X[i : i + 1])[0] for i in range(len(X))])
    np.testing.assert_allclose(batch, rows, rtol=1e-12, atol=1e-9, err_msg=f"{_label(model)}: batch != rows")


def check_model_default_pose(model: HandModel) -> None:
    """The default pose lies within the bounds and its joints are finite."""
    x0 = model.default_params()
    lower, upper = model.bounds()
    _require(x0.shape == (model.n_params,), f"{_label(model)}: default_params has shape {x0.shape}")
    _require(bool(((x0 >= lower) & (x0 <= upper)).all()), f"{_label(model)}: the default pose violates the bounds")
    _require(bool(np.isfinite(model.forward(x0)).all()), f"{_label(model)}: the default pose has non-finite joints")


def check_model_bone_lengths(model: HandModel) -> None:
    """Every joint keeps its distance to its parent under any parameters (rigid bones)."""
    parents = np.asarray(model.parents)
    child = np.flatnonzero(parents >= 0)
    X = np.vstack([model.default_params()[None], _random_params(model, np.random.default_rng(2), 32)])
    joints = model.forward(X)
    lengths = np.linalg.norm(joints[:, child] - joints[:, parents[child]], axis=-1)
    worst = np.abs(lengths - lengths[0]).max(axis=0)
    bad = np.flatnonzero(worst > 1e-6 * max(1.0, float(lengths[0].max())))
    _require(len(bad) == 0, f"{_label(model)}: bones change length: "
             + ", ".join(f"{model.joint_names[child[b]]} (by {worst[b]:.3g} mm)" for b in bad[:5]))


def check_model_stages(model: HandModel) -> None:
    """Stages partition the parameters and the joints; the root stage holds the global pose;
    a stage's parameters never move the joints of earlier stages."""
    stages = model.stages()
    params = sorted(p for s in stages for p in s.parameters)
    joints = sorted(j for s in stages for j in s.joints)
    _require(params == list(range(model.n_params)), f"{_label(model)}: stage parameters do not partition 0..P-1")
    _require(joints == list(range(model.n_joints)), f"{_label(model)}: stage joints do not partition 0..J-1")
    _require(set(range(7)) <= set(stages[0].parameters), f"{_label(model)}: the first stage must hold parameters 0..6")
    rng = np.random.default_rng(3)
    x = _random_params(model, rng, 1)[0]
    lower, upper = model.bounds()
    base = model.forward(x)
    for s, stage in enumerate(stages):
        moved = x.copy()
        idx = list(stage.parameters)
        moved[idx] = np.clip(x[idx] + rng.normal(0, 0.1, len(idx)) * np.maximum(1.0, np.abs(x[idx])), lower[idx], upper[idx])
        delta = np.abs(model.forward(moved) - base).max(axis=-1)
        earlier = [j for t in stages[:s] for j in t.joints]
        _require(bool((delta[earlier] < 1e-9).all()) if earlier else True,
                 f"{_label(model)}: stage {stage.name!r} moves joints of an earlier stage")


def check_model_joint_subset(model: HandModel) -> None:
    """``forward(X, joints=subset)`` gives the full forward pass's joints for every joint
    asked for (single joints, each stage's joints, and a random subset)."""
    rng = np.random.default_rng(4)
    X = _random_params(model, rng, 6)
    full = model.forward(X)
    J = model.n_joints
    subsets = [np.array([j]) for j in range(J)] + [np.asarray(s.joints) for s in model.stages()]
    subsets.append(np.sort(rng.choice(J, size=max(1, J // 2), replace=False)))
    for subset in subsets:
        subset = subset.astype(np.int64)
        part = model.forward(X, subset)
        _require(part.shape == full.shape, f"{_label(model)}: forward(X, joints) gave {part.shape}, expected {full.shape}")
        close = np.isclose(part[:, subset], full[:, subset], rtol=1e-12, atol=1e-9).all(axis=(0, 2))
        _require(bool(close.all()), f"{_label(model)}: forward(X, joints={subset.tolist()}) differs from the full "
                 f"forward pass at " + ", ".join(model.joint_names[j] for j in subset[~close][:5]))


def _moved(x: float, lower: float, upper: float, share: float = 0.25) -> float:
    """x moved by ``share`` of its range (10 where unbounded), inwards at an upper bound."""
    step = share * (upper - lower) if np.isfinite(upper - lower) else 10.0
    return x + step if x + step <= upper else x - step


def check_model_stage_parameters(model: HandModel) -> None:
    """Every parameter of a stage moves at least one of that stage's own joints (else
    stepwise fitting cannot see it in its stage), at one of a few random poses."""
    lower, upper = model.bounds()
    X = _random_params(model, np.random.default_rng(5), 4)
    base = model.forward(X)
    for stage in model.stages():
        own = list(stage.joints)
        for p in stage.parameters:
            moved = X.copy()
            moved[:, p] = [_moved(x, lower[p], upper[p]) for x in X[:, p]]
            delta = np.abs(model.forward(moved)[:, own] - base[:, own]).max()
            _require(delta > 1e-6, f"{_label(model)}: parameter {model.parameter_names[p]!r} of stage "
                     f"{stage.name!r} moves none of the stage's joints")


# ------------------------------------------------------------------ objectives
def _objective_frame(seed: int = 0, Q: int = 6, K: int = 3):
    """Random proposals (Q, K, 3), weights (Q, K) with point 1 empty, points (5, Q, 3)."""
    rng = np.random.default_rng(seed)
    proposals = rng.normal(0.0, 30.0, size=(Q, K, 3))
    conf = rng.random((Q, K))
    conf[1] = 0.0
    points = proposals[None, :, 0] + rng.normal(0.0, 15.0, size=(5, Q, 3))
    return proposals, normalise_confidences(conf), points


def _observed_frame(seed: int = 0, K: int = 3):
    """For objectives that observe depth: ToyHand, the depth Observation of a pose 400 mm in
    front of the camera, proposals (J, K, 3) around its joints, weights (J, K), and the joints
    (5, J, 3) of that pose perturbed (row 0 unperturbed)."""
    from .datasets.camera import Intrinsics
    from .objective import Observation
    from .model.render import Renderer
    from .synthetic.proposals import PALM_TO_CAMERA
    from .model.rotations import matrix_to_quaternion

    rng = np.random.default_rng(seed)
    model = ToyHand()
    pose = model.default_params().astype(float)
    pose[:3] = (0.0, 0.0, 400.0)
    pose[3:7] = matrix_to_quaternion(PALM_TO_CAMERA)
    intrinsics = Intrinsics(width=160, height=120, cx=80.0, cy=60.0, fx=120.0, fy=120.0)
    depth = Renderer(model, intrinsics).render(pose)[0][0]
    params = np.repeat(pose[None], 5, axis=0)
    params[1:, :3] += rng.normal(0.0, 10.0, size=(4, 3))
    params[1:, 7:] += rng.normal(0.0, 0.2, size=(4, model.n_params - 7))
    joints = model.forward(model.clip(params))
    proposals = joints[0][:, None] + rng.normal(0.0, 8.0, size=(model.n_joints, K, 3))
    conf = rng.random((model.n_joints, K))
    conf[1] = 0.0
    return model, Observation.from_depth(depth, intrinsics), proposals, normalise_confidences(conf), joints


def _bound_frame(objective: Objective, seed: int = 0):
    """(loss(points, subset), proposals, weights, points) of a check frame: random points for
    proposal objectives, a rendered hand's joints for objectives that observe depth (which
    then score the points as the model's joints)."""
    if not getattr(objective, "observes_depth", False):
        proposals, weights, points = _objective_frame(seed)
        return objective.bind(proposals, weights), proposals, weights, points
    model, observation, proposals, weights, joints = _observed_frame(seed)
    bound = objective.bind_observed(proposals, weights, observation, model)
    return (lambda points, subset: bound(points, subset, points)), proposals, weights, joints


def check_objective_shapes(objective: Objective) -> None:
    """loss(points (N, Q, 3), subset) is (N,) finite float64, N = 0 included."""
    loss, proposals, weights, points = _bound_frame(objective)
    every = np.arange(len(proposals), dtype=np.int64)
    out = loss(points, every)
    _require(isinstance(out, np.ndarray) and out.shape == (5,) and out.dtype == np.float64,
             f"{_label(objective)}: loss must be a (N,) float64 array, got {getattr(out, 'shape', type(out))}")
    _require(bool(np.isfinite(out).all()), f"{_label(objective)}: non-finite losses {out}")
    _require(loss(points[:0], every).shape == (0,), f"{_label(objective)}: N = 0 must give an empty array")


def check_objective_batching(objective: Objective) -> None:
    """Scoring a batch gives the same losses as scoring each hypothesis alone."""
    loss, proposals, weights, points = _bound_frame(objective, 1)
    every = np.arange(len(proposals), dtype=np.int64)
    rows = np.array([loss(points[i : i + 1], every)[0] for i in range(len(points))])
    np.testing.assert_allclose(loss(points, every), rows, rtol=1e-12, atol=1e-12,
                               err_msg=f"{_label(objective)}: batch != rows")


def check_objective_sum_over_points(objective: Objective) -> None:
    """The loss is a sum over points: disjoint subsets add up, the empty subset scores 0,
    and a point without proposals contributes nothing wherever it is. (Only for objectives
    declared ``additive``; an image term scores the whole hand on any subset.)"""
    if not getattr(objective, "additive", True):
        not_applicable(objective, "its loss is not a sum over points (additive = False)")
    proposals, weights, points = _objective_frame(2)
    loss = objective.bind(proposals, weights)
    Q = len(proposals)
    a, b = np.arange(0, Q, 2, dtype=np.int64), np.arange(1, Q, 2, dtype=np.int64)
    whole = loss(points, np.arange(Q, dtype=np.int64))
    np.testing.assert_allclose(loss(points, a) + loss(points, b), whole, rtol=1e-9, atol=1e-9,
                               err_msg=f"{_label(objective)}: subset losses do not add up")
    _require(bool((loss(points, np.zeros(0, dtype=np.int64)) == 0).all()), f"{_label(objective)}: empty subset != 0")
    empty = np.array([1], dtype=np.int64)  # point 1 has all-zero weights
    _require(bool((loss(points, empty) == 0).all()), f"{_label(objective)}: a point without proposals contributes")
    moved = points.copy()
    moved[:, 1] += 500.0
    np.testing.assert_array_equal(loss(moved, np.arange(Q, dtype=np.int64)), whole,
                                  err_msg=f"{_label(objective)}: moving a point without proposals changes the loss")


def check_objective_lower_bound(objective: Objective) -> None:
    """No loss is below ``lower_bound(weights)``, at the proposals themselves included."""
    loss, proposals, weights, points = _bound_frame(objective, 3)
    every = np.arange(len(proposals), dtype=np.int64)
    at_top = proposals[np.arange(len(proposals)), weights.argmax(axis=-1)][None]
    low = objective.lower_bound(weights)
    values = np.concatenate([loss(points, every), loss(at_top, every)])
    _require(bool((values >= low - 1e-9 * max(1.0, abs(low))).all()),
             f"{_label(objective)}: losses {values.min()} below lower_bound {low}")


def check_objective_deterministic(objective: Objective) -> None:
    """Binding twice and scoring twice gives bit-identical losses."""
    loss, proposals, weights, points = _bound_frame(objective, 4)
    every = np.arange(len(proposals), dtype=np.int64)
    first = loss(points, every)
    second = _bound_frame(objective, 4)[0](points.copy(), every)
    np.testing.assert_array_equal(first, second, err_msg=f"{_label(objective)}: not deterministic")


def check_objective_capabilities(objective: Objective) -> None:
    """A compiled kernel, a compiled frames kernel, a frame-batched scorer (``score_frames``)
    and CasADi symbols (``casadi_loss``, where casadi is installed) that the core would use
    (:func:`hybridfit.objective.capability`) give ``bind``'s losses on random points, on the
    whole frame and on a subset of points, for several frames at once."""
    kernel = compiled_kernel_of(objective)
    frames_kernel = compiled_kernel_of(objective, "compiled_frames_kernel")
    score_frames = capability(objective, "score_frames")
    symbols = _casadi_scorer(objective)
    if objective.observes_depth or all(c is None for c in (kernel, frames_kernel, score_frames, symbols)):
        not_applicable(objective, "it offers no capability beside bind (compiled kernels, score_frames, CasADi "
                       "symbols)" if not objective.observes_depth else "it observes depth (bind_observed only)")
    frames = [_objective_frame(seed) for seed in (11, 12, 13)]
    proposals = np.stack([f[0] for f in frames])
    weights = np.stack([f[1] for f in frames])
    points = np.stack([f[2] for f in frames])  # (F, N, Q, 3)
    Q = proposals.shape[1]
    for subset in (np.arange(Q, dtype=np.int64), np.array([0, 2, 3], dtype=np.int64)):
        want = np.stack([objective.bind(proposals[f], weights[f])(points[f], subset) for f in range(len(frames))])
        if kernel is not None:
            function, consts = kernel
            got = np.empty_like(want)
            for f in range(len(frames)):
                function(np.ascontiguousarray(points[f].transpose(1, 2, 0)), subset, np.ascontiguousarray(proposals[f]),
                         np.ascontiguousarray(weights[f]), consts, got[f])
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9,
                                       err_msg=f"{_label(objective)}: compiled_kernel disagrees with bind")
        if frames_kernel is not None:  # frames 1.. side by side, then frame 0 alone, into a wider output
            function, consts = frames_kernel
            F, N = want.shape
            got = np.full((F, N + 3), np.nan)
            for f0, f1 in ((1, F), (0, 1)):
                columns = np.ascontiguousarray(np.concatenate([points[f].transpose(1, 2, 0) for f in range(f0, f1)],
                                                              axis=-1))
                function(columns, subset, np.ascontiguousarray(proposals), np.ascontiguousarray(weights), consts, f0,
                         f1, N, got)
            np.testing.assert_allclose(got[:, :N], want, rtol=1e-9, atol=1e-9,
                                       err_msg=f"{_label(objective)}: compiled_frames_kernel disagrees with bind")
        if score_frames is not None:
            got = _scored_frames(objective, score_frames, *frames_arguments(points, subset, proposals, weights))
            _require(got.shape == want.shape, f"{_label(objective)}: score_frames returned shape {got.shape}, "
                     f"expected {want.shape}")
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9,
                                       err_msg=f"{_label(objective)}: score_frames disagrees with bind")
        if symbols is not None:
            got = np.stack([symbols(points[f], subset, proposals[f], weights[f]) for f in range(len(frames))])
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9,
                                       err_msg=f"{_label(objective)}: casadi_loss disagrees with bind")


def _casadi_scorer(objective: Objective):
    """None, or score(points (N, Q, 3), subset, proposals, weights) -> (N,): the objective's
    ``casadi_loss`` on symbolic points (Q, 3), evaluated at each hypothesis (None too where
    casadi is not installed: then no solver can use the symbols either)."""
    casadi_loss = capability(objective, "casadi_loss")
    if casadi_loss is None:
        return None
    try:
        import casadi as ca
    except ImportError:
        return None

    def score(points, subset, proposals, weights):
        symbols = ca.SX.sym("points", points.shape[1], 3)
        function = ca.Function("loss", [symbols], [casadi_loss(symbols, proposals, weights, subset)])
        return np.array([float(function(ca.DM(hypothesis))) for hypothesis in points])

    return score


def check_objective_frames_independent(objective: Objective) -> None:
    """``score_frames`` (when the core would use it) gives each frame's losses bit for bit the
    same beside any other frames (groups of two or more, as the driver hands them), so a
    frame's fit does not depend on the frames fitted beside it, the chunking or ``--jobs``."""
    score_frames = capability(objective, "score_frames")
    if objective.observes_depth or score_frames is None:
        not_applicable(objective, "the core never calls its score_frames (it offers none, or observes depth)")
    frames = [_objective_frame(seed, Q=10) for seed in (21, 22, 23)]  # 10 points: numpy sums them pairwise
    proposals, weights, points = (np.stack([f[i] for f in frames]) for i in range(3))
    every = np.arange(proposals.shape[1], dtype=np.int64)
    together = _scored_frames(objective, score_frames, *frames_arguments(points, every, proposals, weights))
    for group in ([0, 1], [1, 2], [2, 0]):
        got = _scored_frames(objective, score_frames,
                             *frames_arguments(points[group], every, proposals[group], weights[group]))
        for row, f in enumerate(group):
            _require(np.array_equal(got[row], together[f]), f"{_label(objective)}: score_frames gives frame {f} "
                     f"other losses beside frames {group} than beside [0, 1, 2]: a frame's fit would depend on "
                     f"the frames fitted beside it")


def frames_arguments(points: np.ndarray, subset: np.ndarray, proposals: np.ndarray, weights: np.ndarray):
    """What the driver hands ``score_frames`` for frames' points (F, N, Q, 3), proposals
    (F, Q, K, 3) and weights (F, Q, K) scored over ``subset`` (m,): (points (F, N, m, 3),
    subset, proposals (F, m, K, 3), weights (F, m, K)), the points' rows and the proposals cut
    to ``subset``, each laid out with the frame innermost in memory as the driver lays them
    out (views, not C-contiguous; :func:`hybridfit.fitting.evaluator.frames_innermost_points`
    and :func:`~hybridfit.fitting.evaluator.frames_innermost`)."""
    return (frames_innermost_points(np.asarray(points)[:, :, subset]), subset,
            frames_innermost(np.asarray(proposals)[:, subset], 1), frames_innermost(np.asarray(weights)[:, subset], 1))


def _scored_frames(objective: Objective, score_frames, points, subset, proposals, weights) -> np.ndarray:
    """score_frames' result; its failure on the driver's arguments is the check's failure."""
    try:
        return np.asarray(score_frames(points, subset, proposals, weights))
    except Exception as err:
        raise AssertionError(f"{_label(objective)}: score_frames fails on the driver's arguments (the points in "
                             f"subset only, proposals and weights cut to them, the frame innermost in memory): "
                             f"{type(err).__name__}: {err}") from err


def hypotheses_innermost(points: np.ndarray) -> np.ndarray:
    """The same points (..., N, Q, 3), laid out as the driver hands them to ``bind``'s loss: a
    view of a (..., Q, 3, N) array, the hypothesis innermost in memory."""
    points = np.asarray(points, dtype=np.float64)
    axes = tuple(range(points.ndim - 3))
    n = points.ndim
    inner = np.ascontiguousarray(points.transpose(*axes, n - 2, n - 1, n - 3))
    return inner.transpose(*axes, n - 1, n - 3, n - 2)


def check_objective_strided_points(objective: Objective) -> None:
    """``bind``'s loss scores points laid out as the driver hands them (:func:`hypotheses_innermost`,
    not C-contiguous) as it scores a C-contiguous copy, and ``score_frames`` (when the core
    would use it) scores the driver's arguments (:func:`frames_arguments`, the frame innermost)
    as it scores C-contiguous copies: numpy code is layout-agnostic, code that assumes C order
    is not."""
    if objective.observes_depth:
        not_applicable(objective, "it observes depth: its losses take the model's joints, not strided points")
    proposals, weights, points = _objective_frame(5)
    loss = objective.bind(proposals, weights)
    score_frames = capability(objective, "score_frames")
    for subset in (np.arange(len(proposals), dtype=np.int64), np.array([0, 2, 3], dtype=np.int64)):
        want = loss(points.copy(), subset)
        try:
            got = loss(hypotheses_innermost(points), subset)
        except Exception as err:
            raise AssertionError(f"{_label(objective)}: its loss fails on points that are not C-contiguous (the "
                                 f"driver's layout): {type(err).__name__}: {err}") from err
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12, err_msg=f"{_label(objective)}: its loss "
                                   f"differs on points that are not C-contiguous (the driver's layout)")
        if score_frames is not None:
            frames = (np.stack([points, points[::-1]]), subset, np.stack([proposals] * 2), np.stack([weights] * 2))
            driver_args = frames_arguments(*frames)
            c_ordered = [np.ascontiguousarray(a) for a in driver_args]
            want_frames = np.asarray(score_frames(*c_ordered))
            got = _scored_frames(objective, score_frames, *driver_args)
            np.testing.assert_allclose(got, want_frames, rtol=1e-12, atol=1e-12,
                                       err_msg=f"{_label(objective)}: score_frames differs on the driver's layout "
                                       f"(the frame innermost) from C-contiguous arrays")


def check_objective_observed(objective: Objective) -> None:
    """An objective that observes depth scores the rendered pose itself at least as well as
    perturbed poses, and a Problem without the frame's depth is refused with a clear error.
    (Nothing to check for proposal-only objectives.)"""
    if not getattr(objective, "observes_depth", False):
        not_applicable(objective, "it scores proposals only (observes_depth = False)")
    loss, proposals, weights, joints = _bound_frame(objective, 5)
    values = loss(joints, np.arange(len(proposals), dtype=np.int64))
    _require(bool(values[0] <= values[1:].min()), f"{_label(objective)}: the observed pose scores {values[0]}, "
             f"worse than a perturbed pose ({values[1:].min()})")
    try:
        Problem(ToyHand(), objective, proposals, weights)
    except HybridfitError as err:
        _require("depth" in str(err), f"{_label(objective)}: the error does not say the depth is missing: {err}")
    else:
        raise AssertionError(f"{_label(objective)}: a Problem without the depth image was accepted")


# ------------------------------------------------------------------ optimizers
class RecordingTask(Task):
    """A Task that records every evaluated batch (its stages share the record)."""

    def __init__(self, *args, record: list | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.record: list[tuple[Task, np.ndarray]] = [] if record is None else record

    def evaluate(self, X):
        X = np.array(X, dtype=np.float64)
        losses = super().evaluate(X)
        self.record.append((self, X))
        return losses

    def stage(self, name, parameters, points, budget, owned=None, index=0):
        return RecordingTask(self.problem, budget, parameters, points, base=self.base, name=name, parent=self,
                             owned=owned, index=index, record=self.record)


def check_problem(seed: int = 0) -> Problem:
    """A small synthetic frame (ToyHand, ToyClamped, k = 3) for the optimiser checks."""
    model = ToyHand()
    data = synthetic_proposals(1, k=3, seed=seed, model=model)
    return Problem(model, ToyClamped(), data["proposals"][0], data["confidences"][0])


def known_optimum_problem(seed: int = 0) -> tuple[Problem, np.ndarray]:
    """(problem, truth (P,)): ToyHand with one exact proposal per joint at a random pose and
    ToyLeastSquares, so the optimum is the pose itself, loss 0. The initial guess (given, not
    estimated) has the true global pose and the default finger angles."""
    model = ToyHand()
    truth = synthetic_proposals(1, k=1, seed=seed, model=model, p_missing=0.0)["params"][0]
    start = truth.copy()
    start[7:] = model.default_params()[7:]
    proposals = model.forward(truth)[:, None]
    return Problem(model, ToyLeastSquares(), proposals,
                   np.ones((model.n_joints, 1)), x0=start), truth


def _budget(optimizer: Optimizer, task: Task) -> int:
    return max(CHECK_BUDGET, int(optimizer.min_budget(task)))


def _counting(problem: Problem) -> list[int]:
    """Count the rows that reach the problem's loss (the evaluations really made). A single
    row that the previous call scored on other points is not counted: that is the Task
    re-scoring the best hypothesis of a guided stage on the points the stage owns."""
    rows = [0]
    evaluate = problem.evaluate
    last = [np.zeros((0, problem.model.n_params)), None]

    def counted(params, subset=None):
        params = np.asarray(params)
        rescore = (len(params) == 1 and (last[0] == params[0]).all(axis=1).any() and subset is not None
                   and last[1] is not None and not np.array_equal(subset, last[1]))
        rows[0] += 0 if rescore else len(params)
        last[:] = [params.copy(), None if subset is None else np.asarray(subset).copy()]
        return evaluate(params, subset)

    problem.evaluate = counted
    return rows


def check_optimizer_budget(optimizer: Optimizer) -> None:
    """Never more evaluations than the budget, and the reported number is the real one."""
    problem = check_problem(1)
    base = _budget(optimizer, Task(problem, 1))
    for budget in (base, base + 37):
        rows = _counting(problem)
        result = optimizer.run(problem, budget, seed=0)
        _require(rows[0] <= budget, f"{_label(optimizer)}: {rows[0]} evaluations for a budget of {budget}")
        _require(result.evaluations == rows[0],
                 f"{_label(optimizer)}: reports {result.evaluations} evaluations but made {rows[0]}")
        del problem.evaluate
        task = RecordingTask(problem, budget)
        optimizer.minimize(task, np.random.default_rng(0))
        _require(task.used == sum(len(X) for _, X in task.record) and task.used <= budget,
                 f"{_label(optimizer)}: task.used {task.used} for budget {budget}")


def check_optimizer_deterministic(optimizer: Optimizer) -> None:
    """One seed gives a bit-identical result, whatever ran in between and whatever the
    global numpy random state is (all randomness must come from the rng passed in)."""
    problem = check_problem(2)
    budget = _budget(optimizer, Task(problem, 1))
    state = np.random.get_state()
    try:
        np.random.seed(1)
        first = optimizer.run(problem, budget, seed=5)
        optimizer.run(problem, budget, seed=6)
        np.random.seed(2)
        again = optimizer.run(problem, budget, seed=5)
    finally:
        np.random.set_state(state)
    for field in ("params", "loss", "evaluations", "history_loss", "history_evaluations"):
        np.testing.assert_array_equal(getattr(first, field), getattr(again, field),
                                      err_msg=f"{_label(optimizer)}: {field} differs between runs with one seed")


def check_optimizer_bounds(optimizer: Optimizer) -> None:
    """Every evaluated hypothesis is finite and within its task's bounds."""
    problem = check_problem(3)
    task = RecordingTask(problem, _budget(optimizer, Task(problem, 1)))
    optimizer.minimize(task, np.random.default_rng(0))
    _require(bool(task.record), f"{_label(optimizer)}: evaluated nothing")
    for t, X in task.record:
        _require(bool(np.isfinite(X).all()), f"{_label(optimizer)}: non-finite hypotheses in task {t.name}")
        outside = (X < t.lower) | (X > t.upper)
        _require(not outside.any(), f"{_label(optimizer)}: {int(outside.any(axis=1).sum())} hypotheses outside "
                 f"the bounds of task {t.name}")


def check_optimizer_subset(optimizer: Optimizer) -> None:
    """It works on a stage: a subset of the parameters (the others frozen) and points."""
    problem = check_problem(4)
    root = Task(problem, 10**6)
    name, params, points = problem.stage_points()[2]
    budget = _budget(optimizer, root.stage(name, params, points, 1))
    stage = RecordingTask(problem, budget, params, points, base=root.base, name=name)
    optimizer.minimize(stage, np.random.default_rng(0))
    _require(0 < stage.used <= budget, f"{_label(optimizer)}: used {stage.used} of a stage budget of {budget}")
    _require(all(X.shape[1] == len(params) for _, X in stage.record), f"{_label(optimizer)}: wrong dimension")
    _require(np.isfinite(stage.best_loss), f"{_label(optimizer)}: no finite loss on the stage")


def check_optimizer_min_budget(optimizer: Optimizer) -> None:
    """min_budget is a positive int; a smaller budget is refused with a HybridfitError."""
    problem = check_problem(5)
    need = optimizer.min_budget(Task(problem, 1))
    _require(isinstance(need, (int, np.integer)) and need >= 1, f"{_label(optimizer)}: min_budget {need!r}")
    if need > 1:
        try:
            optimizer.run(problem, need - 1)
        except HybridfitError as err:
            _require(str(need) in str(err), f"{_label(optimizer)}: the error does not say the minimum: {err}")
        else:
            raise AssertionError(f"{_label(optimizer)}: a budget below min_budget ({need}) was accepted")


#: share of the gap between the start's loss and the known optimum an optimiser must close
IMPROVE_SHARE = 0.2


def check_optimizer_improves(optimizer: Optimizer) -> None:
    """On a toy problem with a known optimum (loss 0) it closes at least ``IMPROVE_SHARE``
    of the gap between its start and the optimum, on the whole problem and on one finger's
    stage alone (as stepwise fitting runs it)."""
    problem, truth = known_optimum_problem(6)
    root = Task(problem, 10**6)
    name, params, points = problem.stage_points()[1]
    tasks = [lambda b: Task(problem, b), lambda b: Task(problem, b, params, points, base=root.base, name=name)]
    for make in tasks:
        probe = make(1)
        start = float(probe.evaluate(probe.x0[None])[0])
        task = make(_budget(optimizer, make(1)))
        optimizer.minimize(task, np.random.default_rng(0))
        _require(start > 0, "the toy problem's start is already optimal")
        _require(task.best_loss <= (1.0 - IMPROVE_SHARE) * start,
                 f"{_label(optimizer)}: reached loss {task.best_loss:.4g} from a start of {start:.4g} on task "
                 f"{task.name!r} (optimum 0) within {task.budget} evaluations: less than "
                 f"{IMPROVE_SHARE:.0%} of the gap closed")


def check_optimizer_batch_steps(optimizer: Optimizer) -> None:
    """An optimiser the driver runs (its plan's stages share batch steps,
    ``hybridfit.fitting.driver``), fitting several frames in lockstep, spends each frame's
    budget exactly, and fits each frame as it fits it alone (its random numbers come from its
    own key). Skipped for optimisers the driver does not run (callback-style solvers)."""
    from .fitting.driver import Driver, _batched_layout

    model = ToyHand()
    data = synthetic_proposals(3, k=3, seed=7, model=model)
    objective = ToyClamped()
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0])
    budget = _budget(optimizer, Task(problem, 1))
    if _batched_layout(optimizer, Task(problem, budget)) is None:
        not_applicable(optimizer, "the driver does not run it: its plan's stages share no batch steps (a "
                       "callback-style solver runs frame by frame on a Task)")
    driver = Driver(model, objective, optimizer, model.joint_names, budget, seed=3)
    together = driver.fit_chunk([0, 1, 2], data["proposals"], data["confidences"])
    for f in range(3):
        alone = driver.fit_chunk([f], data["proposals"][f:f + 1], data["confidences"][f:f + 1])[0]
        _require(together[f][2] is None and alone[2] is None, f"{_label(optimizer)}: frame {f} failed")
        _require(together[f][1][4] == budget, f"{_label(optimizer)}: {together[f][1][4]} evaluations for a budget "
                 f"of {budget}")
        _require(np.array_equal(together[f][1][0], alone[1][0]),
                 f"{_label(optimizer)}: frame {f} fitted beside other frames differs from frame {f} fitted alone")


# ------------------------------------------------------------------ registry of checks
_COMMON = (check_config_round_trip, check_unknown_setting, check_pickle)
_CHECKS: dict[str, tuple[Callable, ...]] = {
    "model": _COMMON + (check_model_shapes, check_model_parameter_names, check_model_batching,
                        check_model_default_pose, check_model_bone_lengths, check_model_stages,
                        check_model_joint_subset, check_model_stage_parameters),
    "objective": _COMMON + (check_objective_shapes, check_objective_batching, check_objective_sum_over_points,
                            check_objective_lower_bound, check_objective_deterministic, check_objective_capabilities,
                            check_objective_frames_independent, check_objective_strided_points,
                            check_objective_observed),
    "optimizer": _COMMON + (check_optimizer_budget, check_optimizer_deterministic, check_optimizer_bounds,
                            check_optimizer_subset, check_optimizer_min_budget, check_optimizer_improves,
                            check_optimizer_batch_steps),
}


def checks(kind: str) -> tuple[Callable, ...]:
    """The checks for a plugin kind ('model', 'objective' or 'optimizer'), in order."""
    try:
        return _CHECKS[kind]
    except KeyError:
        raise HybridfitError(f"unknown plugin kind {kind!r}; choose from {sorted(_CHECKS)}") from None


def check_plugin(kind: str, plugin) -> list[str]:
    """Run every check of the kind on a configured plugin (raises on the first failure);
    returns the reasons of the checks that did not apply (skipped)."""
    skipped = []
    for check in checks(kind):
        try:
            check(plugin)
        except unittest.SkipTest as skip:
            skipped.append(f"{check.__name__}: {skip}")
    return skipped


def check_model(model: HandModel) -> list[str]:
    """Run every model check on a configured model (raises on the first failure; ``checks("model")`` lists them)."""
    return check_plugin("model", model)


def check_objective(objective: Objective) -> list[str]:
    """Run every objective check on a configured objective (raises on the first failure; ``checks("objective")`` lists them)."""
    return check_plugin("objective", objective)


def check_optimizer(optimizer: Optimizer) -> list[str]:
    """Run every optimizer check on a configured optimizer (raises on the first failure; ``checks("optimizer")`` lists them)."""
    return check_plugin("optimizer", optimizer)
