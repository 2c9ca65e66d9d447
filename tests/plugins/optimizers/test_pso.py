"""pso and stepwise-pso: recover known poses, honour the budget exactly, respect bounds."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import BudgetExceeded, HybridfitError
from hybridfit.metrics import joint_errors
from hybridfit.fitting.driver import run_problem
from hybridfit.task import Task
from hybridfit.problem import Problem


def problem(model, objective, data, f):
    return Problem(model, objective, data["proposals"][f], data["confidences"][f], list(data["joint_names"]))


def test_constriction_factor_of_the_hand_tracking_literature():
    from hybridfit_plugins.optimizers.pso import constriction as chi

    assert chi(2.8, 1.3) == pytest.approx(0.7298, abs=1e-4)
    assert chi(1.0, 1.0) == 1.0


@pytest.mark.parametrize("budget", [8, 57, 100, 3400])
def test_budget_is_used_exactly(hand26, clamped, frames, budget):
    pso = hybridfit.create("optimizer", "pso")
    seen = []
    result = run_problem(pso, problem(hand26, clamped, frames, 0), budget, seed=1, record=seen)
    assert result.evaluations == budget
    assert len(np.concatenate(seen)) == budget  # each hypothesis scored is one evaluation (one stage, no re-scores)


def test_stepwise_budget_split_is_exact(hand26, clamped, frames):
    from hybridfit_plugins.optimizers.stepwise import split_budget

    assert split_budget(8301, [4096, 841, 841, 841, 841, 841]) == [4096] + [841] * 5
    assert sum(split_budget(3400, [0.5] + [0.1] * 5)) == 3400
    opt = hybridfit.create("optimizer", "stepwise-pso")
    p = problem(hand26, clamped, frames, 1)
    result = run_problem(opt, p, 3401, seed=0)
    assert result.evaluations == 3401
    search = ["palm", "thumb", "index", "middle", "ring", "little"]
    plan = opt.plan(Task(p, 3401))
    assert [st.name for st in plan] == search + ["local"]
    assert sum(st.budget for st in plan) == 3401
    # the local stage: whole rows of d + 1 evaluations, the remainder to the search stages
    row, share = hand26.n_params + 1, opt.settings.local_share
    assert 0 < share and plan[-1].budget % row == 0
    assert round(share * 3401) - row < plan[-1].budget <= round(share * 3401)
    paper = opt.with_params(local_share=0.0)
    assert [st.name for st in paper.plan(Task(p, 3401))] == search
    assert run_problem(paper, p, 3401, seed=0).evaluations == 3401
    refined = opt.with_params(refine_share=0.25)
    plan = refined.plan(Task(p, 3401))
    assert [st.name for st in plan] == search + ["refine", "local"] and sum(st.budget for st in plan) == 3401
    assert run_problem(refined, p, 3401, seed=0).evaluations == 3401
    # a budget whose local share is below the local optimiser's minimum (two rows): no local
    # stage, its share goes to the search stages, and the budget is still exact
    small = int((2 * row - 0.5) / share) - 1
    plan = opt.plan(Task(p, small))
    assert [st.name for st in plan] == search and sum(st.budget for st in plan) == small
    assert run_problem(opt, p, small, seed=0).evaluations == small


def test_a_task_refuses_to_overshoot(hand26, clamped, frames):
    task = Task(problem(hand26, clamped, frames, 0), budget=5)
    task.evaluate(np.tile(task.x0, (5, 1)))
    with pytest.raises(BudgetExceeded):
        task.evaluate(task.x0[None])


def test_stepwise_loss_equals_the_full_objective(hand26, clamped, frames):
    p = problem(hand26, clamped, frames, 2)
    result = run_problem(hybridfit.create("optimizer", "stepwise-pso"), p, 1000, seed=3)
    assert result.loss == pytest.approx(p.evaluate(result.params[None])[0])


def test_same_seed_same_result_bit_for_bit(hand26, clamped, frames):
    p = problem(hand26, clamped, frames, 3)
    opt = hybridfit.create("optimizer", "stepwise-pso")
    a, b = run_problem(opt, p, 800, seed=7), run_problem(opt, p, 800, seed=7)
    np.testing.assert_array_equal(a.params, b.params)
    assert a.loss == b.loss
    assert not np.array_equal(a.params, run_problem(opt, p, 800, seed=8).params)


def test_bounds_are_respected(hand26, clamped, frames):
    p = problem(hand26, clamped, frames, 0)
    seen = []
    run_problem(hybridfit.create("optimizer", "pso"), p, 2000, seed=0, record=seen)
    X = np.concatenate(seen)
    assert len(X) == 2000
    assert np.all(X >= p.lower - 1e-12) and np.all(X <= p.upper + 1e-12)


@pytest.mark.parametrize("optimizer, config, tolerance_mm", [
    ("stepwise-pso", {}, 3.0),
    ("pso", {}, 15.0),
])
def test_known_poses_are_recovered_from_exact_proposals(hand26, clamped, exact_frames, optimizer, config, tolerance_mm):
    errors = []
    for f in range(len(exact_frames["proposals"])):
        result = run_problem(hybridfit.create("optimizer", optimizer, config), problem(hand26, clamped, exact_frames, f), 3400, f)
        errors.append(joint_errors(hand26.forward(result.params), exact_frames["ground_truth"][f]).mean())
    # stepwise PSO at budget 3400 typically lands within ~1 mm of the true joints
    assert np.mean(errors) < tolerance_mm, errors


def test_stepwise_beats_joint_on_noisy_proposals(hand26, clamped, frames):
    """The paper's ablation in miniature: at an equal, small budget stepwise reaches a better
    objective than joint optimisation in most frames (measured: about 9 frames in 10)."""
    stepwise = hybridfit.create("optimizer", "stepwise-pso")
    joint = stepwise.with_params(schedule="joint")
    better = [run_problem(stepwise, problem(hand26, clamped, frames, f), 1000, f).loss
              < run_problem(joint, problem(hand26, clamped, frames, f), 1000, f).loss for f in range(8)]
    assert sum(better) >= 6, better


@pytest.mark.parametrize("objective", ["clamped-confidence", "clamped-then-soft-l1"])
def test_the_local_stage_keeps_the_budget_and_never_loses(hand26, frames, objective):
    """The default schedule's last stage (Levenberg-Marquardt, all parameters): the fit's loss
    (the objective in force, for the pair the paper's at the final pose) is never worse than
    that of the search stages before it, which draw the same numbers."""
    p = problem(hand26, hybridfit.create("objective", objective), frames, 4)
    opt = hybridfit.create("optimizer", "stepwise-pso")
    local = run_problem(opt, p, 1200, seed=2)
    plan = opt.plan(Task(p, 1200))
    assert local.evaluations == 1200 and plan[-1].name == "local"
    assert type(plan[-1].optimizer).__name__ == "LevenbergMarquardt"
    assert local.loss == pytest.approx(p.evaluate(local.params[None])[0])
    before = run_problem(opt.with_params(local_share=0.0), p, 1200 - plan[-1].budget, seed=2)
    assert local.loss <= before.loss + 1e-12
    assert not np.array_equal(local.params, before.params)


def test_refinement_stage_keeps_the_budget_and_never_loses(hand26, clamped, frames):
    p = problem(hand26, clamped, frames, 4)
    opt = hybridfit.create("optimizer", "stepwise-pso", {"refine_share": 0.25, "local_share": 0.0})
    refined = run_problem(opt, p, 1200, seed=2)
    plan = opt.plan(Task(p, 1200))
    assert refined.evaluations == 1200 and plan[-1].name == "refine" and plan[-1].budget == 300
    assert refined.loss == pytest.approx(p.evaluate(refined.params[None])[0])
    # the loss before refinement: the stepwise stages alone (the same stage keys: the refinement
    # is the last stage, so the stages before it draw the same numbers)
    before = run_problem(opt.with_params(refine_share=0.0), p, 900, seed=2)
    assert refined.loss <= before.loss + 1e-12 or refined.loss <= p.evaluate(before.params[None])[0]


def test_budget_too_small_for_the_swarm(hand26, clamped, frames):
    opt = hybridfit.create("optimizer", "pso", {"particles": 50})
    with pytest.raises(HybridfitError, match="budget 60 is too small.*at least 100"):
        run_problem(opt, problem(hand26, clamped, frames, 0), 60)
    with pytest.raises(HybridfitError, match="too small"):
        run_problem(hybridfit.create("optimizer", "stepwise-pso"), problem(hand26, clamped, frames, 0), 10)


def test_stepwise_settings_are_validated(hand26, clamped, frames):
    with pytest.raises(HybridfitError, match="schedule"):
        hybridfit.create("optimizer", "stepwise-pso", {"schedule": "sideways"})
    with pytest.raises(HybridfitError, match="stage_weights needs 6"):
        run_problem(hybridfit.create("optimizer", "stepwise", {"stage_weights": [1, 2]}), problem(hand26, clamped, frames, 0), 100)
    with pytest.raises(HybridfitError, match="unknown optimizer"):
        run_problem(hybridfit.create("optimizer", "stepwise", {"optimizer": "nope"}), problem(hand26, clamped, frames, 0), 100)
