"""Conformance checks that every hybridfit plugin, built-in or third-party, must pass.

As with scikit-learn's ``check_estimator``, each check is a public function taking a configured
plugin and raising ``AssertionError`` naming the plugin and the fault, one test id each::

    from hybridfit import registry, testing

    @pytest.mark.parametrize("check", testing.checks("optimizer"), ids=lambda c: c.__name__)
    def test_my_optimizer(check):
        check(registry.create("optimizer", "my-optimizer"))

``check_model``, ``check_objective`` and ``check_optimizer`` run all checks of a kind. A check
that does not apply (a capability the plugin does not declare) is skipped with its reason
(``unittest.SkipTest``, reported by pytest as skipped), never passed. The optimiser checks fit
the suite's own :class:`ToyHand` (13 parameters, 7 joints) with its own objectives,
:class:`ToyClamped` (a ``point_loss``) and :class:`ToyLeastSquares` (a numpy ``bind``), so they
take seconds and depend on no plugin; the checks of depth objectives render ToyHand too.
"""

from __future__ import annotations

import json
import pickle
import unittest
from collections.abc import Callable

import numba as nb
import numpy as np
from pydantic import Field

from .errors import HybridfitError, PluginError
from .fitting.angles import PARAMETER_NAME
from .fitting.driver import run_problem
from .model.base import ANGLES, HandModel, Stage
from .model.kinematics import NO_AXIS, X_AXIS, Z_AXIS, KinematicTree, TreeHandModel
from .objective import (
    POINT_LOSS_SIGNATURE,
    Objective,
    capability,
    normalise_confidences,
    point_loss_of,
)
from .optimizer import Optimizer
from .plugin import Settings
from .point_loss import bound_point_loss
from .problem import Problem
from .synthetic.proposals import synthetic_proposals
from .task import StagePlan, Task

__all__ = [
    "DERIVATIVE_RTOL",
    "DERIVATIVE_STEP_MM",
    "RecordingTask",
    "ToyClamped",
    "ToyHand",
    "ToyLeastSquares",
    "ToySquared",
    "check_config_round_trip",
    "check_model",
    "check_model_bone_lengths",
    "check_model_deterministic",
    "check_model_joint_names",
    "check_model_keeps_input",
    "check_model_parameter_names",
    "check_model_shapes",
    "check_model_stages",
    "check_objective",
    "check_objective_casadi_agrees",
    "check_objective_deterministic",
    "check_objective_forms",
    "check_objective_keeps_input",
    "check_objective_lower_bound",
    "check_objective_observed",
    "check_objective_observed_derivatives",
    "check_objective_point_loss",
    "check_objective_point_loss_agrees",
    "check_objective_shapes",
    "check_objective_sum_over_points",
    "check_optimizer",
    "check_optimizer_batch_steps",
    "check_optimizer_bounds",
    "check_optimizer_budget",
    "check_optimizer_deterministic",
    "check_optimizer_forms",
    "check_optimizer_improves",
    "check_optimizer_subset",
    "check_pickle",
    "check_plugin",
    "check_problem",
    "check_unknown_setting",
    "checks",
    "not_applicable",
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


@nb.njit(cache=True)
def toy_clamped_point(x, y, z, proposals, weights, constants, out):
    """ToyClamped's per-point loss: out[i] = -max_r w_r max(0, 1 - d_r^2 / d_max^2) for the
    point at (x[i], y[i], z[i]); constants: (1 / d_max^2,)."""
    out[:] = 0.0
    for r in range(proposals.shape[0]):
        for i in range(x.shape[0]):
            d2 = ((proposals[r, 0] - x[i]) ** 2 + (proposals[r, 1] - y[i]) ** 2 + (proposals[r, 2] - z[i]) ** 2)
            out[i] = min(out[i], weights[r] * (d2 * constants[0] - 1.0))


class ToyClamped(Objective):
    """The paper's clamped, confidence-weighted objective as a ``point_loss`` (its ``bind``
    is built from it), for the optimiser checks: loss = -sum_j max_r w_jr (1 - min(1,
    ||p_jr - h_j|| / d_max)^2), in [-Q, 0] for weights that sum to 1 per point."""

    Settings = ToyClampedSettings

    def point_loss(self):
        return toy_clamped_point, np.array([1.0 / self.settings.d_max_mm**2])

    def lower_bound(self, weights):
        return -float(np.max(weights, axis=-1).sum())


class ToyLeastSquares(Objective):
    """Squared distance (mm^2) from each point to its most confident proposal, summed, as a
    numpy ``bind`` (no point_loss), for the optimiser checks with a known optimum (0 where
    every point is on its proposal); a point without proposals (all weights 0) contributes 0."""

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


@nb.njit(cache=True)
def toy_squared_point(x, y, z, proposals, weights, constants, out):
    """ToySquared's per-point loss: out[i] = the squared distance (mm^2) of (x[i], y[i], z[i])
    to the point's most confident proposal."""
    top = np.argmax(weights)
    for i in range(x.shape[0]):
        out[i] = (proposals[top, 0] - x[i]) ** 2 + (proposals[top, 1] - y[i]) ** 2 + (proposals[top, 2] - z[i]) ** 2


class ToySquared(Objective):
    """ToyLeastSquares's loss as a ``point_loss``: the objective of :func:`check_optimizer_improves`,
    which every kind of optimiser can minimise (derivative steps need a per-point loss)."""

    def point_loss(self):
        return toy_squared_point, np.zeros(0)

    def lower_bound(self, weights):
        return 0.0


# ------------------------------------------------------------------ every plugin
def _refuses(plugin, call: Callable[[], object], accepted: str, naming: str) -> None:
    """``call()`` must raise a HybridfitError whose message names ``naming``; ``accepted``: what it took."""
    try:
        call()
    except HybridfitError as err:
        _require(naming in str(err), f"{_label(plugin)}: the error does not name {naming!r}: {err}")
    else:
        raise AssertionError(f"{_label(plugin)}: {accepted} was accepted")


def check_config_round_trip(plugin) -> None:
    """``type(p)(**p.get_params()) == p``, through JSON too, and ``with_params()`` equals p."""
    params = plugin.get_params()
    _require(type(plugin)(**params) == plugin, f"{_label(plugin)}: get_params() rebuilds a different plugin")
    again = json.loads(json.dumps(params))
    _require(type(plugin)(**again) == plugin, f"{_label(plugin)}: get_params() does not survive a JSON round trip")
    _require(plugin.with_params() == plugin, f"{_label(plugin)}: with_params() without changes is not equal")
    _require(isinstance(repr(plugin), str), f"{_label(plugin)}: repr failed")


def check_unknown_setting(plugin) -> None:
    """An unknown setting is refused with a HybridfitError naming it."""
    _refuses(plugin, lambda: type(plugin)(**plugin.get_params(), no_such_setting_xyz=1), "an unknown setting",
             "no_such_setting_xyz")


def check_pickle(plugin) -> None:
    """Plugins travel to worker processes (``fit(jobs=...)``): pickling keeps them equal."""
    _require(pickle.loads(pickle.dumps(plugin)) == plugin, f"{_label(plugin)}: not equal after pickling")


# ------------------------------------------------------------------ models
def _bounds(model: HandModel) -> tuple[np.ndarray, np.ndarray]:
    """The model's bounds, failing the check (not with numpy's error) unless they are two (P,)
    arrays with lower <= upper."""
    P = model.n_params
    lower, upper = (np.asarray(b, dtype=float) for b in model.bounds())
    _require(lower.shape == (P,) and upper.shape == (P,),
             f"{_label(model)}: bounds must be two ({P},) arrays, got {lower.shape} and {upper.shape}")
    crossed = [model.parameter_names[i] for i in np.flatnonzero(~(lower <= upper))]
    _require(not crossed, f"{_label(model)}: bounds have lower > upper for {crossed[:5]} (or NaN)")
    return lower, upper


def _forward(model: HandModel, X: np.ndarray) -> np.ndarray:
    """``model.forward`` of a copy of X, failing the check with its own message: a PluginError (the
    core's shape and dtype check), X changed, another result for the same X, or not float64
    (N, J, 3) (a model overriding ``forward`` itself)."""
    given = np.array(X, dtype=np.float64)
    try:
        out = model.forward(given)
        again = model.forward(np.array(X, dtype=np.float64))
    except PluginError as err:
        raise AssertionError(f"{_label(model)}: {err}") from err
    _require(np.array_equal(given, X, equal_nan=True), f"{_label(model)}: forward changed the parameters it was given "
             "(it must not write to its input)")
    shape = (*np.shape(X)[:-1], model.n_joints, 3)
    _require(isinstance(out, np.ndarray) and out.dtype == np.float64, f"{_label(model)}: forward returned "
             f"{getattr(out, 'dtype', type(out).__name__)} joints, expected float64")
    _require(out.shape == shape, f"{_label(model)}: forward of {np.shape(X)} returned shape {out.shape}, "
             f"expected {shape}")
    _require(np.array_equal(out, again, equal_nan=True), f"{_label(model)}: forward is not deterministic: the same "
             "parameters gave other joints on a second call")
    return out


def _random_params(model: HandModel, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, P) parameters within the model's bounds (infinite bounds: +-100 around the default)."""
    lower, upper = _bounds(model)
    x0 = model.default_params()
    lower = np.where(np.isfinite(lower), lower, x0 - 100.0)
    upper = np.where(np.isfinite(upper), upper, x0 + 100.0)
    X = rng.uniform(lower, upper, size=(n, model.n_params))
    X[:, 3:7] = rng.normal(size=(n, 4))
    return X


def check_model_shapes(model: HandModel) -> None:
    """parents (J,), bounds two (P,) arrays, default_params (P,) within them with finite joints;
    forward (N, P) -> (N, J, 3) float64 ((P,) -> (J, 3), N = 0 included), a batch giving the
    joints of its rows one at a time; parameters of the wrong length are refused."""
    P, J = model.n_params, model.n_joints
    _require(P >= 7, f"{_label(model)}: needs at least the 7 global pose parameters, has {P}")
    parents = np.asarray(model.parents)
    _require(parents.shape == (J,), f"{_label(model)}: parents has shape {parents.shape}, expected ({J},)")
    _require(int((parents < 0).sum()) == 1 and all(p < j for j, p in enumerate(parents)),
             f"{_label(model)}: parents must have one root (-1) and list parents before children")
    lower, upper = _bounds(model)
    x0 = model.default_params()
    _require(x0.shape == (P,), f"{_label(model)}: default_params has shape {x0.shape}")
    _require(bool(((x0 >= lower) & (x0 <= upper)).all()), f"{_label(model)}: the default pose violates the bounds")
    _require(bool(np.isfinite(_forward(model, x0)).all()), f"{_label(model)}: the default pose has non-finite joints")
    X = _random_params(model, np.random.default_rng(1), 8)
    out = _forward(model, X)
    _forward(model, X[0])
    _forward(model, X[:0])
    rows = np.stack([_forward(model, X[i : i + 1])[0] for i in range(len(X))])
    np.testing.assert_allclose(out, rows, rtol=1e-12, atol=1e-9, err_msg=f"{_label(model)}: batch != rows")
    _refuses(model, lambda: model.forward(np.zeros((2, P + 1))), "forward of parameters of the wrong length", "")


def check_model_deterministic(model: HandModel) -> None:
    """forward gives bit-identical joints for the same parameters, whatever ran in between and
    whatever the global numpy random state is."""
    X = _random_params(model, np.random.default_rng(7), 8)
    state = np.random.get_state()
    try:
        np.random.seed(1)
        first = model.forward(X.copy())
        model.forward(_random_params(model, np.random.default_rng(8), 5))
        np.random.seed(2)
        again = model.forward(X.copy())
    except PluginError as err:
        raise AssertionError(f"{_label(model)}: {err}") from err
    finally:
        np.random.set_state(state)
    _require(np.array_equal(first, again, equal_nan=True), f"{_label(model)}: forward is not deterministic: the same "
             "parameters gave other joints on a second call")


def check_model_keeps_input(model: HandModel) -> None:
    """forward leaves the parameters it is given as they were (the core hands it views of its
    own arrays), one hypothesis or a batch."""
    for X in (_random_params(model, np.random.default_rng(9), 6), model.default_params().astype(np.float64)):
        given = X.copy()
        try:
            model.forward(given)
        except PluginError as err:
            raise AssertionError(f"{_label(model)}: {err}") from err
        _require(np.array_equal(given, X, equal_nan=True), f"{_label(model)}: forward changed the parameters it was "
                 "given (it must not write to its input)")


def check_model_parameter_names(model: HandModel) -> None:
    """The P parameter names are unique strings that can name a column (no whitespace, commas or
    quotes); the joint angles (parameters 7..P-1) are radians: finite bounds within +-2 pi."""
    names = tuple(model.parameter_names)
    bad = [n for n in names if not (isinstance(n, str) and PARAMETER_NAME.fullmatch(n))]
    _require(not bad, f"{_label(model)}: parameter names must be strings without whitespace, commas or quotes: {bad}")
    repeated = sorted({n for n in names if names.count(n) > 1})
    _require(not repeated, f"{_label(model)}: parameter names repeat: {repeated}")
    lower, upper = (b[ANGLES] for b in _bounds(model))
    limits = np.abs(np.concatenate([lower[np.isfinite(lower)], upper[np.isfinite(upper)]]))
    _require(bool((limits <= 2 * np.pi).all()), f"{_label(model)}: joint angle bounds beyond +-2 pi "
             f"(largest {limits.max() if len(limits) else 0:.4g}): angles must be radians")


def check_model_joint_names(model: HandModel) -> None:
    """The J joint names and the derived points' names are unique, printable strings (they name
    the proposals' points, the fits' columns and the exports' joints), and a derived point
    takes no joint's name."""
    joints = tuple(model.joint_names)
    derived = tuple(model.derived_points)
    bad = [n for n in joints + derived if not (isinstance(n, str) and n and n.isprintable())]
    _require(not bad, f"{_label(model)}: joint and derived point names must be non-empty printable strings: {bad}")
    repeated = sorted({n for n in joints if joints.count(n) > 1})
    _require(not repeated, f"{_label(model)}: joint names repeat: {repeated}")
    taken = sorted(set(joints) & set(derived))
    _require(not taken, f"{_label(model)}: derived points take joint names: {taken}")


def check_model_bone_lengths(model: HandModel) -> None:
    """Every joint keeps its distance to its parent under any parameters (rigid bones)."""
    parents = np.asarray(model.parents)
    child = np.flatnonzero(parents >= 0)
    X = np.vstack([model.default_params()[None], _random_params(model, np.random.default_rng(2), 32)])
    joints = _forward(model, X)
    lengths = np.linalg.norm(joints[:, child] - joints[:, parents[child]], axis=-1)
    worst = np.abs(lengths - lengths[0]).max(axis=0)
    bad = np.flatnonzero(worst > 1e-6 * max(1.0, float(lengths[0].max())))
    _require(len(bad) == 0, f"{_label(model)}: bones change length: "
             + ", ".join(f"{model.joint_names[child[b]]} (by {worst[b]:.3g} mm)" for b in bad[:5]))


def check_model_stages(model: HandModel) -> None:
    """Stages partition the parameters and the joints, the first holding the global pose (0..6);
    at a few random poses, each parameter of a stage (moved by a quarter of its range, 10 where
    unbounded) moves none of an earlier stage's joints and some of its own (else stepwise fitting
    cannot see it in its stage)."""
    stages = model.stages()
    params = sorted(p for s in stages for p in s.parameters)
    joints = sorted(j for s in stages for j in s.joints)
    _require(params == list(range(model.n_params)), f"{_label(model)}: stage parameters do not partition 0..P-1")
    _require(joints == list(range(model.n_joints)), f"{_label(model)}: stage joints do not partition 0..J-1")
    _require(set(range(7)) <= set(stages[0].parameters), f"{_label(model)}: the first stage must hold parameters 0..6")
    lower, upper = _bounds(model)
    step = np.where(np.isfinite(upper - lower), 0.25 * (upper - lower), 10.0)  # (P,)
    X = _random_params(model, np.random.default_rng(5), 4)
    base = _forward(model, X)
    earlier: list[int] = []
    for stage in stages:
        for p in stage.parameters:
            moved = X.copy()
            moved[:, p] = np.where(X[:, p] + step[p] <= upper[p], X[:, p] + step[p], X[:, p] - step[p])
            delta = np.abs(_forward(model, moved) - base).max(axis=(0, 2))  # (J,)
            which = f"{_label(model)}: parameter {model.parameter_names[p]!r} of stage {stage.name!r}"
            _require(bool((delta[earlier] < 1e-9).all()), f"{which} moves joints of an earlier stage")
            _require(bool(delta[list(stage.joints)].max() > 1e-6), f"{which} moves none of the stage's joints")
        earlier += stage.joints


# ------------------------------------------------------------------ objectives
def _frame(seed: int, objective: Objective | None = None, K: int = 3, bound_to: list | None = None):
    """(proposals (Q, K, 3), weights (Q, K), points (5, Q, 3), loss) of a check frame, point 1 without
    proposals and a proposal of point 2 at weight 0: random points (Q = 6) or, when ``objective``
    observes depth, ToyHand's joints (Q = 7) at a pose rendered 400 mm in front of the camera (row 0)
    and perturbed. loss(points, subset=every point) -> (N,) is ``objective`` bound (None without one);
    an objective observing depth scores the points as the model's joints. With ``bound_to`` (a list)
    the loss is bound to copies of the proposals and weights, appended to it."""
    rng = np.random.default_rng(seed)
    observed = objective is not None and objective.observes_depth
    if observed:
        from .datasets.camera import Intrinsics
        from .model.render import Renderer
        from .model.rotations import matrix_to_quaternion
        from .objective import Observation
        from .synthetic.proposals import PALM_TO_CAMERA

        model = ToyHand()
        pose = model.default_params()
        pose[:3], pose[3:7] = (0.0, 0.0, 400.0), matrix_to_quaternion(PALM_TO_CAMERA)
        params = np.repeat(pose[None], 5, axis=0)
        params[1:, :3] += rng.normal(0.0, 10.0, size=(4, 3))
        params[1:, 7:] += rng.normal(0.0, 0.2, size=(4, model.n_params - 7))
        points = model.forward(model.clip(params))
        proposals = points[0][:, None] + rng.normal(0.0, 8.0, size=(model.n_joints, K, 3))
        conf = rng.random((model.n_joints, K))
    else:
        proposals = rng.normal(0.0, 30.0, size=(6, K, 3))
        conf = rng.random((6, K))
        points = proposals[None, :, 0] + rng.normal(0.0, 15.0, size=(5, 6, 3))
    conf[1], conf[2, 0] = 0.0, 0.0
    weights, every = normalise_confidences(conf), np.arange(len(proposals), dtype=np.int64)
    if objective is None:
        return proposals, weights, points, None
    given = (proposals, weights) if bound_to is None else (proposals.copy(), weights.copy())
    if bound_to is not None:
        bound_to += given
    if not observed:
        bound = objective.bind(*given)
        return proposals, weights, points, lambda points, subset=every: bound(points, subset)
    intrinsics = Intrinsics(width=160, height=120, cx=80.0, cy=60.0, fx=120.0, fy=120.0)
    observation = Observation.from_depth(Renderer(model, intrinsics).render(pose)[0][0], intrinsics)
    bound = objective.bind_observed(*given, observation, model)
    scored = lambda points, subset=every: bound(points, subset, points)
    scored.bound = bound  # the loss as bind_observed returned it
    return proposals, weights, points, scored


def check_objective_forms(objective: Objective) -> None:
    """It offers its loss in a form the core runs: a ``point_loss`` (the fast form) or its own
    ``bind`` (numpy); ``bind_observed`` when it ``observes_depth``."""
    offers = type(objective).offers
    if objective.observes_depth:
        _require("bind_observed" in offers, f"{_label(objective)}: it observes depth "
                 f"(observes_depth = True) but defines no bind_observed, the form the core scores it by")
    else:
        _require("bind" in offers or point_loss_of(objective) is not None,
                 f"{_label(objective)}: it offers its loss in no form: define point_loss (the fast form, a numba "
                 f"function of one point) or bind (numpy, a loss over a frame's points)")


def check_objective_shapes(objective: Objective) -> None:
    """loss(points (N, Q, 3), subset) is (N,) finite float64, N = 0 included, and a batch scores
    as its hypotheses one at a time."""
    _, _, points, loss = _frame(0, objective)
    out = loss(points)
    _require(isinstance(out, np.ndarray) and out.shape == (5,) and out.dtype == np.float64,
             f"{_label(objective)}: loss must be a (N,) float64 array, got {getattr(out, 'shape', type(out))}")
    _require(bool(np.isfinite(out).all()), f"{_label(objective)}: non-finite losses {out}")
    _require(loss(points[:0]).shape == (0,), f"{_label(objective)}: N = 0 must give an empty array")
    rows = np.array([loss(points[i : i + 1])[0] for i in range(len(points))])
    np.testing.assert_allclose(out, rows, rtol=1e-12, atol=1e-12, err_msg=f"{_label(objective)}: batch != rows")


def check_objective_sum_over_points(objective: Objective) -> None:
    """The loss is a sum over points: disjoint subsets add up, the empty subset scores 0, and a
    point without proposals contributes nothing wherever it is. (Only for ``additive`` objectives;
    an image term scores the whole hand on any subset.)"""
    if not objective.additive:
        not_applicable(objective, "its loss is not a sum over points (additive = False)")
    proposals, weights, points, _ = _frame(2)
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
    proposals, weights, points, loss = _frame(3, objective)
    at_top = proposals[np.arange(len(proposals)), weights.argmax(axis=-1)][None]
    low = objective.lower_bound(weights)
    values = np.concatenate([loss(points), loss(at_top)])
    _require(bool((values >= low - 1e-9 * max(1.0, abs(low))).all()),
             f"{_label(objective)}: losses {values.min()} below lower_bound {low}")


def check_objective_deterministic(objective: Objective) -> None:
    """Binding twice and scoring twice (each on its own copy of the points) gives bit-identical losses."""
    _, _, points, loss = _frame(4, objective)
    np.testing.assert_array_equal(loss(points.copy()), _frame(4, objective)[3](points.copy()),
                                  err_msg=f"{_label(objective)}: not deterministic")


def check_objective_keeps_input(objective: Objective) -> None:
    """Binding and scoring leave what they are given as it was: the proposals and weights, the
    points scored and the subset (the core hands them its own arrays, reused for every batch)."""
    bound_to: list[np.ndarray] = []
    proposals, weights, points, loss = _frame(8, objective, bound_to=bound_to)
    scored, subset = points.copy(), np.arange(len(proposals), dtype=np.int64)
    loss(scored, subset)
    for name, before, after in (("proposals", proposals, bound_to[0]), ("weights", weights, bound_to[1]),
                                ("points", points, scored), ("subset", np.arange(len(proposals)), subset)):
        which = "bind" if name in ("proposals", "weights") else "loss"
        _require(np.array_equal(before, after), f"{_label(objective)}: its {which} changed the {name} it was given "
                 "(it must not write to its input)")


def _unused(objective: Objective, name: str) -> str:
    """Why the core runs no ``name`` (``point_loss`` or ``casadi_loss``) of the objective."""
    if objective.observes_depth:
        return "it observes depth: the core scores it on the whole hand (bind_observed) only"
    if capability(objective, name) is None:
        defined = getattr(type(objective), name, None) is not getattr(Objective, name, None)
        return (f"its {name} is its parent's, and it defines its own bind, which the core runs instead" if defined
                else f"it offers no {name}")
    return f"its {name} returns None"


def _point_loss(objective: Objective):
    """The objective's point_loss (function, constants) as the core runs it, or skip the check."""
    found = point_loss_of(objective)
    if found is None:
        not_applicable(objective, _unused(objective, "point_loss"))
    return found


def check_objective_point_loss(objective: Objective) -> None:
    """Its ``point_loss`` compiles for the contract's types and writes out[i] for every hypothesis
    (an out filled with NaN comes back finite), each scored alone as beside the others (1e-12):
    the driver hands it any number of hypotheses, of several frames, in one reused buffer."""
    function, constants = _point_loss(objective)
    try:  # the contract's argument types (what the core's loops pass it)
        nb.njit(POINT_LOSS_SIGNATURE)(getattr(function, "py_func", function))
    except Exception as err:  # numba's typing error, whatever its class
        raise AssertionError(f"{_label(objective)}: its point_loss does not compile for the contract's types "
                             f"(hybridfit.objective.POINT_LOSS_SIGNATURE): {err}") from err
    proposals, weights, points, _ = _frame(6)
    for q in np.flatnonzero(weights.max(axis=-1) > 0):  # it is called only for points with proposals
        x, y, z = (np.ascontiguousarray(points[:, q, c]) for c in range(3))
        together = np.full(len(x), np.nan)
        function(x, y, z, proposals[q], weights[q], constants, together)
        unwritten = np.flatnonzero(~np.isfinite(together)).tolist()
        _require(not unwritten, f"{_label(objective)}: its point_loss left out[i] unwritten (or not finite) for "
                 f"hypotheses {unwritten} of {len(x)} at point {q}: it must write every out[i]")
        for i in range(len(x)):
            alone = np.full(1, np.nan)
            function(x[i:i + 1], y[i:i + 1], z[i:i + 1], proposals[q], weights[q], constants, alone)
            np.testing.assert_allclose(alone, together[i:i + 1], rtol=1e-12, atol=1e-12, err_msg=f"{_label(objective)}"
                                       f": its point_loss scores hypothesis {i} of point {q} alone otherwise than "
                                       f"beside the others: a hypothesis's loss must not depend on the batch")


def _agrees_with_bind(objective: Objective, name: str, score) -> None:
    """score(points (N, Q, 3), subset, proposals, weights) -> (N,), the form ``name``, gives
    ``bind``'s losses on random points, on the whole frame and on a subset of points."""
    for seed in (11, 12):
        proposals, weights, points, _ = _frame(seed)
        for subset in (np.arange(len(proposals), dtype=np.int64), np.array([0, 2, 3], dtype=np.int64)):
            want = objective.bind(proposals, weights)(points, subset)
            np.testing.assert_allclose(score(points, subset, proposals, weights), want, rtol=1e-9, atol=1e-9,
                                       err_msg=f"{_label(objective)}: {name} disagrees with bind")


def check_objective_point_loss_agrees(objective: Objective) -> None:
    """Its ``point_loss`` (what the driver scores by) gives its own ``bind``'s losses (what a
    Task and a model without a kinematic tree score by), when it defines both."""
    _point_loss(objective)
    if "bind" not in type(objective).offers:
        not_applicable(objective, "its bind is the one built from its point_loss: nothing to compare")
    _agrees_with_bind(objective, "point_loss", lambda points, subset, proposals, weights:
                      bound_point_loss(point_loss_of(objective), proposals, weights)(points, subset))


def check_objective_casadi_agrees(objective: Objective) -> None:
    """Its CasADi symbols (``casadi_loss``, when the core would use them: for gradient solvers
    such as ``casadi-ik``), evaluated on symbolic points (Q, 3) at each hypothesis, give
    ``bind``'s losses. Skipped where casadi is not installed (no solver can use them then)."""
    casadi_loss = None if objective.observes_depth else capability(objective, "casadi_loss")
    if casadi_loss is None:
        not_applicable(objective, _unused(objective, "casadi_loss"))
    try:
        import casadi as ca
    except ImportError:
        not_applicable(objective, "casadi is not installed")

    def score(points, subset, proposals, weights):
        symbols = ca.SX.sym("points", points.shape[1], 3)
        function = ca.Function("loss", [symbols], [casadi_loss(symbols, proposals, weights, subset)])
        return np.array([float(function(ca.DM(hypothesis))) for hypothesis in points])

    _agrees_with_bind(objective, "casadi_loss", score)


def check_objective_observed(objective: Objective) -> None:
    """An objective that observes depth scores the rendered pose at least as well as perturbed
    poses, and a Problem without the frame's depth is refused with an error saying so."""
    if not objective.observes_depth:
        not_applicable(objective, "it scores proposals only (observes_depth = False)")
    proposals, weights, joints, loss = _frame(5, objective)
    values = loss(joints)
    _require(bool(values[0] <= values[1:].min()), f"{_label(objective)}: the observed pose scores {values[0]}, "
             f"worse than a perturbed pose ({values[1:].min()})")
    _refuses(objective, lambda: Problem(ToyHand(), objective, proposals, weights),
             "a Problem without the depth image", "depth")


#: check_objective_observed_derivatives' central-difference step (mm) and its tolerance: a share of the
#: largest directional derivative (depth terms may be computed in float32)
DERIVATIVE_STEP_MM, DERIVATIVE_RTOL = 1e-2, 0.05


def check_objective_observed_derivatives(objective: Objective) -> None:
    """An objective with ``observed_derivatives``: its loss's ``derivatives(points, subset, joints)``
    give the loss, its gradients with respect to the points and to the joints (each along 3 random
    directions, as central differences of the loss give them) and symmetric positive semi-definite
    curvatures, in the documented shapes (:data:`hybridfit.objective.ObservedLoss`)."""
    if not (objective.observes_depth and objective.observed_derivatives):
        not_applicable(objective, "its loss offers no derivatives (observed_derivatives = False)")
    _, _, joints, scored = _frame(6, objective)
    loss, label = scored.bound, _label(objective)
    _require(callable(getattr(loss, "derivatives", None)),
             f"{label}: observed_derivatives = True, but bind_observed's loss has no derivatives")
    N, J = joints.shape[:2]
    every = np.arange(J, dtype=np.int64)
    out = loss.derivatives(joints.copy(), every, joints.copy())
    _require(isinstance(out, tuple) and len(out) == 5,
             f"{label}: derivatives gives {type(out).__name__}, not (losses, point gradients, point curvatures, "
             "joint gradients, joint curvatures)")
    values, pg, ph, jg, jc = (np.asarray(a, dtype=np.float64) for a in out)
    for name, array, shape in (("losses", values, (N,)), ("point gradients", pg, (N, J, 3)),
                               ("point curvatures", ph, (N, J, 3, 3)), ("joint gradients", jg, (N, J, 3)),
                               ("joint curvatures", jc, (N, 3 * J, 3 * J))):
        _require(array.shape == shape and bool(np.isfinite(array).all()),
                 f"{label}: derivatives' {name} are {array.shape}, not finite {shape}")
    np.testing.assert_allclose(values, loss(joints, every, joints), rtol=1e-12, atol=1e-12,
                               err_msg=f"{label}: derivatives' losses are not the loss's")
    rng, h = np.random.default_rng(7), DERIVATIVE_STEP_MM
    for name, gradient, moved in (("points", pg, 0), ("joints", jg, 1)):
        for _ in range(3):
            direction = rng.normal(size=joints.shape)
            up, down = [joints, joints], [joints, joints]
            up[moved], down[moved] = joints + h * direction, joints - h * direction
            numeric = (loss(up[0], every, up[1]) - loss(down[0], every, down[1])) / (2 * h)
            analytic = np.einsum("njc,njc->n", gradient, direction)
            worst = np.abs(numeric - analytic).max()
            _require(bool(worst <= DERIVATIVE_RTOL * max(np.abs(numeric).max(), 1e-3)),
                     f"{label}: the gradient with respect to the {name} is {analytic}, central differences give "
                     f"{numeric}")
    for name, curvature in (("point", ph), ("joint", jc)):
        scale = max(np.abs(curvature).max(), 1.0)
        _require(bool(np.allclose(curvature, np.swapaxes(curvature, -1, -2), atol=1e-9 * scale)),
                 f"{label}: the {name} curvatures are not symmetric")
        _require(bool(np.linalg.eigvalsh(curvature).min() >= -1e-9 * scale),
                 f"{label}: the {name} curvatures are not positive semi-definite")


# ------------------------------------------------------------------ optimizers
class RecordingTask(Task):
    """A Task that records every evaluated batch, (task, X (n, dim)): a callback solver's
    ``minimize`` run on it directly."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.record: list[tuple[Task, np.ndarray]] = []

    def evaluate(self, X):
        X = np.array(X, dtype=np.float64)
        losses = super().evaluate(X)
        self.record.append((self, X))
        return losses


def check_problem(seed: int = 0) -> Problem:
    """A small synthetic frame (ToyHand, ToyClamped, k = 3) for the optimiser checks."""
    model = ToyHand()
    data = synthetic_proposals(1, k=3, seed=seed, model=model)
    return Problem(model, ToyClamped(), data["proposals"][0], data["confidences"][0])


class _OneStage(Optimizer):
    """Runs ``inner`` on one stage of a frame (its ``parameters`` over its ``points``, the others
    at the initial guess), as ``stepwise`` runs an optimiser on each stage."""

    def __init__(self, inner: Optimizer, stage: tuple[str, np.ndarray, np.ndarray]) -> None:
        super().__init__()
        self.inner, self.stage = inner, stage

    def _task(self, task: Task) -> Task:
        name, params, points = self.stage
        return Task(task.problem, task.budget, params, points, name=name)

    def plan(self, task: Task) -> list[StagePlan]:
        name, params, points = self.stage
        return [StagePlan(name, params, points, points, task.budget, self.inner)]

    def min_budget(self, task: Task) -> int:
        return self.inner.min_budget(self._task(task))


def _fit(optimizer: Optimizer, problem: Problem, budget: int | None = None, seed: int = 0, stage=None):
    """(result, hypotheses (n, P)): the driver's fit of ``problem`` (of its ``stage`` (name, parameters,
    points) when given) within ``budget`` (None: the check budget), and every hypothesis evaluated,
    by the driver or by the optimiser itself through ``task.problem`` (behind the budget's back).
    A plugin error (nothing evaluated, a budget overrun) fails the check."""
    runner = optimizer if stage is None else _OneStage(optimizer, stage)
    budget = _budget(runner, Task(problem, 1)) if budget is None else budget
    seen: list[np.ndarray] = []
    own = problem.evaluate

    def behind(params, subset=None):  # the problem is the Task's: the driver itself never scores by it
        seen.append(np.array(params, dtype=np.float64, ndmin=2))
        return own(params, subset)

    problem.evaluate = behind
    try:
        result = run_problem(runner, problem, budget, seed, record=seen)
    except PluginError as err:
        raise AssertionError(f"{_label(optimizer)}: {err}") from err
    finally:
        del problem.evaluate
    return result, (np.concatenate(seen) if seen else np.zeros((0, problem.model.n_params)))


def _budget(optimizer: Optimizer, task: Task) -> int:
    return max(CHECK_BUDGET, int(optimizer.min_budget(task)))


def check_optimizer_forms(optimizer: Optimizer) -> None:
    """It offers a form the driver runs (``offers``: batch steps, derivative steps, a callback
    ``minimize`` or a plan), and each offered steps method gives its kind of steps."""
    from .task import BatchSteps, DerivativeSteps

    offers = type(optimizer).offers
    _require(bool(offers & {"batch_steps", "derivative_steps", "minimize", "plan"}),
             f"{_label(optimizer)}: it offers no form the driver runs: define batch_steps, derivative_steps, minimize "
             f"or plan")
    for form, kind in (("batch_steps", BatchSteps), ("derivative_steps", DerivativeSteps)):
        if form in offers:
            steps = getattr(optimizer, form)()
            _require(isinstance(steps, kind) and all(callable(f) for f in steps),
                     f"{_label(optimizer)}: {form}() gave {type(steps).__name__}, not {kind.__name__} of three functions")


def check_optimizer_budget(optimizer: Optimizer) -> None:
    """min_budget is a positive int and a smaller budget is refused with a HybridfitError saying
    it; never more evaluations than the budget, and the reported number is the real one."""
    problem = check_problem(1)
    need = optimizer.min_budget(Task(problem, 1))
    _require(isinstance(need, (int, np.integer)) and need >= 1, f"{_label(optimizer)}: min_budget {need!r}")
    if need > 1:
        _refuses(optimizer, lambda: run_problem(optimizer, problem, need - 1),
                 f"a budget below min_budget ({need})", str(need))
    base = max(CHECK_BUDGET, int(need))
    for budget in (base, base + 37):
        result, scored = _fit(optimizer, problem, budget)
        _require(len(scored) <= budget, f"{_label(optimizer)}: {len(scored)} evaluations for a budget of {budget}")
        _require(result.evaluations == len(scored),
                 f"{_label(optimizer)}: reports {result.evaluations} evaluations but made {len(scored)}")


def check_optimizer_deterministic(optimizer: Optimizer) -> None:
    """One seed gives a bit-identical result, whatever ran in between and whatever the
    global numpy random state is (all randomness must come from the rng passed in)."""
    problem = check_problem(2)
    state = np.random.get_state()
    try:
        np.random.seed(1)
        first, first_scored = _fit(optimizer, problem, seed=5)
        _fit(optimizer, problem, seed=6)
        np.random.seed(2)
        again, again_scored = _fit(optimizer, problem, seed=5)
    finally:
        np.random.set_state(state)
    for name, a, b in (("params", first.params, again.params), ("loss", first.loss, again.loss),
                       ("evaluations", first.evaluations, again.evaluations),
                       ("hypotheses scored", first_scored, again_scored)):
        np.testing.assert_array_equal(a, b, err_msg=f"{_label(optimizer)}: {name}: differs between runs with one seed")


def check_optimizer_bounds(optimizer: Optimizer) -> None:
    """Every evaluated hypothesis is finite and within the frame's search box."""
    problem = check_problem(3)
    _, scored = _fit(optimizer, problem)
    _require(len(scored) > 0, f"{_label(optimizer)}: evaluated nothing")
    _require(bool(np.isfinite(scored).all()), f"{_label(optimizer)}: non-finite hypotheses")
    outside = (scored < problem.lower) | (scored > problem.upper)
    _require(not outside.any(), f"{_label(optimizer)}: {int(outside.any(axis=1).sum())} hypotheses outside the "
             f"bounds of the search box")


def check_optimizer_subset(optimizer: Optimizer) -> None:
    """It works on a stage: a subset of the parameters (the others frozen) and points."""
    problem = check_problem(4)
    stage = problem.stage_points()[2]
    result, scored = _fit(optimizer, problem, stage=stage)
    _require(0 < result.evaluations == len(scored), f"{_label(optimizer)}: {result.evaluations} evaluations "
             f"reported, {len(scored)} made on a stage")
    _require(np.isfinite(result.loss), f"{_label(optimizer)}: no finite loss on the stage")
    others = np.setdiff1d(np.arange(problem.model.n_params), stage[1])
    _require(bool((scored[:, others] == problem.x0[others]).all()), f"{_label(optimizer)}: parameters outside "
             f"the stage moved")


#: share of the gap between the start's loss and the known optimum an optimiser must close
IMPROVE_SHARE = 0.2


def check_optimizer_improves(optimizer: Optimizer) -> None:
    """It closes at least ``IMPROVE_SHARE`` of the gap between its start and the optimum (loss 0)
    in the median of three seeds, on the whole problem and on one finger's stage alone (as stepwise
    fitting runs it). The problem: ToySquared with one exact proposal per ToyHand joint at a
    random pose; the start has the true global pose and the default finger angles."""
    model = ToyHand()
    truth = synthetic_proposals(1, k=1, seed=6, model=model, p_missing=0.0)["params"][0]
    start = np.concatenate([truth[:7], model.default_params()[7:]])
    problem = Problem(model, ToySquared(), model.forward(truth)[:, None], np.ones((model.n_joints, 1)), x0=start)
    for stage in (None, problem.stage_points()[1]):
        points = problem.all_points if stage is None else stage[2]
        start = float(problem.evaluate(problem.x0[None], points)[0])
        _require(start > 0, "the toy problem's start is already optimal")
        fits = [_fit(optimizer, problem, seed=seed, stage=stage)[0] for seed in range(3)]
        loss = float(np.median([fit.loss for fit in fits]))
        _require(loss <= (1.0 - IMPROVE_SHARE) * start,
                 f"{_label(optimizer)}: reached loss {loss:.4g} (median of 3 seeds) from a start of {start:.4g} on "
                 f"{'the whole problem' if stage is None else 'stage ' + repr(stage[0])} (optimum 0) within "
                 f"{fits[0].evaluations} evaluations: less than {IMPROVE_SHARE:.0%} of the gap closed")


def check_optimizer_batch_steps(optimizer: Optimizer) -> None:
    """An optimiser the driver runs (its plan's stages share batch or derivative steps,
    ``hybridfit.fitting.driver``), fitting several frames in lockstep, spends each frame's budget
    exactly (derivative steps: in whole rows of d + 1) and fits each frame as
    alone (its random numbers come from its own key). Skipped for callback-style solvers."""
    from .fitting.driver import Driver, batched_layout

    model = ToyHand()
    data = synthetic_proposals(3, k=3, seed=7, model=model)
    objective = ToyClamped()
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0])
    budget = _budget(optimizer, Task(problem, 1))
    if batched_layout(model, objective, optimizer, problem, budget) is None:
        not_applicable(optimizer, "the driver does not run it: its plan's stages share no batch steps (a "
                       "callback-style solver runs frame by frame on a Task)")
    driver = Driver(model, objective, optimizer, model.joint_names, budget, seed=3)
    together = driver.fit_chunk([0, 1, 2], data["proposals"], data["confidences"])
    _require(together.fitted == [0, 1, 2], f"{_label(optimizer)}: frames {sorted(together.errors)} failed")
    spent = sum(st.budget - (st.budget % (len(st.parameters) + 1) if st.kind == "derivative" else 0)
                for st in driver.layout(problem).stages)  # derivative steps spend whole rows of d + 1
    _require(bool((together.evaluations == spent).all()), f"{_label(optimizer)}: {together.evaluations} "
             f"evaluations for a budget of {budget} (its stages spend {spent})")
    for f in range(3):
        alone = driver.fit_chunk([f], data["proposals"][f:f + 1], data["confidences"][f:f + 1])
        _require(np.array_equal(together.params[f], alone.params[0]),
                 f"{_label(optimizer)}: frame {f} fitted beside other frames differs from frame {f} fitted alone")


# ------------------------------------------------------------------ registry of checks
_COMMON = (check_config_round_trip, check_unknown_setting, check_pickle)
_CHECKS: dict[str, tuple[Callable, ...]] = {
    "model": _COMMON + (check_model_shapes, check_model_deterministic, check_model_keeps_input,
                        check_model_parameter_names, check_model_joint_names, check_model_bone_lengths,
                        check_model_stages),
    "objective": _COMMON + (check_objective_forms, check_objective_shapes, check_objective_sum_over_points,
                            check_objective_lower_bound, check_objective_deterministic, check_objective_keeps_input,
                            check_objective_point_loss,
                            check_objective_point_loss_agrees, check_objective_casadi_agrees,
                            check_objective_observed, check_objective_observed_derivatives),
    "optimizer": _COMMON + (check_optimizer_forms, check_optimizer_budget, check_optimizer_deterministic,
                            check_optimizer_bounds, check_optimizer_subset, check_optimizer_improves,
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
    """``check_plugin("model", model)``: every check of ``checks("model")``."""
    return check_plugin("model", model)


def check_objective(objective: Objective) -> list[str]:
    """``check_plugin("objective", objective)``: every check of ``checks("objective")``."""
    return check_plugin("objective", objective)


def check_optimizer(optimizer: Optimizer) -> list[str]:
    """``check_plugin("optimizer", optimizer)``: every check of ``checks("optimizer")``."""
    return check_plugin("optimizer", optimizer)
