"""rendered-depth (FORTH's objective): conformance, bounds, batch invariance, and a known pose
scoring best on its own rendering; objectives that observe depth without it (with hybrid)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import testing
from hybridfit.datasets.camera import Intrinsics
from hybridfit.errors import HybridfitError
from hybridfit.objective import Observation
from hybridfit.problem import Problem
from hybridfit.model.render import Renderer
from hybridfit.synthetic.poses import sequence_poses
from hybridfit_plugins.objectives.rendered_depth import RenderedDepth

MODEL = hybridfit.create("model", "hand26")
K = Intrinsics(width=160, height=120, cx=80.0, cy=60.0, fx=120.0, fy=120.0)
POSES = sequence_poses({"frames": 6, "seed": 3})
DEPTH = Renderer(MODEL, K).render(POSES)[0]
J = MODEL.n_joints
EVERY = np.arange(J, dtype=np.int64)


def bound(name: str, frame: int, config=None):
    obj = hybridfit.create("objective", name, config)
    truth = MODEL.forward(POSES[frame])
    props = truth[:, None] + np.random.default_rng(frame).normal(0, 5, (J, 2, 3))
    weights = np.full((J, 2), 0.5)
    loss = obj.bind_observed(props, weights, Observation.from_depth(DEPTH[frame], K), MODEL)
    return obj, lambda params: loss(MODEL.forward(params), EVERY, MODEL.forward(params))


@pytest.mark.parametrize("check", testing.checks("objective"), ids=lambda c: c.__name__)
def test_conformance(check):
    check(hybridfit.create("objective", "rendered-depth"))


def perturbed(frame: int, seed: int, n: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X = np.repeat(POSES[frame:frame + 1], n, axis=0)
    X[:, :3] += rng.normal(0, 15 * scale, (n, 3))
    X[:, 7:] += rng.normal(0, 0.4 * scale, (n, X.shape[1] - 7))
    return MODEL.clip(X)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 5), st.integers(0, 10**6), st.floats(0.05, 3.0))
def test_loss_within_bounds(frame, seed, scale):
    obj, loss = bound("rendered-depth", frame)
    values = loss(perturbed(frame, seed, 8, scale))
    s = obj.settings
    assert values.shape == (8,)
    assert np.all(values >= 0) and np.all(values <= s.d_max_mm + s.silhouette_weight_mm + 1e-9)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 5), st.integers(0, 10**6), st.integers(1, 12))
def test_batch_invariance(frame, seed, n):
    _, loss = bound("rendered-depth", frame)
    X = perturbed(frame, seed, n, 1.0)
    batch = loss(X)
    rows = np.array([loss(X[i:i + 1])[0] for i in range(n)])
    np.testing.assert_array_equal(batch, rows)
    np.testing.assert_array_equal(loss(X[::-1]), batch[::-1])


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 5), st.integers(0, 10**6))
def test_known_pose_scores_best_on_its_own_rendering(frame, seed):
    _, loss = bound("rendered-depth", frame)
    values = loss(np.concatenate([POSES[frame:frame + 1], perturbed(frame, seed, 16, 1.0)]))
    assert values[0] < values[1:].min()
    assert values[0] < 6.0  # mm of 60: only edge pixels differ (nearest-pixel resampling of the observation)


def test_silhouette_only_and_far_hand():
    obj, loss = bound("rendered-depth", 0, {"silhouette_weight_mm": 0.0})
    far = POSES[:1].copy()
    far[0, 0] += 500.0  # out of the hand box: nothing rendered there
    assert loss(far)[0] == pytest.approx(obj.settings.d_max_mm)


class _Inverted(RenderedDepth):
    """Deliberately broken: prefers poses unlike the observation."""

    def bind_observed(self, proposals, weights, observation, model):
        loss = super().bind_observed(proposals, weights, observation, model)
        return lambda points, subset, joints: 100.0 - loss(points, subset, joints)


def test_the_observed_check_catches_a_broken_objective():
    with pytest.raises(AssertionError, match="perturbed"):
        testing.check_objective_observed(_Inverted())


def test_problem_without_depth_is_a_clear_error():
    truth = MODEL.forward(POSES[0])
    with pytest.raises(HybridfitError, match="depth image"):
        Problem(MODEL, hybridfit.create("objective", "rendered-depth"), truth[:, None], np.ones((J, 1)))
    with pytest.raises(HybridfitError, match="depth"):
        hybridfit.fit(truth[None, :, None], np.ones((1, J, 1)), objective="hybrid")


def test_observation_errors_name_the_frame():
    with pytest.raises(HybridfitError, match="frame 7: no hand pixels"):
        Observation.from_depth(np.zeros((120, 160)), K, where="frame 7")
    with pytest.raises(HybridfitError, match="frame 3: depth image of shape"):
        Observation.from_depth(np.zeros((10, 10)), K, where="frame 3")


def test_fit_with_observations_reports_the_full_loss():
    truth = MODEL.forward(POSES[:2])
    obs = [Observation.from_depth(d, K) for d in DEPTH[:2]]
    res = hybridfit.fit(truth[:, :, None], np.ones((2, J, 1)), objective="hybrid", observations=obs, budget=300)
    assert not res.failed.any() and (res.evaluations == 300).all()
    # stage losses do not add up for an image term: the reported loss is the final pose's own
    problem = Problem(MODEL, hybridfit.create("objective", "hybrid"), truth[0][:, None], np.ones((J, 1)),
                      observation=obs[0])
    assert res.objective[0] == pytest.approx(problem.evaluate(res.params[:1])[0], rel=1e-12)
