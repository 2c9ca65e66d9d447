"""casadi-ik: CasADi's SQP method on a surrogate built once per stage structure, honest accounting."""

import weakref

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError, PluginError
from hybridfit.fitting.driver import run_problem
from hybridfit.task import StagePlan, Task

pytest.importorskip("casadi")

from hybridfit_plugins.optimizers import casadi_ik


def _exact(frames=1):
    return hybridfit.synthetic_proposals(frames, k=1, noise_mm=0.0, p_missing=0.0, seed=3)


@pytest.fixture
def fresh_cache(monkeypatch):
    """An empty cache of the surrogate's problems, so that the test builds its own."""
    monkeypatch.setattr(casadi_ik, "_PROBLEMS", weakref.WeakKeyDictionary())


@pytest.fixture
def runs(monkeypatch):
    """Each run's solver counts and what was charged for them: a list of (stats, charge)."""
    seen = []
    charge = casadi_ik.CasadiIK.charge

    def recorded(self, stats):
        seen.append((dict(stats), charge(self, stats)))
        return seen[-1][1]

    monkeypatch.setattr(casadi_ik.CasadiIK, "charge", recorded)
    return seen


def _stepwise_fit(data, budget=1000, jobs=1, **config):
    return hybridfit.fit(data["proposals"], data["confidences"], objective="clamped-confidence", budget=budget,
                         optimizer="stepwise", jobs=jobs,
                         optimizer_config={"local_share": 0.0, "optimizer": "casadi-ik", "optimizer_config": config})


def test_recovers_a_known_pose_from_exact_proposals():
    data = _exact()
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="least-squares", budget=1000,
                        optimizer="casadi-ik")
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.05


def test_stepwise_on_parameter_subsets_recovers_the_pose():
    data = _exact()  # (stepwise PSO is 3 mm off at this budget)
    fit = hybridfit.fit(data["proposals"], data["confidences"], budget=1500,
                        optimizer="stepwise", optimizer_config={"optimizer": "casadi-ik"})
    assert np.linalg.norm(fit.joints - data["ground_truth"], axis=-1).max() < 0.05


def test_one_problem_per_stage_structure_serves_every_frame(fresh_cache, monkeypatch):
    built = []
    surrogate = casadi_ik._surrogate
    monkeypatch.setattr(casadi_ik, "_surrogate", lambda task, *a: built.append(task.name) or surrogate(task, *a))
    data = hybridfit.synthetic_proposals(4, k=3, seed=2)  # some joints without proposals: stages' points differ
    _stepwise_fit(data)
    assert sorted(built) == sorted(s.name for s in hybridfit.create("model", "hand26").stages())
    _stepwise_fit(hybridfit.synthetic_proposals(3, k=3, seed=4))
    assert len(built) == 6  # the next fit builds nothing


def test_no_python_runs_inside_a_solve(runs):
    problem = testing.check_problem()
    task = testing.RecordingTask(problem, 300)
    registry.create("optimizer", "casadi-ik").minimize(task, np.random.default_rng(0))
    # the candidates, then one evaluation per solver run (its charge), however many iterations it made
    assert len(task.record) == 1 + len(runs) and len(runs) >= 1
    assert all(stats["n_call_callback_fun"] == 0 for stats, _ in runs)
    assert max(stats["iter_count"] for stats, _ in runs) > 1


@pytest.mark.parametrize("gradient_cost", [0, 2, 5])
def test_each_run_is_charged_its_solver_counts_within_the_budget(runs, gradient_cost):
    problem = testing.check_problem()
    for budget in (40, 137, 400):
        runs.clear()
        task = testing.RecordingTask(problem, budget)
        optimizer = registry.create("optimizer", "casadi-ik", {"gradient_cost": gradient_cost})
        optimizer.minimize(task, np.random.default_rng(1))
        sizes = [len(X) for _, X in task.record]
        assert sizes[0] == 8  # the candidates, one batch
        charged = [stats["n_call_nlp_fg"] + (1 + gradient_cost) * stats["n_call_nlp_jac_fg"] for stats, _ in runs]
        assert sizes[1:] == [c for c in charged if c]
        assert [c for _, c in runs] == charged
        # each run within its worst case, and the total within the budget
        assert all(c <= optimizer._worst(stats["iter_count"]) for (stats, _), c in zip(runs, charged))
        assert task.used == 8 + sum(charged) <= budget


def test_a_run_whose_solver_raises_is_charged_its_worst_case(monkeypatch):
    class Raising:
        def __call__(self, **_):
            raise RuntimeError("Error in Function::call for 'ik'\nqpsolver failed")

        def stats(self):
            raise AssertionError("no counts after a raise")

    monkeypatch.setattr(casadi_ik.SymbolicProblem, "solver", lambda self, n, tol: Raising())
    problem = testing.check_problem()
    optimizer = registry.create("optimizer", "casadi-ik")
    task = testing.RecordingTask(problem, 8 + 3 * optimizer._worst(100) + 5)
    with pytest.raises(HybridfitError, match="3 runs in a row failed: qpsolver failed"):
        optimizer.minimize(task, np.random.default_rng(0))
    assert [len(X) for _, X in task.record] == [8] + [optimizer._worst(100)] * 3


def test_an_evaluation_without_a_cost_is_refused():
    with pytest.raises(PluginError, match="no cost for: n_call_nlp_hess_l"):
        registry.create("optimizer", "casadi-ik").charge({"n_call_nlp_fg": 3, "n_call_nlp_hess_l": 2})


def test_a_seed_gives_the_same_fit_cached_or_built_and_on_threads(fresh_cache):
    data = hybridfit.synthetic_proposals(4, k=3, seed=6)
    first = _stepwise_fit(data, budget=800)  # builds the problems
    again = _stepwise_fit(data, budget=800)  # reuses them
    threads = _stepwise_fit(data, budget=800, jobs=2)
    for fit in (again, threads):
        np.testing.assert_array_equal(fit.params, first.params)
        np.testing.assert_array_equal(fit.evaluations, first.evaluations)


def test_without_extract_parametric_the_problem_is_the_same(fresh_cache, monkeypatch):
    import casadi

    data = hybridfit.synthetic_proposals(2, k=3, seed=7)
    hoisted = _stepwise_fit(data, budget=800)
    monkeypatch.setattr(casadi_ik, "_PROBLEMS", weakref.WeakKeyDictionary())
    monkeypatch.delattr(casadi, "extract_parametric")
    plain = _stepwise_fit(data, budget=800)
    np.testing.assert_allclose(plain.params, hoisted.params, atol=1e-6)


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
    proposals[1, 20] = 1e200  # the surrogate is NaN for frame 1: the solver cannot start
    for on_failure in ("restart", "raise"):
        fit = hybridfit.fit(proposals, data["confidences"], budget=200, optimizer="casadi-ik",
                            optimizer_config={"on_failure": on_failure})
        assert fit.failed.tolist() == [False, True, False]
        assert "sqpmethod failed" in fit.errors[1] and "Non_Regular_Sensitivities" in fit.errors[1]
        assert np.isfinite(fit.joints[[0, 2]]).all()


def test_budget_and_settings_errors():
    data = hybridfit.synthetic_proposals(1)
    with pytest.raises(HybridfitError, match="needs at least 19 evaluations"):  # 8 candidates + one iteration
        hybridfit.fit(data["proposals"], data["confidences"], budget=10, optimizer="casadi-ik")
    with pytest.raises(HybridfitError, match="on_failure"):
        registry.create("optimizer", "casadi-ik", {"on_failure": "ignore"})


def test_a_model_without_a_kinematic_tree_is_refused():
    problem = testing.check_problem()
    task = Task(problem, 10)
    problem.model = type("Opaque", (), {"name": "opaque"})()
    with pytest.raises(HybridfitError, match="no kinematic_tree"):
        casadi_ik.own_problem(task, None)


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
    assert calls and result.loss < 1e-2  # near the least-squares optimum (0 mm^2 at the exact pose)
