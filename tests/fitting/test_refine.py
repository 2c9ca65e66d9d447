import numpy as np
import pytest

import hybridfit
from hybridfit.fitting.refine import fit_and_refine, proposal_weights, refine

NAMES = None


@pytest.fixture(scope="module")
def model():
    return hybridfit.create("model", "hand26")


def _poses(model, frames, seed=0):
    rng = np.random.default_rng(seed)
    lower, upper = model.bounds()
    x = np.tile(model.default_params(), (frames, 1))
    x[:, 2] = 400.0
    x[:, 3:7] = rng.normal(size=(frames, 4))
    x[:, 3:7] /= np.linalg.norm(x[:, 3:7], axis=1, keepdims=True)
    x[:, 7:] = rng.uniform(lower[7:], upper[7:])
    return x


def test_the_polish_reaches_a_pose_the_model_can_represent(model):
    truth = _poses(model, 8)
    start = truth.copy()
    start[:, 7:] = np.clip(start[:, 7:] + np.radians(8.0), *[b[7:] for b in model.bounds()])
    start[:, :3] += 4.0
    names = model.joint_names
    target = model.forward(truth)[:, :, None]
    before = np.linalg.norm(model.forward(start) - target[:, :, 0], axis=-1).mean()
    polished = refine(model, start, target, np.ones(target.shape[:3]), names, iterations=40).params
    after = np.linalg.norm(model.forward(polished) - target[:, :, 0], axis=-1).mean()
    assert before > 5.0 and after < 0.1 * before


def test_joint_limits_hold_and_no_frame_gets_worse(model):
    names = model.joint_names
    start = _poses(model, 6, seed=1)
    target = model.forward(start)[:, :, None] + np.random.default_rng(2).normal(0, 15.0, (6, 21, 1, 3))
    polished = refine(model, start, target, np.ones(target.shape[:3]), names).params
    lower, upper = model.bounds()
    assert (polished[:, 7:] >= lower[7:] - 1e-12).all() and (polished[:, 7:] <= upper[7:] + 1e-12).all()
    np.testing.assert_allclose(np.linalg.norm(polished[:, 3:7], axis=1), 1.0)

    def loss(p):  # soft_l1 at 10 mm, the default
        d2 = ((model.forward(p)[:, :, None] - target) ** 2).sum(-1) / 100.0
        return (2 * (np.sqrt(1 + d2) - 1)).sum((1, 2))

    assert (loss(polished) <= loss(start) + 1e-9).all() and (loss(polished) < loss(start)).any()


def test_a_far_mode_does_not_pull_and_failed_frames_stay_nan(model):
    names = model.joint_names
    start = _poses(model, 3, seed=4)
    near = model.forward(start)
    proposals = np.stack([near, near + 200.0], axis=2)  # a second mode 350 mm away
    conf = np.ones(proposals.shape[:3])
    w = proposal_weights(proposals, conf, near)
    assert (w[..., 0] == 0.5).all() and (w[..., 1] == 0).all()
    start[1] = np.nan
    polished = refine(model, start, proposals, conf, names).params
    assert np.isnan(polished[1]).all()
    np.testing.assert_allclose(model.forward(polished[[0, 2]]), near[[0, 2]], atol=1e-3)


def test_fit_and_refine_is_fit_then_the_polish(model):
    truth = model.forward(_poses(model, 3, seed=5))
    proposals = truth[:, :, None] + np.random.default_rng(6).normal(0, 3.0, truth.shape)[:, :, None]
    conf = np.ones(proposals.shape[:3])
    plain = hybridfit.fit(proposals, conf, budget=600)
    polished = fit_and_refine(proposals, conf, budget=600)
    np.testing.assert_allclose(polished.params, refine(model, plain.params, proposals, conf, model.joint_names).params)
    np.testing.assert_allclose(polished.joints, model.forward(polished.params))
    err = lambda r: np.linalg.norm(r.joints - truth, axis=-1).mean()  # noqa: E731
    assert err(polished) < err(plain)
    assert (polished.objective < 0).all() and not np.allclose(polished.objective, plain.objective)
