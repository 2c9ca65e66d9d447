"""A stage's loss gradient and curvature (hybridfit.fitting.derivatives), as derivative steps get them."""

import numpy as np
import pytest

import hybridfit
from hybridfit.fitting.driver import Driver
from hybridfit.fitting.evaluator import PointScorer


def _scorer(objective_name, seed=0):
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", objective_name)
    frames = hybridfit.synthetic_proposals(2, k=3, noise_mm=6.0, seed=seed)
    names = model.joint_names
    driver = Driver(model, objective, hybridfit.create("optimizer", "pso"), names, 100, 0)
    weights = frames["confidences"] / frames["confidences"].sum(-1, keepdims=True)
    scorer = PointScorer(driver.tree, driver.point_map, driver.compiled(objective), frames["proposals"], weights,
                         objective)
    problems = [hybridfit.Problem(model, objective, frames["proposals"][f], frames["confidences"][f], names)
                for f in range(2)]
    return model, scorer, problems


@pytest.mark.parametrize("objective", ["soft-l1", "gaussian-mixture", "clamped-confidence"])
def test_the_gradient_is_the_loss_s_and_the_curvature_is_symmetric_positive_semidefinite(objective):
    model, scorer, problems = _scorer(objective)
    rng = np.random.default_rng(1)
    base = np.stack([p.x0 for p in problems])
    pidx = np.arange(model.n_params, dtype=np.int64)
    every = np.arange(model.n_joints, dtype=np.int64)
    X = (base + rng.normal(0, 0.01, base.shape))[:, None]
    X[:, :, :3] = base[:, None, :3] + rng.normal(0, 3.0, (2, 1, 3))
    d = model.n_params
    grads, curv = np.empty((2, 1, d)), np.empty((2, 1, d, d))
    stage = scorer.prepare_derivatives(base, pidx, every, 1)
    scorer.derivatives(stage, X, every, np.ones(2, dtype=bool), grads, curv)
    np.testing.assert_allclose(stage[3][4][:, 0], [p.evaluate(X[f])[0] for f, p in enumerate(problems)], rtol=1e-9)
    for f, problem in enumerate(problems):
        x = X[f, 0]
        h = 1e-5
        numeric = np.array([(problem.evaluate((x + h * e)[None])[0] - problem.evaluate((x - h * e)[None])[0]) / (2 * h)
                            for e in np.eye(d)])
        np.testing.assert_allclose(grads[f, 0], numeric, rtol=2e-3, atol=2e-3 * np.abs(numeric).max())
        np.testing.assert_allclose(curv[f, 0], curv[f, 0].T, atol=1e-9 * np.abs(curv[f, 0]).max())
        assert np.linalg.eigvalsh(curv[f, 0]).min() >= -1e-8 * np.abs(curv[f, 0]).max()


def test_a_point_without_proposals_adds_nothing_and_frames_not_asked_for_are_left_alone():
    model, scorer, problems = _scorer("soft-l1")
    base = np.stack([p.x0 for p in problems])
    pidx = np.arange(model.n_params, dtype=np.int64)
    every = np.arange(model.n_joints, dtype=np.int64)
    d = model.n_params

    def derivatives(points, frames=np.ones(2, dtype=bool)):
        out = [np.full((2, 1, d), 7.0), np.full((2, 1, d, d), 7.0)]
        scorer.derivatives(scorer.prepare_derivatives(base, pidx, points, 1), base[:, None], points, frames, *out)
        return out

    scorer.weights[:, 5:] = 0.0
    some, alone = derivatives(every[:5]), derivatives(every)
    for a, b in zip(some, alone):
        np.testing.assert_array_equal(a, b)
    first = derivatives(every, np.array([True, False]))
    for a, b in zip(first, alone):
        np.testing.assert_array_equal(a[0], b[0])
        assert (a[1] == 7.0).all()
