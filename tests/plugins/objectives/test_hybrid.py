"""hybrid: conformance, the proposal term plus the weighted depth terms, the observed pose scoring
best, its derivatives (the proposal term's per point, the depth terms' per joint) and the local
stage that takes gradient steps on them."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import testing
from hybridfit.datasets.camera import Intrinsics
from hybridfit.fitting.driver import run_problem
from hybridfit.fitting.evaluator import BoundScorer
from hybridfit.model.render import Renderer
from hybridfit.objective import Observation
from hybridfit.optimizer import Task
from hybridfit.problem import Problem
from hybridfit.synthetic.poses import sequence_poses

MODEL = hybridfit.create("model", "hand26")
K = Intrinsics(width=160, height=120, cx=80.0, cy=60.0, fx=120.0, fy=120.0)
POSES = sequence_poses({"frames": 6, "seed": 3})
DEPTH = Renderer(MODEL, K).render(POSES)[0]
J = MODEL.n_joints
EVERY = np.arange(J, dtype=np.int64)


def _proposals(frame):
    truth = MODEL.forward(POSES[frame])
    return truth[:, None] + np.random.default_rng(frame).normal(0, 5, (J, 2, 3)), np.full((J, 2), 0.5)


def bound(frame: int, config=None):
    props, weights = _proposals(frame)
    obj = hybridfit.create("objective", "hybrid", config)
    return obj, obj.bind_observed(props, weights, Observation.from_depth(DEPTH[frame], K), MODEL)


def perturbed(frame: int, seed: int, n: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X = np.repeat(POSES[frame:frame + 1], n, axis=0)
    X[:, :3] += rng.normal(0, 15 * scale, (n, 3))
    X[:, 7:] += rng.normal(0, 0.4 * scale, (n, X.shape[1] - 7))
    return MODEL.clip(X)


@pytest.mark.parametrize("check", testing.checks("objective"), ids=lambda c: c.__name__)
def test_conformance(check):
    check(hybridfit.create("objective", "hybrid"))


def test_hybrid_is_clamped_confidence_plus_the_weighted_depth_terms():
    X = perturbed(2, 7, 6, 1.0)
    joints = MODEL.forward(X)
    props, weights = _proposals(2)
    proposal = hybridfit.create("objective", "clamped-confidence").bind(props, weights)
    _, zero = bound(2, {"data_weight": 0.0, "model_weight": 0.0})
    np.testing.assert_allclose(zero(joints, EVERY, joints), proposal(joints, EVERY))
    _, loss = bound(2, {"data_weight": 0.7, "model_weight": 0.2})
    data, silhouette = loss.terms.losses(joints)
    assert (data > 0).all() and (silhouette > 0).all()
    np.testing.assert_allclose(loss(joints, EVERY, joints), proposal(joints, EVERY) + 0.7 * data + 0.2 * silhouette)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 5), st.integers(0, 10**6))
def test_the_observed_pose_scores_best_and_its_depth_terms_are_nearly_zero(frame, seed):
    _, loss = bound(frame, {"data_weight": 1.0, "model_weight": 1.0})
    X = np.concatenate([POSES[frame:frame + 1], perturbed(frame, seed, 16, 1.0)])
    joints = MODEL.forward(X)
    data, silhouette = loss.terms.losses(joints)
    assert data[0] < 0.05 and silhouette[0] == 0.0  # its own surface: the depth is rounded to mm, nothing else
    assert data[0] < data[1:].min()
    values = loss(joints, EVERY, joints)
    assert values[0] < values[1:].min()


def test_the_sampled_points_are_the_frame_s_hand_pixels_back_projected():
    _, loss = bound(1, {"points": 40})
    frame = loss.terms.frame
    assert frame.points.shape == (3, 40)
    obs = Observation.from_depth(DEPTH[1], K)
    u = frame.points[0] * K.fx / frame.points[2] + K.cx - obs.box[0]
    v = frame.points[1] * K.fy / frame.points[2] + K.cy - obs.box[1]
    iu, iv = np.rint(u).astype(int), np.rint(v).astype(int)
    np.testing.assert_allclose(u, iu, atol=1e-9)
    np.testing.assert_allclose(frame.points[2], obs.depth_mm[iv, iu])
    assert len(set(zip(iu, iv))) == 40
    again = bound(1, {"points": 40})[1].terms.frame.points
    np.testing.assert_array_equal(again, frame.points)  # a fixed sample: the same each time


def test_off_the_mask_distances_count_from_the_margin():
    from scipy import ndimage

    obs = Observation.from_depth(DEPTH[2], K)
    for margin in (0.0, 2.5):
        dt = bound(2, {"margin_px": margin})[1].terms.frame.dt
        np.testing.assert_allclose(dt, np.maximum(ndimage.distance_transform_edt(obs.depth_mm <= 0) - margin, 0))
        assert (dt[obs.depth_mm > 0] == 0).all()


def test_derivatives_are_the_proposal_term_s_per_point_and_the_depth_terms_per_joint():
    _, loss = bound(3, {"data_weight": 0.6, "model_weight": 0.3})
    joints = MODEL.forward(perturbed(3, 1, 3, 0.3))
    values, pg, ph, jg, jc = loss.derivatives(joints, EVERY, joints)
    np.testing.assert_array_equal(values, loss(joints, EVERY, joints))
    dg, dc, mg, mc = loss.terms.derivatives(joints)
    np.testing.assert_allclose(jg, 0.6 * dg + 0.3 * mg)
    np.testing.assert_allclose(jc, 0.6 * dc + 0.3 * mc)
    props, weights = _proposals(3)
    proposal = hybridfit.create("objective", "clamped-confidence").bind(props, weights)
    h = 1e-4
    for q in range(0, J, 4):  # the proposal term's gradient at a point, by central differences
        for c in range(3):
            up, down = joints.copy(), joints.copy()
            up[:, q, c] += h
            down[:, q, c] -= h
            numeric = (proposal(up, EVERY) - proposal(down, EVERY)) / (2 * h)
            np.testing.assert_allclose(pg[:, q, c], numeric, atol=1e-6)
    assert np.all(np.linalg.eigvalsh(ph) >= -1e-12)
    only = np.array([4, 8], dtype=np.int64)  # a subset: the other points' derivatives are 0
    _, pg2, _, _, _ = loss.derivatives(joints, only, joints)
    assert np.abs(pg2[:, only]).max() > 0 and not np.delete(pg2, only, axis=1).any()


def _parameter_gradient(loss, X, point_matrix=None):
    """The scorer's gradient and curvature of one hypothesis X (P,) of every parameter."""
    scorer = BoundScorer(MODEL, None, None, point_matrix, [loss], True)
    pidx = np.arange(MODEL.n_params, dtype=np.int64)
    every = np.arange(J if point_matrix is None else len(point_matrix), dtype=np.int64)
    grads, curvs = np.empty((1, 1, len(pidx))), np.empty((1, 1, len(pidx), len(pidx)))
    scorer.derivatives(scorer.prepare_derivatives(X[None], pidx, every, 1), X[None, None].copy(), every,
                       np.ones(1, dtype=bool), grads, curvs)
    return grads[0, 0], curvs[0, 0]


@pytest.mark.parametrize("derived", [False, True], ids=["joints", "derived points"])
def test_the_scorer_chains_them_into_the_loss_gradient_of_the_parameters(derived):
    rng = np.random.default_rng(4)
    M = rng.random((6, J)) * (rng.random((6, J)) < 0.3) if derived else None
    truth = MODEL.forward(POSES[4])
    points = truth if M is None else M @ truth
    props = points[:, None] + rng.normal(0, 5, (len(points), 2, 3))
    # rho untruncated within reach (tau 30 mm): its kinks would take over central differences
    objective = hybridfit.create("objective", "hybrid", {"data_weight": 0.5, "model_weight": 0.5, "tau_mm": 30.0})
    loss = objective.bind_observed(
        props, np.full((len(points), 2), 0.5), Observation.from_depth(DEPTH[4], K), MODEL)
    every = np.arange(len(points), dtype=np.int64)

    def value(x):
        joints = MODEL.forward(x[None])
        return loss(joints if M is None else np.einsum("qj,njc->nqc", M, joints), every, joints)[0]

    X = MODEL.clip(POSES[4] + np.r_[rng.normal(0, 3, 3), np.zeros(4), rng.normal(0, 0.05, 20)])
    gradient, curvature = _parameter_gradient(loss, X, M)
    numeric = np.zeros_like(gradient)
    for k in range(len(X)):
        h = 1e-4 * max(1.0, abs(X[k]))
        numeric[k] = (value(X + h * np.eye(len(X))[k]) - value(X - h * np.eye(len(X))[k])) / (2 * h)
    np.testing.assert_allclose(gradient, numeric, atol=2e-3 * np.abs(numeric).max())
    np.testing.assert_allclose(curvature, curvature.T, atol=1e-9 * np.abs(curvature).max())
    assert np.linalg.eigvalsh(curvature).min() >= -1e-8 * np.abs(curvature).max()


def test_the_local_stage_takes_gradient_steps_on_hybrid_and_a_swarm_on_rendered_depth():
    props, conf = _proposals(0)
    obs = Observation.from_depth(DEPTH[0], K)
    stepwise = hybridfit.create("optimizer", "stepwise-pso")
    for name, local in (("hybrid", "levenberg-marquardt"), ("rendered-depth", "pso")):
        problem = Problem(MODEL, hybridfit.create("objective", name), props, conf, observation=obs)
        plan = stepwise.plan(Task(problem, 3400))
        assert plan[-1].name == "local" and plan[-1].optimizer.name == local
        if name == "hybrid":  # on its local objective: the depth weighted by the local weights
            assert plan[-1].objective.settings.data_weight == problem.objective.settings.local_data_weight
            assert plan[-1].objective.settings.model_weight == problem.objective.settings.local_model_weight
            assert all(st.objective is None for st in plan[:-1])
    res = hybridfit.fit(props[None], conf[None], objective="hybrid", observations=[obs], budget=600)
    assert res.evaluations[0] == 600
    assert json.loads(res.schedule)[0]["stages"][-1]["optimizer"]["name"] == "levenberg-marquardt"


def test_the_local_objective_is_hybrid_with_the_local_weights():
    obj = hybridfit.create("objective", "hybrid", {"local_data_weight": 7.0, "local_model_weight": 0.5, "tau_mm": 5.0})
    local = obj.local_objective()
    assert type(local) is type(obj) and local.settings == obj.settings.model_copy(
        update={"data_weight": 7.0, "model_weight": 0.5})


def test_the_search_and_the_local_objective_read_a_frame_once_and_a_used_objective_pickles():
    obj = hybridfit.create("objective", "hybrid")
    props, weights = _proposals(1)
    obs = Observation.from_depth(DEPTH[1], K)
    search = obj.bind_observed(props, weights, obs, MODEL)
    local = obj.local_objective().bind_observed(props, weights, obs, MODEL)
    assert local.terms.frame is search.terms.frame
    other = obj.bind_observed(props, weights, Observation.from_depth(DEPTH[1], K), MODEL)  # an equal, other frame
    assert other.terms.frame is not search.terms.frame
    np.testing.assert_array_equal(other.terms.frame.dt, search.terms.frame.dt)
    again = pickle.loads(pickle.dumps(obj))
    assert again == obj
    joints = MODEL.forward(perturbed(1, 3, 4, 0.5))
    np.testing.assert_array_equal(again.bind_observed(props, weights, obs, MODEL)(joints, EVERY, joints),
                                  search(joints, EVERY, joints))


def test_gradient_steps_lower_the_loss_from_where_the_search_left_it():
    props, conf = _proposals(5)
    obs = Observation.from_depth(DEPTH[5], K)
    search = hybridfit.fit(props[None], conf[None], objective="hybrid", observations=[obs], budget=1400,
                           optimizer_config={"local_share": 0.0})
    problem = Problem(MODEL, hybridfit.create("objective", "hybrid"), props, conf, observation=obs,
                      x0=search.params[0])
    refined = run_problem(hybridfit.create("optimizer", "levenberg-marquardt"), problem, 280)
    assert refined.loss < problem.evaluate(search.params[:1])[0] - 1e-3


def test_frames_fitted_together_fit_as_each_alone(monkeypatch):
    """A depth objective's frames run in lockstep in chunks (fitting.OBSERVED_CHUNK): the fits are
    those of one frame at a time, and of worker processes, bit for bit."""
    from hybridfit.fitting import frames as fitting

    data = [_proposals(f) for f in range(6)]
    props, conf = np.stack([p for p, _ in data]), np.stack([c for _, c in data])
    obs = [Observation.from_depth(d, K) for d in DEPTH]
    fits = {}
    for chunk in (1, 4, 16):
        monkeypatch.setattr(fitting, "OBSERVED_CHUNK", chunk)
        fits[chunk] = hybridfit.fit(props, conf, objective="hybrid", observations=obs, budget=500, seed=2)
    fits["jobs"] = hybridfit.fit(props, conf, objective="hybrid", observations=obs, budget=500, seed=2, jobs=2)
    for other in fits.values():
        assert np.array_equal(other.params, fits[1].params) and np.array_equal(other.objective, fits[1].objective)
    assert (fits[16].evaluations == 500).all() and not fits[16].failed.any()
