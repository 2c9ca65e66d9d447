"""nlopt: local and global NLopt algorithms, one point per call, restarted to the budget."""

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError, PluginError
from hybridfit_plugins.optimizers.nlopt_ import ALGORITHMS
from hybridfit.fitting.driver import run_problem


def test_recovers_a_known_pose_from_exact_proposals_stepwise():
    data = hybridfit.synthetic_proposals(1, k=1, noise_mm=0.0, p_missing=0.0, seed=3)
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="least-squares", budget=1500,
                        optimizer="stepwise", optimizer_config={"optimizer": "nlopt"})
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.5


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_algorithm_spends_the_budget_one_point_at_a_time_within_bounds(algorithm):
    problem = testing.check_problem()
    optimizer = registry.create("optimizer", "nlopt", {"algorithm": algorithm, "population": 30})
    task = testing.RecordingTask(problem, 150)
    optimizer.minimize(task, np.random.default_rng(0))
    assert task.used == 150 and all(len(X) == 1 for _, X in task.record)
    X = np.vstack([X for _, X in task.record])
    assert (X >= task.lower).all() and (X <= task.upper).all()


def test_crs2_never_overruns_a_small_remaining_budget():
    # CRS2's first population (10 (d + 1) points) ignores maxeval: the plugin must stop it
    result = run_problem(registry.create("optimizer", "nlopt", {"algorithm": "crs2"}), testing.check_problem(), 300)
    assert result.evaluations == 300


def test_unknown_algorithm_lists_the_valid_ones():
    with pytest.raises(HybridfitError, match="algorithm") as err:
        registry.create("optimizer", "nlopt", {"algorithm": "lbfgs"})
    for name in ("bobyqa", "sbplx", "crs2", "esch", "isres"):
        assert name in str(err.value)


def test_budget_below_what_the_algorithm_needs_is_refused():
    data = hybridfit.synthetic_proposals(2, seed=1)
    with pytest.raises(HybridfitError, match="needs at least 281"):  # the population, then one more
        hybridfit.fit(data["proposals"], data["confidences"], budget=100,
                      optimizer="nlopt", optimizer_config={"algorithm": "isres", "population": 280})


def test_an_nlopt_error_is_a_clear_error():
    # CRS2 needs a population of at least dim + 1 points
    problem = testing.check_problem()
    with pytest.raises(HybridfitError, match=f"NLopt crs2 failed on task all \\({problem.model.n_params} parameters\\)"):
        run_problem(registry.create("optimizer", "nlopt", {"algorithm": "crs2", "population": 5}), problem, 100)


class _Broken(hybridfit.objective.Objective):
    """A loss with a bug (ValueError) or of the wrong shape (the driver's PluginError)."""

    def __init__(self, fault: str):
        super().__init__()
        self.fault = fault

    def bind(self, proposals, weights):
        def loss(points, subset):
            if self.fault == "bug":
                raise ValueError("a bug in the objective")
            return np.zeros(len(points) + 1)

        return loss


@pytest.mark.parametrize("algorithm", ["bobyqa", "crs2"])
@pytest.mark.parametrize("fault, match", [("bug", "ValueError while fitting .* a bug in the objective"),
                                          ("shape", "objective _Broken: .*shape")])
def test_an_error_of_the_objective_stops_the_fit_and_is_not_taken_for_a_solver_failure(algorithm, fault, match):
    # NLopt catches only its own exceptions: the objective's error (a bug, a wrong shape) is a
    # PluginError of the fit, not a frame that failed to converge
    data = hybridfit.synthetic_proposals(2, seed=1)
    with pytest.raises(PluginError, match=match):
        hybridfit.fit(data["proposals"], data["confidences"], budget=300, objective=_Broken(fault),
                      optimizer="nlopt", optimizer_config={"algorithm": algorithm})
