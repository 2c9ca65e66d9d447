"""casadi-ik: IPOPT on a smooth surrogate with symbolic kinematics and honest accounting."""

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError
from hybridfit.fitting.driver import run_problem
from hybridfit.task import StagePlan, Task

pytest.importorskip("casadi")


def _exact(frames=1):
    return hybridfit.synthetic_proposals(frames, k=1, noise_mm=0.0, p_missing=0.0, seed=3)


def test_recovers_a_known_pose_from_exact_proposals():
    data = _exact()
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="least-squares", budget=1000,
                        optimizer="casadi-ik")
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.05


def test_stepwise_on_parameter_subsets_recovers_the_pose():
    data = _exact()
    fit = hybridfit.fit(data["proposals"], data["confidences"], budget=600,
                        optimizer="stepwise", optimizer_config={"optimizer": "casadi-ik"})
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.05


def test_every_function_and_gradient_is_charged():
    problem = testing.check_problem()
    for cost in (0, 2, 5):
        task = testing.RecordingTask(problem, 120)
        registry.create("optimizer", "casadi-ik", {"gradient_cost": cost}).minimize(task, np.random.default_rng(0))
        sizes = [len(X) for _, X in task.record]
        assert sizes[0] == 8  # the candidates, one batch
        # then one row per new value, gradient_cost rows per gradient (+1 with a new value)
        assert set(sizes[1:]) <= {1, cost, cost + 1} - {0}
        assert 120 - 2 * (1 + cost) < task.used <= 120  # stopped before the budget runs out


def test_reported_loss_is_the_task_objective_of_the_reported_params():
    problem = testing.check_problem()
    result = run_problem(registry.create("optimizer", "casadi-ik"), problem, 200)
    assert result.loss == problem.evaluate(result.params[None])[0]


def test_frozen_parameters_stay_at_the_base():
    problem = testing.check_problem()
    name, params, points = problem.stage_points()[-1]
    inner = registry.create("optimizer", "casadi-ik")

    class OneStage(hybridfit.Optimizer):
        def plan(self, task):
            return [StagePlan(name, params, points, points, 150, inner)]

    seen = []
    run_problem(OneStage(), problem, 150, 0, record=seen)
    others = np.setdiff1d(np.arange(problem.model.n_params), params)
    X = np.concatenate(seen)
    np.testing.assert_array_equal(X[:, others], np.repeat(problem.x0[None, others], len(X), axis=0))


def test_a_solver_failure_fails_its_frame_only(monkeypatch):
    import hybridfit.plausible

    monkeypatch.setattr(hybridfit.plausible, "MAX_COORDINATE_MM", np.inf)  # past the input check (it refuses 1e200)
    data = hybridfit.synthetic_proposals(3, k=2, seed=0)
    proposals = data["proposals"].copy()
    proposals[1, 20] = 1e200  # the surrogate is NaN for frame 1: IPOPT cannot start
    for on_failure in ("restart", "raise"):
        fit = hybridfit.fit(proposals, data["confidences"], budget=200, optimizer="casadi-ik",
                            optimizer_config={"on_failure": on_failure})
        assert fit.failed.tolist() == [False, True, False]
        assert "IPOPT failed" in fit.errors[1] and "Invalid_Number_Detected" in fit.errors[1]
        assert np.isfinite(fit.joints[[0, 2]]).all()


def test_budget_and_settings_errors():
    data = hybridfit.synthetic_proposals(1)
    with pytest.raises(HybridfitError, match="needs at least 20 evaluations"):
        hybridfit.fit(data["proposals"], data["confidences"], budget=10, optimizer="casadi-ik")
    with pytest.raises(HybridfitError, match="on_failure"):
        registry.create("optimizer", "casadi-ik", {"on_failure": "ignore"})


def test_a_model_without_a_kinematic_tree_is_refused():
    from hybridfit_plugins.optimizers.casadi_ik import surrogate

    problem = testing.check_problem()
    task = Task(problem, 10)
    problem.model = type("Opaque", (), {"name": "opaque"})()
    with pytest.raises(HybridfitError, match="no kinematic_tree"):
        surrogate(task, 15.0, np.ones(27))


def test_names_the_surrogate_it_optimises_when_the_objective_has_no_symbols():
    problem = testing.check_problem()  # the suite's ToyClamped: not smooth, no CasADi symbols
    with pytest.warns(UserWarning, match=r"objective 'ToyClamped' offers no CasADi symbols .* surrogate: "
                                          r"the Gaussian-mixture negative log-likelihood .*sigma_mm=15"):
        run_problem(registry.create("optimizer", "casadi-ik"), problem, 100)


def test_optimises_the_objective_itself_when_it_offers_casadi_symbols():
    import warnings

    import casadi as ca

    base = type(registry.create("objective", "least-squares"))
    calls = []

    class SymbolicLeastSquares(base):
        def casadi_loss(self, points, proposals, weights, subset):
            calls.append(len(subset))
            f = ca.SX(0.0)
            for q in subset:
                if weights[q].max() > 0:
                    f += ca.sumsqr(points[int(q), :] - ca.DM(proposals[q, weights[q].argmax()]).T)
            return f

    data = _exact()
    model = registry.create("model", "hand26")
    from hybridfit.problem import Problem

    problem = Problem(model, SymbolicLeastSquares(), data["proposals"][0], data["confidences"][0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = run_problem(registry.create("optimizer", "casadi-ik"), problem, 1000)
    assert calls and result.loss < 1e-3  # the least-squares optimum (0 at the exact pose)
