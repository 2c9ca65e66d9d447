"""The driver: one stage loop for every scorer, exact budgets, and results that depend on a
frame only (not its chunk, batch, threads or --jobs)."""

from __future__ import annotations

import json

import numba as nb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.fitting import driver, frames as fitting
from hybridfit.objective import Objective, point_loss_of
from hybridfit.optimizer import Task
from hybridfit.problem import Problem
from hybridfit.testing import ToyLeastSquares
from hybridfit_plugins.objectives.clamped_confidence import ClampedConfidence
from hybridfit.fitting.driver import run_problem


@nb.njit(cache=True)
def user_clamped_point(x, y, z, proposals, weights, constants, out):
    """A user's clamped-confidence (the paper's Eq. 1), written as one point's loss."""
    for i in range(x.shape[0]):
        best = 0.0
        for r in range(proposals.shape[0]):
            d2 = (proposals[r, 0] - x[i]) ** 2 + (proposals[r, 1] - y[i]) ** 2 + (proposals[r, 2] - z[i]) ** 2
            best = min(best, weights[r] * (d2 * constants[0] - 1.0))
        out[i] = best


class UserClamped(Objective):
    """clamped-confidence as a user writes it in a point_loss, outside hybridfit's plugins."""

    def point_loss(self):
        return user_clamped_point, np.array([1.0 / 40.0**2])


#: the same user's loss compiled with fastmath, as the built-in clamped-confidence is
fast_user_clamped_point = nb.njit(cache=True, fastmath=True)(user_clamped_point.py_func)


class FastUserClamped(Objective):
    """UserClamped with the built-in's floating-point options: the local stage's derivatives
    (finite differences of the per-point loss) then see the same roundings as the built-in's."""

    def point_loss(self):
        return fast_user_clamped_point, np.array([1.0 / 40.0**2])


class NumpyClamped(ClampedConfidence):
    """clamped-confidence in numpy, its terms summed point by point as the driver's loop sums
    them. It defines bind: its parent's point_loss is never run (the capability rule)."""

    def bind(self, proposals, weights):
        scale = 1.0 / self.settings.d_max_mm**2

        def loss(points, subset):
            d2 = np.square(points[:, subset, None, :] - proposals[subset]).sum(axis=-1)  # (N, m, K)
            terms = np.minimum(weights[subset] * (d2 * scale - 1.0), 0.0).min(axis=-1)  # (N, m)
            out = np.zeros(len(points))
            for t in range(len(subset)):
                out += terms[:, t]
            return out

        return loss


def driver_path(data, optimizer, budget, seed, frames, names=None, jobs=1, model=None, scorer="point",
                objective=None):
    """(params (F, P), loss (F,), evaluations (F,)) fitted by the driver, scoring with the
    objective's point_loss compiled into its loop ("point", PointScorer), its ``bind`` per frame
    ("bind", BoundScorer), or bind on a model without a kinematic tree ("forward")."""
    model = model or hybridfit.create("model", "hand26")
    objective = objective or hybridfit.create("objective", "clamped-confidence")
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0], names or data["joint_names"])
    assert driver.batched_layout(model, objective, optimizer, problem, budget)
    fitter = driver.Driver(model, objective, optimizer, names or data["joint_names"], budget, seed)
    assert (fitter.compiled(objective) is not None) == (point_loss_of(objective) is not None)
    if scorer == "point":
        assert fitter.compiled(objective) is not None
    else:
        # bind per frame (clamped-confidence's: the one built from its point_loss)
        fitter.compiled = lambda objective: None
    if scorer == "forward":
        fitter.tree = None
    chunks = [list(c) for c in np.array_split(np.asarray(frames), jobs)]  # jobs chunks run at once
    fitted = list(fitter.fit_chunks(chunks, data["proposals"], data["confidences"], jobs))
    assert [f for part in fitted for f in part.fitted] == list(frames)
    return tuple(np.concatenate([getattr(part, k) for part in fitted]) for k in ("params", "loss", "evaluations"))


def frame_losses(data, params, names=None, model=None):
    """Each frame's full clamped-confidence loss at params (F, P)."""
    model = model or hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    return np.array([Problem(model, objective, data["proposals"][f], data["confidences"][f],
                             names or data["joint_names"]).evaluate(params[n][None])[0]
                     for n, f in enumerate(range(len(params)))])


@pytest.fixture(scope="module")
def partial():
    """6 frames; frames 3-5 lose all but two palm points, so the root stage is guided by points
    of the fingers, and frame 5 also loses its whole index finger (a skipped stage)."""
    data = dict(hybridfit.synthetic_proposals(6, k=3, seed=4))
    c = data["confidences"].copy()
    c[3:, [0, 5, 9, 13]] = 0.0
    c[5, 6:9] = 0.0
    data["confidences"] = c
    return data


OPTIMIZERS = {
    "stepwise-pso": ("stepwise-pso", {}),  # the default: palm, fingers, then the local stage
    "search": ("stepwise-pso", {"local_share": 0.0}),  # the paper's: palm and fingers only
    "refine": ("stepwise-pso", {"refine_share": 0.3, "refine_config": {"init_sigma": 0.02}}),
    "joint": ("stepwise-pso", {"schedule": "joint"}),
    "stepwise+pso": ("stepwise", {"optimizer": "pso", "optimizer_config": {"cognitive": 2.0, "social": 2.0}}),
    "pso": ("pso", {"particles": 12, "init_share": 0.25}),
}


def search_alone(name: str):
    """OPTIMIZERS[name] without its local stage (of derivative steps: a scorer by bind cannot
    take them), the search stages as they are."""
    kind, config = OPTIMIZERS[name]
    return hybridfit.create("optimizer", kind,
                            {**config, "local_share": 0.0} if kind.startswith("stepwise") else config)


def has_local_stage(optimizer, data, budget, names=None, model=None) -> bool:
    """Whether the optimiser's schedule of the first frame has a stage of derivative steps."""
    model = model or hybridfit.create("model", "hand26")
    problem = Problem(model, hybridfit.create("objective", "clamped-confidence"), data["proposals"][0],
                      data["confidences"][0], names or data["joint_names"])
    lay = driver.batched_layout(model, problem.objective, optimizer, problem, budget)
    return any(st.kind == "derivative" for st in lay.stages)


#: (scorer, objective) pairs that must fit as clamped-confidence's point_loss in the driver's loop
#: does: its bind per frame, on a model without a kinematic tree, a user's point_loss, and a
#: numpy bind (per frame, and without a kinematic tree). A schedule's local stage (derivative
#: steps) needs a point_loss on a kinematic tree: these scorers are compared on the search stages
SCORERS = (("bind", None), ("forward", None), ("point", UserClamped()), ("bind", NumpyClamped()),
           ("forward", NumpyClamped()))
#: ... and these on the whole schedule, its local stage too: a user's point_loss (with the
#: built-in's floating-point options, which the local stage's finite differences see)
LOCAL_SCORERS = (("point", FastUserClamped()),)


@pytest.mark.parametrize("name", OPTIMIZERS)
@pytest.mark.parametrize("budget", [300, 1100])
def test_every_scorer_gives_the_same_fits_and_the_losses_add_up(partial, name, budget):
    optimizer = hybridfit.create("optimizer", *OPTIMIZERS[name])
    frames = np.arange(6)
    # the whole schedule, its local stage too where it has one (the default, at 1100)
    params, loss, used = driver_path(partial, optimizer, budget, 7, frames)
    assert used.tolist() == [budget] * 6
    local = has_local_stage(optimizer, partial, budget)
    if name in ("stepwise-pso", "refine") and budget == 1100:
        assert local
    if name in ("search", "joint", "stepwise+pso", "pso"):
        assert not local
    for scorer, objective in LOCAL_SCORERS:
        other_params, other_loss, other_used = driver_path(partial, optimizer, budget, 7, frames, scorer=scorer,
                                                           objective=objective)
        np.testing.assert_allclose(other_params, params, rtol=0, atol=1e-9)
        np.testing.assert_allclose(other_loss, loss, rtol=0, atol=1e-9)
        assert other_used.tolist() == [budget] * 6
    np.testing.assert_allclose(frame_losses(partial, params), loss, rtol=0, atol=1e-9)
    if local:  # a user's point_loss without fastmath: the local stage amplifies the roundings, a little
        other_params, other_loss, _ = driver_path(partial, optimizer, budget, 7, frames, scorer="point",
                                                  objective=UserClamped())
        np.testing.assert_allclose(other_params, params, rtol=0, atol=1e-4)
        np.testing.assert_allclose(other_loss, loss, rtol=0, atol=1e-6)
    # the search stages, by every scorer
    search = search_alone(name)
    params, loss, used = driver_path(partial, search, budget, 7, frames)
    assert used.tolist() == [budget] * 6 and not has_local_stage(search, partial, budget)
    for scorer, objective in SCORERS:
        other_params, other_loss, _ = driver_path(partial, search, budget, 7, frames, scorer=scorer,
                                                  objective=objective)
        np.testing.assert_allclose(other_params, params, rtol=0, atol=1e-9)
        np.testing.assert_allclose(other_loss, loss, rtol=0, atol=1e-9)
    np.testing.assert_allclose(frame_losses(partial, params), loss, rtol=0, atol=1e-9)


def test_a_local_stage_needs_a_scorer_that_takes_derivatives(partial):
    """A scorer by bind cannot take the local stage's derivative steps: one line, naming the stage."""
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    assert has_local_stage(optimizer, partial, 1100)
    with pytest.raises(hybridfit.HybridfitError, match="offers no point_loss.*'local'"):
        driver_path(partial, optimizer, 1100, 7, np.arange(2), scorer="bind")


def test_derived_points_are_scored_alike_by_every_scorer():
    data = dict(hybridfit.synthetic_proposals(3, k=2, seed=2))
    names = ["palm_centre"] + list(data["joint_names"][1:])  # the wrist replaced by the palm centre
    for optimizer, scorers in ((hybridfit.create("optimizer", "stepwise-pso"), LOCAL_SCORERS),
                               (search_alone("stepwise-pso"), SCORERS)):
        params, loss, used = driver_path(data, optimizer, 700, 1, np.arange(3), names)
        assert (used == 700).all()
        for scorer, objective in scorers:
            ref_params, ref_loss, _ = driver_path(data, optimizer, 700, 1, np.arange(3), names, scorer=scorer,
                                                  objective=objective)
            np.testing.assert_allclose(params, ref_params, rtol=0, atol=1e-9)
            np.testing.assert_allclose(loss, ref_loss, rtol=0, atol=1e-9)
        np.testing.assert_allclose(frame_losses(data, params, names), loss, rtol=0, atol=1e-9)
    assert has_local_stage(hybridfit.create("optimizer", "stepwise-pso"), data, 700, names)


def test_a_left_hand_with_other_bones_is_scored_alike_by_every_scorer():
    model = hybridfit.create("model", "hand26", {"mirror": True, "scale": 1.1})
    data = dict(hybridfit.synthetic_proposals(3, k=3, seed=8, model=model))
    # the whole schedule: its local stage's derivatives through the mirrored tree, and its loss
    # as the model's own forward kinematics give it
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    assert has_local_stage(optimizer, data, 600, model=model)
    params, loss, _ = driver_path(data, optimizer, 600, 2, np.arange(3), model=model)
    np.testing.assert_allclose(frame_losses(data, params, model=model), loss, rtol=0, atol=1e-9)
    search = search_alone("stepwise-pso")
    params, loss, _ = driver_path(data, search, 500, 2, np.arange(3), model=model)
    for scorer, objective in (("forward", None), ("bind", NumpyClamped())):
        ref_params, ref_loss, _ = driver_path(data, search, 500, 2, np.arange(3), model=model, scorer=scorer,
                                              objective=objective)
        np.testing.assert_allclose(params, ref_params, rtol=0, atol=1e-9)
        np.testing.assert_allclose(loss, ref_loss, rtol=0, atol=1e-9)


def test_a_frame_does_not_depend_on_its_batch_or_threads(frames):
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    everything = driver_path(frames, optimizer, 500, 3, np.arange(8), jobs=2)
    for batch in ([5], [6, 1], [7, 0, 3]):
        for jobs in (1, 2):
            part = driver_path(frames, optimizer, 500, 3, np.array(batch), jobs=min(jobs, len(batch)))
            for got, want in zip(part, everything):
                assert np.array_equal(got, want[batch])


@pytest.mark.parametrize("chunk", [1, 3, 256])
def test_fit_gives_the_same_results_for_any_jobs_and_chunking(frames, chunk, monkeypatch):
    pair = hybridfit.create("objective", "clamped-then-soft-l1")
    ref_params, ref_loss, _ = driver_path(frames, hybridfit.create("optimizer", "stepwise-pso"), 600, 5, np.arange(8),
                                          objective=pair)
    search_params, search_loss, _ = driver_path(frames, search_alone("stepwise-pso"), 600, 5, np.arange(8))
    monkeypatch.setattr(fitting, "CHUNK", chunk)
    # the search alone (the paper's objective and schedule) at exactly its budget
    raw = hybridfit.fit(frames["proposals"], frames["confidences"], budget=600, seed=5, objective="clamped-confidence",
                        optimizer_config={"local_share": 0.0})
    assert np.array_equal(raw.params, search_params) and np.array_equal(raw.objective, search_loss)
    one = hybridfit.fit(frames["proposals"], frames["confidences"], budget=600, seed=5)  # the default schedule
    two = hybridfit.fit(frames["proposals"], frames["confidences"], budget=600, seed=5, jobs=2)
    assert np.array_equal(one.params, ref_params) and np.array_equal(one.objective, ref_loss)
    assert np.array_equal(one.params, two.params) and np.array_equal(one.objective, two.objective)
    assert not np.array_equal(one.params, raw.params)
    assert (one.evaluations == 600).all() and (raw.evaluations == 600).all()


@settings(max_examples=12, deadline=None)
@given(budget=st.integers(12, 2500), seed=st.integers(0, 2**32 - 1), name=st.sampled_from(list(OPTIMIZERS)))
def test_budgets_are_exact_and_fits_stay_in_bounds(frames, budget, seed, name):
    optimizer = hybridfit.create("optimizer", *OPTIMIZERS[name])
    problem = Problem(hybridfit.create("model", "hand26"), hybridfit.create("objective", "clamped-confidence"),
                      frames["proposals"][0], frames["confidences"][0])
    if budget < optimizer.min_budget(Task(problem, budget)):
        return
    params, _, used = driver_path(frames, optimizer, budget, seed, np.array([0, 1]))
    assert used.tolist() == [budget, budget]
    for f in (0, 1):
        p = Problem(problem.model, problem.objective, frames["proposals"][f], frames["confidences"][f])
        assert (params[f] >= p.lower).all() and (params[f] <= p.upper).all()


def test_a_schedule_depends_on_a_frame_only_through_its_observed_points():
    """What the Driver's cache of layouts assumes: frames whose points with proposals are the
    same get the same stages."""
    rng = np.random.default_rng(0)
    data = hybridfit.synthetic_proposals(24, k=3, seed=9)
    masks = rng.random((3, 21)) < 0.3
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    optimizer = hybridfit.create("optimizer", "stepwise-pso", {"refine_share": 0.2})
    plans = {}
    for f in range(24):
        c = data["confidences"][f].copy()
        c[masks[f % 3]] = 0.0
        plan = optimizer.plan(Task(Problem(model, objective, data["proposals"][f], c), 3400))
        lay = driver.layout(plan, 21)
        first = plans.setdefault(f % 3, lay)
        assert [(st.budget, st.batch, st.owns_all) for st in first.stages] == \
            [(st.budget, st.batch, st.owns_all) for st in lay.stages]
        assert all(np.array_equal(getattr(st, k), getattr(other, k)) for st, other in zip(first.stages, lay.stages)
                   for k in ("parameters", "points", "owned"))


def test_the_driver_runs_what_offers_batch_steps_and_follows_overrides():
    model = hybridfit.create("model", "hand26")
    clamped = hybridfit.create("objective", "clamped-confidence")
    data = hybridfit.synthetic_proposals(1, k=3, seed=3)
    problem = Problem(model, clamped, data["proposals"][0], data["confidences"][0])
    from hybridfit_plugins.optimizers.pso import PSO

    class Greedy(PSO):  # changes minimize: the driver would not follow it
        def minimize(self, task, rng):
            task.evaluate(task.x0[None])

    assert driver.batched_layout(model, clamped, hybridfit.create("optimizer", "stepwise-pso"), problem, 3400)
    assert not driver.batched_layout(model, clamped, Greedy(), problem, 3400)
    stepwise_nlopt = hybridfit.create("optimizer", "stepwise", {"optimizer": "nlopt"})  # a callback solver
    assert not driver.batched_layout(model, clamped, stepwise_nlopt, problem, 3400)
    # an objective with bind only runs through the driver too (scored per frame by bind)
    assert point_loss_of(ToyLeastSquares()) is None
    assert driver.batched_layout(model, ToyLeastSquares(), hybridfit.create("optimizer", "pso"), problem, 3400)


def test_a_wrong_batch_shape_is_a_plugin_error_naming_the_optimizer(frames):
    from hybridfit_plugins.optimizers.pso import PSO, STEPS
    from hybridfit.errors import PluginError
    from hybridfit.optimizer import BatchSteps

    class Sloppy(PSO):
        def batch_steps(self):
            return BatchSteps(STEPS.init, lambda state, m: STEPS.ask(state, m)[:, :1], STEPS.tell)

    with pytest.raises(PluginError, match="Sloppy.*ask"):
        hybridfit.fit(frames["proposals"][:2], frames["confidences"][:2], optimizer=Sloppy(), budget=300)


@pytest.mark.parametrize("jobs", [1, 3])
def test_an_interrupt_keeps_the_frames_fitted_before_it(frames, interrupt_at, jobs):
    interrupt_at(3)
    result = hybridfit.fit(frames["proposals"], frames["confidences"], budget=300, jobs=jobs)
    assert result.interrupted
    assert not result.failed[:3].any() and result.failed[3:].all()
    assert (result.evaluations[:3] == 300).all()


def test_jobs_split_chunks_with_failed_frames_alike(frames, monkeypatch):
    c = frames["confidences"].copy()
    c[[2, 5]] = 0.0  # no proposals: these frames fail, the others are fitted
    monkeypatch.setattr(fitting, "CHUNK", 3)
    one = hybridfit.fit(frames["proposals"], c, budget=300, seed=1)
    three = hybridfit.fit(frames["proposals"], c, budget=300, seed=1, jobs=3)
    assert sorted(one.errors) == sorted(three.errors) == [2, 5]
    assert np.array_equal(one.params, three.params, equal_nan=True)
    assert np.array_equal(one.objective, three.objective, equal_nan=True)


def test_a_bug_in_a_bound_loss_is_a_plugin_error_naming_the_plugins(frames):
    from hybridfit.errors import PluginError
    from hybridfit.objective import Objective

    class Broken(Objective):
        def bind(self, proposals, weights):
            return lambda points, subset: np.zeros(len(points) + 1)  # one loss too many

    with pytest.raises(PluginError, match="Broken.*shape"):
        hybridfit.fit(frames["proposals"][:2], frames["confidences"][:2], objective=Broken(), budget=300)

    class Raising(Objective):
        def bind(self, proposals, weights):
            def loss(points, subset):
                raise ZeroDivisionError("oops")
            return loss

    with pytest.raises(PluginError, match="ZeroDivisionError.*objective Raising"):
        hybridfit.fit(frames["proposals"][:2], frames["confidences"][:2], objective=Raising(), budget=300)


@pytest.mark.parametrize("short", [False, True], ids=["list-of-ints", "one-frame-short"])
def test_bound_losses_are_converted_together_and_a_frame_of_the_wrong_shape_names_the_objective(frames, short):
    """The scorer converts the frames' bound losses in one go; one frame's wrong shape among
    right ones (a ragged batch) is still the objective's PluginError, and losses that are
    lists of ints score as float64 would."""
    from hybridfit.errors import PluginError
    from hybridfit.objective import Objective

    class Ragged(Objective):
        def bind(self, proposals, weights):
            first = bool(np.all(proposals == frames["proposals"][0][:len(proposals)]))

            def loss(points, subset):
                n = len(points) - (1 if short and first else 0)
                return [0] * n
            return loss

    run = lambda: hybridfit.fit(frames["proposals"][:2], frames["confidences"][:2], objective=Ragged(),  # noqa: E731
                                budget=300, seed=0)
    if short:
        with pytest.raises(PluginError, match=r"objective Ragged: its bound loss returned shape \(\d+,\), "):
            run()
    else:
        fit = run()
        assert not fit.failed.any() and np.all(fit.objective == 0.0)


def test_a_users_point_loss_fits_as_its_numpy_bind_equivalent(partial):
    """A point_loss written outside hybridfit is compiled into the driver's loop and fits, through
    the public ``fit``, as the same loss written in numpy (bind, per frame) does on the search
    stages; in the default schedule its local stage takes derivative steps as the built-in's
    does (the numpy bind's is gradient-free: it offers no per-point loss)."""
    def run(objective, **options):
        return hybridfit.fit(partial["proposals"], partial["confidences"], objective=objective, budget=900, seed=2,
                             **options)

    def local_optimizer(result):
        return json.loads(result.schedule)[0]["stages"][-1]["optimizer"]["name"]

    search = {"optimizer_config": {"local_share": 0.0}}
    ours, numpy = run(UserClamped(), **search), run(NumpyClamped(), **search)
    assert not ours.failed.any() and (ours.evaluations == 900).all()
    np.testing.assert_allclose(ours.params, numpy.params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.objective, numpy.objective, rtol=0, atol=1e-9)
    ours, builtin, numpy = run(FastUserClamped()), run("clamped-confidence"), run(NumpyClamped())
    assert local_optimizer(ours) == local_optimizer(builtin) == "levenberg-marquardt"
    assert local_optimizer(numpy) == "pso"
    assert not ours.failed.any() and (ours.evaluations == 900).all() and (numpy.evaluations == 900).all()
    np.testing.assert_allclose(ours.params, builtin.params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.objective, builtin.objective, rtol=0, atol=1e-9)


def test_a_subclass_that_defines_bind_never_runs_its_parents_point_loss(partial):
    """The capability rule: the driver scores a subclass by its own bind, whatever point_loss
    its parent offers (here one that fails when asked for)."""

    class Parent(Objective):
        def point_loss(self):
            raise AssertionError("the parent's point_loss was run")

    class Child(Parent):
        bind = ToyLeastSquares.bind

    def run(objective):
        return hybridfit.fit(partial["proposals"], partial["confidences"], objective=objective, budget=600, seed=1)

    assert point_loss_of(Child()) is None
    child, numpy = run(Child()), run(ToyLeastSquares())
    assert np.array_equal(child.params, numpy.params) and np.array_equal(child.objective, numpy.objective)


@pytest.mark.parametrize("config", [{}, {"local_share": 0.0}, {"refine_share": 0.25}],
                         ids=["default", "paper", "refine"])
def test_the_task_path_fits_every_frame_as_the_driver_does_bit_for_bit(monkeypatch, config):
    """One frame at a time (the path of depth objectives and callback solvers) runs the same
    schedule with the same documented keys (seed, frame, stage) as frames in lockstep: the same
    fit, bit for bit, for the paper's objective and the default pair, and the same for
    run_problem (Optimizer.run) on one frame."""
    data = hybridfit.synthetic_proposals(5, k=3, seed=4)
    optimizer = hybridfit.create("optimizer", "stepwise-pso", config)
    run = lambda objective: hybridfit.fit(data["proposals"], data["confidences"], budget=700, seed=7,  # noqa: E731
                                          optimizer=optimizer, objective=objective)
    by_driver, default_by_driver = run("clamped-confidence"), run("clamped-then-soft-l1")
    monkeypatch.setattr(driver.Layout, "lockstep", property(lambda self: False))  # every frame on its own
    sizes, real_run = [], driver.Driver.run
    monkeypatch.setattr(driver.Driver, "run",
                        lambda fitter, chunk: sizes.append(len(chunk.kept)) or real_run(fitter, chunk))
    by_task, default_by_task = run("clamped-confidence"), run("clamped-then-soft-l1")
    assert sizes == [1] * 10  # the patch took: one frame at a time
    assert np.array_equal(by_task.params, by_driver.params)
    assert np.array_equal(by_task.objective, by_driver.objective)
    assert np.array_equal(default_by_task.params, default_by_driver.params)
    np.testing.assert_allclose(default_by_task.objective, default_by_driver.objective, rtol=1e-12)
    assert (by_task.evaluations == 700).all() and (default_by_task.evaluations == 700).all()
    stages = json.loads(default_by_driver.schedule)[0]["stages"]
    assert (stages[-1]["name"] == "local") == ("local_share" not in config)
    for objective, fitted in (("clamped-confidence", by_driver), ("clamped-then-soft-l1", default_by_driver)):
        problem = Problem(hybridfit.create("model", "hand26"), hybridfit.create("objective", objective),
                          data["proposals"][3], data["confidences"][3], data["joint_names"])
        assert np.array_equal(run_problem(optimizer, problem, 700, 7, 3).params, fitted.params[3])
