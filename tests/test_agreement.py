"""Confidences of several predictors from their agreement (no ground truth)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridfit.agreement import agreement_confidences, frame_weights, own_variances


def _predictors(sd, shared=2.0, frames=4000, points=3, seed=0):
    """Predictions (F, Q, M, 3) of a random truth: a shared error plus each its own of sd mm."""
    rng = np.random.default_rng(seed)
    truth = rng.normal(0.0, 50.0, (frames, points, 3))
    common = rng.normal(0.0, shared, truth.shape)
    return truth, np.stack([truth + common + rng.normal(0.0, s, truth.shape) for s in sd], axis=2)


def test_own_variances_are_recovered_and_the_shared_error_is_not_counted():
    _, x = _predictors([1.0, 2.0, 3.0, 4.0])
    v = own_variances(x)  # up to a common factor
    np.testing.assert_allclose(v / v.sum(1, keepdims=True), np.tile([1.0, 4.0, 9.0, 16.0], (3, 1)) / 30.0, atol=0.02)


def test_a_predictor_s_rare_failures_do_not_make_it_the_least_trusted():
    truth, x = _predictors([2.0, 3.0, 4.0], shared=1.0)
    x[::50, :, 0] += 80.0  # the best predictor loses the hand in 2 % of the frames
    conf = agreement_confidences(x)
    assert (conf[1, :, 0] > conf[1, :, 1]).all() and (conf[1, :, 1] > conf[1, :, 2]).all()
    assert (conf[0, :, 0] < 0.2 * conf[1, :, 0]).all()  # ... but it is trusted less where it fails
    assert (agreement_confidences(x, frame_reach=None)[0] == agreement_confidences(x, frame_reach=None)[1]).all()


def test_a_predictor_far_from_the_others_in_a_frame_weighs_less_there():
    truth, x = _predictors([2.0, 2.0, 2.0], shared=0.0, frames=400)
    x[7, 1, 2] += 60.0
    w = frame_weights(x)
    assert w[7, 1, 2] < 0.2 and w.shape == x.shape[:3]
    assert np.median(w) == 1.0 and (w > 0).all() and (w <= 1).all()
    np.testing.assert_array_equal(frame_weights(x, reach=np.inf), 1.0)  # no reach: nothing is far


def test_with_heavy_tailed_errors_frame_weights_beat_the_sequence_confidences():
    rng = np.random.default_rng(1)
    truth, x = _predictors([2.0, 3.0, 4.0], shared=1.0)
    x += rng.normal(0.0, 1.0, x.shape) * (rng.random(x.shape[:3] + (1,)) < 0.05) * 30.0  # 5 % gross errors
    err = lambda c: np.linalg.norm((x * (c / c.sum(-1, keepdims=True))[..., None]).sum(2) - truth, axis=-1).mean()  # noqa: E731
    assert err(agreement_confidences(x)) < 0.8 * err(agreement_confidences(x, frame_reach=None))


def test_the_weighted_mean_beats_the_best_predictor_and_the_plain_mean():
    truth, x = _predictors([2.0, 3.0, 4.0], shared=1.0)
    conf = agreement_confidences(x)
    assert conf.shape == x.shape[:3] and conf.max() == 1.0
    err = lambda p: np.linalg.norm(p - truth, axis=-1).mean()  # noqa: E731
    weighted = (x * (conf / conf.sum(-1, keepdims=True))[..., None]).sum(2)
    assert err(weighted) < min(err(x[:, :, 0]), err(x.mean(2)))


def test_two_predictors_or_unknown_points_get_equal_confidences():
    _, x = _predictors([1.0, 3.0])
    np.testing.assert_array_equal(agreement_confidences(x), 1.0)
    _, x = _predictors([1.0, 2.0, 3.0], frames=5)
    x[:, 1, 0] = np.nan  # no frame observes point 1 with predictor 0
    conf = agreement_confidences(x)
    np.testing.assert_array_equal(conf[:, 1], 1.0)
    assert (conf[:, 0] < 1.0).any()


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 6), st.integers(3, 5), st.integers(0, 2**16))
def test_confidences_are_finite_positive_and_at_most_one(frames, predictors, seed):
    _, x = _predictors(list(np.linspace(0.5, 5.0, predictors)), frames=frames, seed=seed)
    x[0, 0] = x[0, 0, :1]  # the predictors agree exactly somewhere
    conf = agreement_confidences(x)
    assert np.isfinite(conf).all() and (conf > 0).all() and (conf <= 1.0).all()
    sequence = agreement_confidences(x, frame_reach=None)
    assert sequence.min() >= 0.05 - 1e-12 or predictors < 3
    assert (conf.max(-1) == 1.0).all()


@pytest.mark.parametrize("predictors", [3, 4])
def test_identical_predictors_get_equal_confidences(predictors):
    _, x = _predictors([1.0], frames=10)
    np.testing.assert_array_equal(agreement_confidences(np.repeat(x, predictors, axis=2)), 1.0)


def test_on_a_hand_the_model_represents_the_fused_fit_beats_the_best_predictor():
    """Three correlated predictors (4/5/6 mm, half their error shared) of hand26's own points:
    fitted with confidences from their agreement, the fit beats the best of them and the fit
    with equal confidences."""
    import hybridfit
    from hybridfit.synthetic.predictors import predictor_errors

    model = hybridfit.create("model", "hand26")
    truth = hybridfit.synthetic_proposals(40, k=1, seed=5)["ground_truth"]
    names = list(model.joint_names)
    preds = truth[None] + predictor_errors(model, names, len(truth), np.random.default_rng(0))
    x = preds.transpose(1, 2, 0, 3)
    err = lambda p: np.linalg.norm(p - truth, axis=-1).mean()  # noqa: E731
    fused = err(hybridfit.fit(x, agreement_confidences(x), budget=1000).joints)
    equal = err(hybridfit.fit(x, np.ones(x.shape[:3]), budget=1000).joints)
    assert fused < min(err(p) for p in preds) and fused < equal, (fused, equal)
