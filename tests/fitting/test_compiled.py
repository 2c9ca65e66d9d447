"""The compiled fitting path gives the Task path's results, exact budgets and determinism."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.fitting import compiled, frames as fitting
from hybridfit.optimizer import Task
from hybridfit.problem import Problem


def task_path(data, optimizer, budget, seed, frames, names=None, model=None):
    """(params (F, P), loss (F,), evaluations (F,)) fitted through Task and optimizer.run."""
    model = model or hybridfit.create("model", "hand26")
    names = tuple(names or data["joint_names"])
    spec = fitting._Spec(model, hybridfit.create("objective", "clamped-confidence"), optimizer, budget, seed, names, 60.0)
    items = fitting._fit_chunk(spec, frames, data["proposals"][frames], data["confidences"][frames])
    return tuple(np.array([item[1][k] for item in items]) for k in (0, 3, 4))


def compiled_path(data, optimizer, budget, seed, frames, names=None, threads=1, model=None):
    model = model or hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    assert compiled.supports(model, objective, optimizer)
    fitter = compiled.CompiledFitter(model, objective, optimizer, names or data["joint_names"], budget, seed)
    items = fitter.fit_chunk(list(frames), data["proposals"][frames], data["confidences"][frames], threads)
    assert [item[0] for item in items] == list(frames)
    return tuple(np.array([item[1][k] for item in items]) for k in (0, 3, 4))


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
    "stepwise-pso": ("stepwise-pso", {}),
    "refine": ("stepwise-pso", {"refine_share": 0.3, "refine_config": {"init_sigma": 0.02}}),
    "joint": ("stepwise-pso", {"schedule": "joint"}),
    "stepwise+pso": ("stepwise", {"optimizer": "pso", "optimizer_config": {"cognitive": 2.0, "social": 2.0}}),
    "pso": ("pso", {"particles": 12, "init_share": 0.25}),
}


@pytest.mark.parametrize("name", OPTIMIZERS)
@pytest.mark.parametrize("budget", [300, 1100])
def test_compiled_path_gives_the_task_paths_fits(partial, name, budget):
    optimizer = hybridfit.create("optimizer", *OPTIMIZERS[name])
    frames = np.arange(6)
    params, loss, used = compiled_path(partial, optimizer, budget, 7, frames)
    ref_params, ref_loss, ref_used = task_path(partial, optimizer, budget, 7, frames)
    assert used.tolist() == ref_used.tolist() == [budget] * 6
    np.testing.assert_allclose(params, ref_params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(loss, ref_loss, rtol=0, atol=1e-9)


def test_derived_points_are_scored_as_in_the_task_path():
    data = dict(hybridfit.synthetic_proposals(3, k=2, seed=2))
    names = ["palm_centre"] + list(data["joint_names"][1:])  # the wrist replaced by the palm centre
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    params, loss, _ = compiled_path(data, optimizer, 700, 1, np.arange(3), names)
    ref_params, ref_loss, _ = task_path(data, optimizer, 700, 1, np.arange(3), names)
    np.testing.assert_allclose(params, ref_params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(loss, ref_loss, rtol=0, atol=1e-9)


def test_a_left_hand_with_other_bones_is_fitted_as_in_the_task_path():
    model = hybridfit.create("model", "hand26", {"mirror": True, "scale": 1.1})
    data = dict(hybridfit.synthetic_proposals(3, k=3, seed=8, model=model))
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    params, loss, _ = compiled_path(data, optimizer, 500, 2, np.arange(3), model=model)
    ref_params, ref_loss, _ = task_path(data, optimizer, 500, 2, np.arange(3), model=model)
    np.testing.assert_allclose(params, ref_params, rtol=0, atol=1e-9)
    np.testing.assert_allclose(loss, ref_loss, rtol=0, atol=1e-9)


def test_a_frame_does_not_depend_on_its_batch_or_threads(frames):
    optimizer = hybridfit.create("optimizer", "stepwise-pso")
    everything = compiled_path(frames, optimizer, 500, 3, np.arange(8), threads=2)
    for batch in ([5], [6, 1], [7, 0, 3]):
        for threads in (1, 2):
            part = compiled_path(frames, optimizer, 500, 3, np.array(batch), threads=threads)
            for got, want in zip(part, everything):
                assert np.array_equal(got, want[batch])


def test_fit_uses_the_compiled_path_with_the_same_results_for_any_jobs(frames):
    one = hybridfit.fit(frames["proposals"], frames["confidences"], budget=600, seed=5)
    two = hybridfit.fit(frames["proposals"], frames["confidences"], budget=600, seed=5, jobs=2)
    ref_params, ref_loss, _ = task_path(frames, hybridfit.create("optimizer", "stepwise-pso"), 600, 5, np.arange(8))
    assert np.array_equal(one.params, two.params) and np.array_equal(one.objective, two.objective)
    np.testing.assert_allclose(one.params, ref_params, rtol=0, atol=1e-9)
    assert (one.evaluations == 600).all()


@settings(max_examples=12, deadline=None)
@given(budget=st.integers(12, 2500), seed=st.integers(0, 2**32 - 1), name=st.sampled_from(list(OPTIMIZERS)))
def test_budgets_are_exact_and_fits_stay_in_bounds(frames, budget, seed, name):
    optimizer = hybridfit.create("optimizer", *OPTIMIZERS[name])
    problem = Problem(hybridfit.create("model", "hand26"), hybridfit.create("objective", "clamped-confidence"),
                      frames["proposals"][0], frames["confidences"][0])
    if budget < optimizer.min_budget(Task(problem, budget)):
        return
    params, _, used = compiled_path(frames, optimizer, budget, seed, np.array([0, 1]))
    assert used.tolist() == [budget, budget]
    for f in (0, 1):
        p = Problem(problem.model, problem.objective, frames["proposals"][f], frames["confidences"][f])
        assert (params[f] >= p.lower).all() and (params[f] <= p.upper).all()


def test_a_schedule_depends_on_a_frame_only_through_its_observed_points():
    """What CompiledFitter's cache of schedules assumes: frames whose points with proposals
    are the same get the same stages."""
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
        plan = compiled.plan(optimizer, Task(Problem(model, objective, data["proposals"][f], c), 3400))
        lay = compiled.layout(plan)
        first = plans.setdefault(f % 3, lay)
        assert np.array_equal(first.stages, lay.stages) and np.array_equal(first.indices, lay.indices)


def test_other_plugins_take_the_task_path():
    model = hybridfit.create("model", "hand26")
    clamped = hybridfit.create("objective", "clamped-confidence")
    from hybridfit_plugins.optimizers.pso import PSO

    class Greedy(PSO):  # changes minimize: the compiled path would not follow it
        def minimize(self, task, rng):
            task.evaluate(task.x0[None])

    assert compiled.supports(model, clamped, hybridfit.create("optimizer", "stepwise-pso"))
    assert not compiled.supports(model, clamped, Greedy())
    assert not compiled.supports(model, clamped, hybridfit.create("optimizer", "stepwise", {"optimizer": "cmaes"}))
    assert not compiled.supports(model, hybridfit.create("objective", "gaussian-mixture"),
                                 hybridfit.create("optimizer", "pso"))


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
    monkeypatch.setattr(fitting, "COMPILED_CHUNK", 3)
    one = hybridfit.fit(frames["proposals"], c, budget=300, seed=1)
    three = hybridfit.fit(frames["proposals"], c, budget=300, seed=1, jobs=3)
    assert sorted(one.errors) == sorted(three.errors) == [2, 5]
    assert np.array_equal(one.params, three.params, equal_nan=True)
    assert np.array_equal(one.objective, three.objective, equal_nan=True)
