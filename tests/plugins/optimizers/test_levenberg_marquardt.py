"""levenberg-marquardt: the local, gradient-based stage on any objective with a per-point loss."""

import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import hybridfit
from hybridfit.fitting.driver import run_problem


@pytest.fixture(scope="module", params=["hand26", "hand27"])
def model(request):
    return hybridfit.create("model", request.param)


def _poses(model, frames, seed=0):
    rng = np.random.default_rng(seed)
    lower, upper = model.bounds()
    x = np.tile(model.default_params(), (frames, 1))
    x[:, 2] = 400.0
    x[:, 3:7] = rng.normal(size=(frames, 4))
    x[:, 3:7] /= np.linalg.norm(x[:, 3:7], axis=1, keepdims=True)
    x[:, 7:] = rng.uniform(lower[7:], upper[7:])
    return x


def _local(model, objective, start, proposals, confidences, budget, config=None, record=None):
    """The optimiser alone on one frame from ``start``: (params, loss, evaluations, problem)."""
    problem = hybridfit.Problem(model, hybridfit.create("objective", objective), proposals, confidences, x0=start)
    r = run_problem(hybridfit.create("optimizer", "levenberg-marquardt", config), problem, budget, record=record)
    return r, problem


@pytest.mark.parametrize("objective", ["soft-l1", "least-squares", "gaussian-mixture"])
def test_it_reaches_a_pose_the_model_can_represent(model, objective):
    truth = _poses(model, 3)
    lower, upper = model.bounds()
    for f in range(3):
        start = truth[f].copy()
        start[7:] = np.clip(start[7:] + np.radians(8.0), lower[7:], upper[7:])
        start[:3] += 4.0
        target = model.forward(truth[f:f + 1])[0][:, None]
        before = np.linalg.norm(model.forward(start[None])[0] - target[:, 0], axis=-1).mean()
        r, _ = _local(model, objective, start, target, np.ones(target.shape[:2]), 60 * (model.n_params + 1))
        after = np.linalg.norm(model.forward(r.params[None])[0] - target[:, 0], axis=-1).mean()
        assert before > 5.0 and after < 0.05 * before, (objective, before, after)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**16), noise_mm=st.floats(0.5, 40.0),
       objective=st.sampled_from(["soft-l1", "clamped-confidence", "gaussian-mixture"]))
def test_no_frame_ends_worse_than_its_start_and_the_box_holds(seed, noise_mm, objective):
    """Three noisy proposals per point with random confidences: the result is the best row it
    evaluated (so never worse than the start) on the objective, lies in the search box, and
    spends whole rows of d + 1 (no convergence tolerance: it steps, and is refused, to the end)."""
    model = hybridfit.create("model", "hand26")
    start = _poses(model, 1, seed=seed)[0]
    rng = np.random.default_rng(seed + 1)
    proposals = model.forward(start[None])[0][:, None] + rng.normal(0, noise_mm, (model.n_joints, 3, 3))
    conf = rng.uniform(0.05, 1.0, proposals.shape[:2])
    budget = 10 * (model.n_params + 1) + 5
    rows: list = []
    r, problem = _local(model, objective, start, proposals, conf, budget, {"tolerance": 0.0}, rows)
    assert r.loss <= problem.evaluate(np.clip(start, problem.lower, problem.upper)[None])[0] + 1e-12
    assert r.loss == pytest.approx(problem.evaluate(np.concatenate(rows)).min(), rel=1e-9, abs=1e-12)
    assert (r.params >= problem.lower).all() and (r.params <= problem.upper).all()
    assert r.evaluations == 10 * (model.n_params + 1)


def test_a_far_mode_does_not_pull_under_soft_l1(model):
    start = _poses(model, 1, seed=4)[0]
    near = model.forward(start[None])[0]
    proposals = np.stack([near + 3.0, near + 200.0], axis=1)  # a second mode 350 mm away
    r, _ = _local(model, "soft-l1", start, proposals, np.ones(proposals.shape[:2]), 40 * (model.n_params + 1))
    np.testing.assert_allclose(model.forward(r.params[None])[0], near + 3.0, atol=0.5)  # the far mode would pull 100 mm


def test_the_default_fit_is_one_rigid_hand_that_its_file_rebuilds(model, tmp_path):
    """Joints are the named model's kinematics of params (to 1e-6 mm) with one length per bone
    in every frame, and the fits file alone rebuilds it; the local stage is a gain."""
    config = {"scale": 1.07, "bone_offsets": {"index_distal": [2.0, -1.0]}}
    frames = hybridfit.synthetic_proposals(12, k=3, noise_mm=6.0, seed=3)
    result = hybridfit.fit(frames["proposals"], frames["confidences"], budget=1200, model=model.name,
                           model_config=config)
    search = hybridfit.fit(frames["proposals"], frames["confidences"], budget=1200, model=model.name,
                           model_config=config, optimizer_config={"local_share": 0.0})
    np.savez(tmp_path / "fits.npz", **result.to_npz())
    with np.load(tmp_path / "fits.npz") as saved:
        hand = hybridfit.create("model", str(saved["model"]), json.loads(str(saved["model_settings"])))
        names = [str(n) for n in saved["joint_names"]]
        np.testing.assert_allclose(hand.points(saved["params"], names), saved["joints"], atol=1e-6, rtol=0)
        np.testing.assert_allclose(hand.forward(saved["params"]), saved["model_joints"], atol=1e-6, rtol=0)
        assert json.loads(str(saved["schedule"]))[0]["stages"][-1]["optimizer"]["name"] == "levenberg-marquardt"
    parents = np.asarray(hand.parents)
    bones = np.linalg.norm(result.model_joints[:, 1:] - result.model_joints[:, parents[1:]], axis=-1)
    np.testing.assert_allclose(bones, np.broadcast_to(bones[:1], bones.shape), atol=1e-6)
    err = lambda r: np.linalg.norm(r.joints - frames["ground_truth"], axis=-1).mean()  # noqa: E731
    assert err(result) < err(search)


@pytest.mark.parametrize("name", ["hand26", "hand27"])
@pytest.mark.parametrize("dataset", ["icvl", "nyu"])
def test_the_default_fit_beats_the_paper_s_schedule_and_top1_on_stress_data(dataset, name):
    from hybridfit.datasets.skeletons import dataset_model_config

    z = hybridfit.stress_proposals(30, dataset=dataset, seed=101, scale_range=(1, 1), proportion_sd=0.0,
                                   weight_sd=0.0, offset_mm=2.0)
    names, truth = list(z["joint_names"]), z["ground_truth"]
    options = dict(joint_names=names, budget=3400, seed=0, model=name, model_config=dataset_model_config(name, {}, dataset))
    err = lambda j: np.nanmean(np.linalg.norm(j - truth, axis=-1))  # noqa: E731
    paper = err(hybridfit.fit(z["proposals"], z["confidences"], objective="clamped-confidence",
                              optimizer_config={"local_share": 0.0}, **options).joints)
    default = err(hybridfit.fit(z["proposals"], z["confidences"], **options).joints)
    assert default <= paper and default <= err(z["proposals"][:, :, 0]), (default, paper)


def test_tracking_runs_the_schedule_too(model):
    from hybridfit.fitting.tracking import track

    frames = hybridfit.synthetic_proposals(3, k=3, noise_mm=5.0, seed=8)
    tracked = track(frames["proposals"], frames["confidences"], budget=600, model=model.name)
    np.testing.assert_allclose(model.forward(tracked.params), tracked.model_joints, atol=1e-9)
    assert json.loads(tracked.schedule)[0]["stages"][-1]["name"] == "local"
    search = track(frames["proposals"], frames["confidences"], budget=600, model=model.name,
                   optimizer_config={"local_share": 0.0})
    assert not np.array_equal(tracked.params, search.params)
