"""Task: exact budgets, guide points owned by later stages, commits that never make a result worse."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.optimizer import Task
from hybridfit.problem import Problem


@pytest.fixture(scope="module")
def problem(hand26, clamped, frames):
    return Problem(hand26, clamped, frames["proposals"][0], frames["confidences"][0])


def test_a_worse_refinement_is_not_committed(problem):
    """A refinement stage whose optimiser never tries its start cannot make the result worse."""
    task = Task(problem, 100)
    pso = hybridfit.create("optimizer", "pso")
    for name, params, points in problem.stage_points():
        stage = task.stage(name, params, points, 12)
        pso.minimize(stage, np.random.default_rng(0))
        task.commit(stage)
    before_x, before = task.best_x.copy(), task.best_loss
    assert before == pytest.approx(problem.evaluate(task.full(before_x[None]))[0])
    refine = task.stage("refine", task.parameters, task.points, 4)
    far = task.x0 + 50.0 * (refine.upper - refine.lower).clip(max=1.0)  # a poor hypothesis, not the start
    refine.evaluate(np.clip(far, refine.lower, refine.upper)[None])
    assert refine.best_loss > before
    task.commit(refine)
    assert task.best_loss == before
    np.testing.assert_array_equal(task.best_x, before_x)


def test_a_better_refinement_replaces_the_stages(problem):
    task = Task(problem, 100)
    stage = task.stage("palm", np.arange(7), problem.stage_points()[0][2], 5)
    stage.evaluate(stage.x0[None])
    task.commit(stage)
    refine = task.stage("refine", task.parameters, task.points, 5)
    refine.evaluate(refine.x0[None])
    task.commit(refine)
    assert task.best_loss == pytest.approx(problem.evaluate(task.full(task.best_x[None]))[0])


def test_guide_points_are_scored_but_not_owned(problem):
    """A stage minimising over more points than it owns contributes only its own points' loss."""
    owned = problem.stage_points()[0][2]
    guides = problem.stage_points()[1][2]
    task = Task(problem, 10)
    stage = task.stage("palm", np.arange(7), np.union1d(owned, guides), 3, owned=owned)
    X = stage.x0 + np.random.default_rng(1).normal(0, 0.01, (3, 7))
    losses = stage.evaluate(X)
    best = X[losses.argmin()]
    assert stage.used == 3 and task.used == 3  # one evaluation per hypothesis, whatever the points
    assert stage.best_loss == pytest.approx(problem.evaluate(stage.full(best[None]), np.union1d(owned, guides))[0])
    assert stage.best_owned_loss == pytest.approx(problem.evaluate(stage.full(best[None]), owned)[0])
    task.commit(stage)
    assert task.best_loss == pytest.approx(stage.best_owned_loss)


class _Overshoots(hybridfit.Optimizer):
    """Asks for one evaluation more than its budget (a plugin bug)."""

    def minimize(self, task, rng) -> None:
        task.evaluate(np.tile(task.x0, (task.remaining + 1, 1)))


def test_a_budget_overrun_is_a_plugin_error_naming_the_optimizer(problem):
    from hybridfit.errors import BudgetExceeded, HybridfitError, PluginError

    with pytest.raises(PluginError, match=r"optimizer _Overshoots: task .*: 11 evaluations asked, 10 left") as err:
        _Overshoots().run(problem, 10)
    assert isinstance(err.value, BudgetExceeded) and not isinstance(err.value, HybridfitError)


def test_a_wrong_ask_shape_on_the_task_path_is_a_plugin_error_naming_the_optimizer(problem):
    from hybridfit.errors import PluginError
    from hybridfit.optimizer import BatchSteps
    from hybridfit_plugins.optimizers.pso import PSO, STEPS

    class Sloppy(PSO):
        def batch_steps(self):
            return BatchSteps(STEPS.init, lambda state, m: STEPS.ask(state, m)[:, :1], STEPS.tell)

    with pytest.raises(PluginError, match=r"optimizer Sloppy: ask returned hypotheses of shape \(1, 1, 27\)"):
        Sloppy(particles=4).run(problem, 20)
