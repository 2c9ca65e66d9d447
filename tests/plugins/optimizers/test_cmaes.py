"""cmaes: CMA-ES with bounds, population, sigma and an exact budget."""

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError
from hybridfit.optimizer import Task
from hybridfit.fitting.driver import run_problem


def test_recovers_a_known_pose_from_exact_proposals_stepwise():
    data = hybridfit.synthetic_proposals(1, k=1, noise_mm=0.0, p_missing=0.0, seed=3)
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="least-squares", budget=2000,
                        optimizer="stepwise", optimizer_config={"optimizer": "cmaes"})
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 4.0


def test_uses_the_budget_exactly_with_a_cut_last_generation():
    problem = testing.check_problem()
    for budget in (13, 100, 257):  # not multiples of the population
        result = run_problem(registry.create("optimizer", "cmaes", {"popsize": 10}), problem, budget)
        assert result.evaluations == budget


def test_population_is_batched_and_bounded():
    problem = testing.check_problem()
    task = testing.RecordingTask(problem, 95)
    registry.create("optimizer", "cmaes", {"popsize": 12, "sigma": 0.9}).minimize(task, np.random.default_rng(0))
    sizes = [len(X) for _, X in task.record]
    assert sizes[:7] == [12] * 7 and sizes[-1] == 95 - 12 * 7
    X = np.vstack([X for _, X in task.record])
    assert (X >= task.lower).all() and (X <= task.upper).all()


def test_settings_and_min_budget():
    cmaes = registry.create("optimizer", "cmaes")
    problem = testing.check_problem()
    assert cmaes.min_budget(Task(problem, 100)) == 4 + int(3 * np.log(problem.model.n_params))
    with pytest.raises(HybridfitError, match="popsize"):
        registry.create("optimizer", "cmaes", {"popsize": 1})
    with pytest.raises(HybridfitError, match="budget 5 is too small"):
        run_problem(cmaes, testing.check_problem(), 5)
