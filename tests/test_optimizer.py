"""Optimisers through the one driver: exact budgets, guide points owned by later stages, commits
that never make a result worse, a callback solver's Task."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import BudgetExceeded, HybridfitError, PluginError
from hybridfit.fitting.driver import run_problem
from hybridfit.problem import Problem
from hybridfit.task import StagePlan, Task


@pytest.fixture(scope="module")
def problem(hand26, clamped, frames):
    return Problem(hand26, clamped, frames["proposals"][0], frames["confidences"][0])


def planned(stages):
    """An optimiser whose schedule is ``stages(task)`` (a list of StagePlan)."""
    class Planned(hybridfit.Optimizer):
        def plan(self, task):
            return stages(task)

    return Planned()


class Evaluates(hybridfit.Optimizer):
    """A callback solver that evaluates ``hypotheses(task)`` (n, dim) and nothing else."""

    def __init__(self, hypotheses) -> None:
        super().__init__()
        self.hypotheses = hypotheses

    def minimize(self, task, rng) -> None:
        task.evaluate(self.hypotheses(task))


def stepwise(problem, budget, then=()):
    pso = hybridfit.create("optimizer", "pso")
    return planned(lambda task: [StagePlan(name, params, points, points, budget, pso)
                                 for name, params, points in problem.stage_points()] + list(then))


def test_a_worse_refinement_is_not_committed(problem):
    """A refinement stage whose optimiser never tries its start cannot make the result worse."""
    def far(task):  # a poor hypothesis, not the start
        return np.clip(task.x0 + 50.0 * (task.upper - task.lower).clip(max=1.0), task.lower, task.upper)[None]

    every = np.arange(len(problem.point_names))
    refine = StagePlan("refine", np.arange(problem.model.n_params), every, every, 1, Evaluates(far))
    before = run_problem(stepwise(problem, 12), problem, 72, seed=3)
    after = run_problem(stepwise(problem, 12, [refine]), problem, 73, seed=3)
    assert before.loss == pytest.approx(problem.evaluate(before.params[None])[0])
    assert after.loss == before.loss and after.evaluations == 73
    np.testing.assert_array_equal(after.params, before.params)


def test_a_better_refinement_replaces_the_stages(problem):
    every = np.arange(len(problem.point_names))
    refine = StagePlan("refine", np.arange(problem.model.n_params), every, every, 400,
                       hybridfit.create("optimizer", "pso"))
    before = run_problem(stepwise(problem, 12), problem, 72, seed=3)
    after = run_problem(stepwise(problem, 12, [refine]), problem, 472, seed=3)
    assert after.loss < before.loss
    assert after.loss == pytest.approx(problem.evaluate(after.params[None])[0])


def test_guide_points_are_scored_but_not_owned(problem):
    """A stage minimising over more points than it owns contributes only its own points' loss."""
    (palm, palm_params, owned), (finger, finger_params, guides) = problem.stage_points()[:2]
    rest = problem.stage_points()[2:]
    pso = hybridfit.create("optimizer", "pso")
    optimizer = planned(lambda task: [StagePlan(palm, palm_params, np.union1d(owned, guides), owned, 20, pso),
                                      StagePlan(finger, finger_params, guides, guides, 20, pso)]
                        + [StagePlan(n, p, q, q, 20, pso) for n, p, q in rest])
    result = run_problem(optimizer, problem, 20 * (len(rest) + 2), seed=0)
    assert result.loss == pytest.approx(problem.evaluate(result.params[None])[0])


def test_a_task_counts_every_row_and_keeps_the_first_best(problem):
    task = Task(problem, 5)
    X = np.tile(task.x0, (3, 1))
    losses = task.evaluate(X)
    assert task.used == 3 and task.remaining == 2 and task.best_loss == losses.min()
    with pytest.raises(BudgetExceeded):
        task.evaluate(np.tile(task.x0, (3, 1)))


class _Overshoots(hybridfit.Optimizer):
    """Asks for one evaluation more than its budget (a plugin bug)."""

    def minimize(self, task, rng) -> None:
        task.evaluate(np.tile(task.x0, (task.remaining + 1, 1)))


def test_a_budget_overrun_is_a_plugin_error_naming_the_optimizer(problem):
    with pytest.raises(PluginError, match=r"optimizer _Overshoots: task .*: 11 evaluations asked, 10 left") as err:
        run_problem(_Overshoots(), problem, 10)
    assert isinstance(err.value, BudgetExceeded) and not isinstance(err.value, HybridfitError)


def test_a_wrong_ask_shape_is_a_plugin_error_naming_the_optimizer(problem):
    from hybridfit.task import BatchSteps
    from hybridfit_plugins.optimizers.pso import PSO, STEPS

    class Sloppy(PSO):
        def batch_steps(self):
            return BatchSteps(STEPS.init, lambda state, m: STEPS.ask(state, m)[:, :1], STEPS.tell)

    with pytest.raises(PluginError, match=r"optimizer Sloppy: ask\(state, 4\) returned \(1, 1, 27\)"):
        run_problem(Sloppy(particles=4), problem, 20)


def test_a_callback_solver_sees_only_its_stage(problem):
    """The parameters outside a stage stay at the stage's base in every hypothesis scored."""
    name, params, points = problem.stage_points()[-1]
    rng_solver = Evaluates(lambda task: task.lower + (task.upper - task.lower) * np.random.default_rng(0).random(
        (7, task.dim)))
    seen = []
    run_problem(planned(lambda task: [StagePlan(name, params, points, points, 7, rng_solver)]), problem, 7, 0,
                record=seen)
    X = np.concatenate(seen)
    others = np.setdiff1d(np.arange(problem.model.n_params), params)
    assert len(X) == 7
    np.testing.assert_array_equal(X[:, others], np.repeat(problem.x0[None, others], 7, axis=0))
