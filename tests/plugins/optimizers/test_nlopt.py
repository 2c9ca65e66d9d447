"""nlopt: local and global NLopt algorithms, restarted to the budget; NLopt calls a compiled
objective where the objective has a per-point loss, and a Python callback otherwise."""

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError, PluginError
from hybridfit.fitting.driver import run_problem
from hybridfit.optimizer import Task
from hybridfit.problem import Problem
from hybridfit_plugins.optimizers import nlopt_
from hybridfit_plugins.optimizers.nlopt_ import ALGORITHMS


def test_recovers_a_known_pose_from_exact_proposals_stepwise():
    data = hybridfit.synthetic_proposals(1, k=1, noise_mm=0.0, p_missing=0.0, seed=3)
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="least-squares", budget=1500,
                        optimizer="stepwise", optimizer_config={"optimizer": "nlopt"})
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.5


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_algorithm_spends_the_budget_within_bounds_the_task_told_in_batches(algorithm):
    """On an objective with a per-point loss NLopt calls the compiled objective: the task is told
    the points it asked in a few batches (the first run's, then the rest), not one call per point."""
    problem = testing.check_problem()
    optimizer = registry.create("optimizer", "nlopt", {"algorithm": algorithm, "population": 30})
    task = testing.RecordingTask(problem, 150)
    optimizer.minimize(task, np.random.default_rng(0))
    assert task.used == 150 and len(task.record) <= 2
    X = np.vstack([X for _, X in task.record])
    assert (X >= task.lower).all() and (X <= task.upper).all()


@pytest.mark.parametrize("algorithm", ["neldermead", "crs2"])
def test_an_objective_without_a_per_point_loss_is_called_back_one_point_at_a_time(algorithm):
    base = testing.check_problem()
    problem = Problem(base.model, _Broken("none"), base.proposals, base.weights)  # bind only: no compiled form
    task = testing.RecordingTask(problem, 150)
    registry.create("optimizer", "nlopt", {"algorithm": algorithm, "population": 30}).minimize(
        task, np.random.default_rng(0))
    assert task.used == 150 and all(len(X) == 1 for _, X in task.record)


@pytest.mark.parametrize("dataset", ["synthetic", "nyu"])
def test_the_compiled_objective_scores_as_the_problem_does(hand26, clamped, dataset):
    """NLopt's compiled objective of each stage gives the problem's loss of the point (the model's
    joints; NYU's points, some of them derived from the joints), records it and counts it."""
    import ctypes

    from hybridfit.datasets.skeletons import dataset_model_config
    from hybridfit.synthetic.stress import stress_proposals

    if dataset == "synthetic":
        data, model = hybridfit.synthetic_proposals(1, k=3, seed=4), hand26
    else:
        data = stress_proposals(1, dataset="nyu", seed=3)
        model = hybridfit.create("model", "hand26", dataset_model_config("hand26", {}, "nyu"))
    problem = Problem(model, clamped, data["proposals"][0], data["confidences"][0], list(data["joint_names"]))
    assert (problem.point_matrix is None) == (dataset == "synthetic")
    rng = np.random.default_rng(0)
    for name, params, points in problem.stage_points():
        task = Task(problem, 5, params, points, name=name)
        header, arrays, objective = nlopt_.compiled_stage(task)
        assert bool(header[nlopt_.IDENTITY]) == (dataset == "synthetic")
        X = rng.uniform(task.lower, task.upper, (5, task.dim))
        for x in X:
            objective.ctypes(task.dim, x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), None, header.ctypes.data)
        assert header[nlopt_.COUNT] == 5
        np.testing.assert_array_equal(arrays["record"], X)
        np.testing.assert_allclose(arrays["losses"], problem.evaluate(task.full(X), points), rtol=1e-12)


def test_a_stage_scored_by_another_objective_goes_on_by_callbacks():
    """When the task's scores differ from the compiled objective's (the stage minimises another
    objective than the problem's), the first run's points are still the task's evaluations, and the
    rest of the budget is spent one point per call, on the task's objective."""
    problem = testing.check_problem()
    other = testing.ToySquared().bind(problem.proposals, problem.weights)
    seen = []

    def score(X):  # the task's own objective: another one than the problem's
        seen.append(len(X))
        return other(problem.model.forward(task.full(X)), problem.all_points)

    task = Task(problem, 300, score=score)
    registry.create("optimizer", "nlopt", {"xtol_rel": 0.05}).minimize(task, np.random.default_rng(0))  # short runs
    assert task.used == 300 and 1 < seen[0] < 300 and set(seen[1:]) == {1}


def test_a_seed_gives_the_same_fit():
    data = hybridfit.synthetic_proposals(2, k=3, seed=8)
    fits = [hybridfit.fit(data["proposals"], data["confidences"], objective="clamped-confidence", budget=600, seed=4,
                          optimizer="stepwise", optimizer_config={"optimizer": "nlopt"}) for _ in range(2)]
    np.testing.assert_array_equal(fits[0].params, fits[1].params)
    assert (fits[0].evaluations == 600).all()


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
            if self.fault == "none":
                return np.sum((points - proposals[None, :, 0]) ** 2, axis=(1, 2))
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
