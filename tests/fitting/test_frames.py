"""hybridfit.fit over frames: shapes, accuracy, determinism across jobs, failures, mapping."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.metrics import joint_errors, summary


def test_fit_beats_the_top_proposals(frames):
    result = hybridfit.fit(frames["proposals"], frames["confidences"], budget=3400, seed=0)
    assert result.params.shape == (8, 27) and result.joints.shape == (8, 21, 3)
    assert (result.evaluations == 3400).all() and not result.failed.any()
    fitted = joint_errors(result.joints, frames["ground_truth"]).mean()
    top = joint_errors(frames["proposals"][:, :, 0], frames["ground_truth"]).mean()
    assert fitted < top, (fitted, top)


def test_results_do_not_depend_on_jobs(frames):
    a = hybridfit.fit(frames["proposals"][:4], frames["confidences"][:4], budget=500, seed=3, jobs=1)
    b = hybridfit.fit(frames["proposals"][:4], frames["confidences"][:4], budget=500, seed=3, jobs=2)
    np.testing.assert_array_equal(a.params, b.params)
    np.testing.assert_array_equal(a.objective, b.objective)


def test_subset_of_named_points(hand26, exact_frames):
    names = ["palm_centre", "wrist", "thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip",
             "index_mcp", "little_mcp", "thumb_mcp"]
    pts = hand26.points(exact_frames["params"], names)
    result = hybridfit.fit(pts[:, :, None], np.ones(pts.shape[:2] + (1,)), joint_names=names, budget=2000)
    assert result.joints.shape == (4, len(names), 3) and result.joint_names == tuple(names)
    assert result.model_joints.shape == (4, 21, 3)
    assert joint_errors(result.joints, pts).mean() < 5.0


def test_a_failing_frame_is_recorded_and_the_others_finish(frames):
    conf = frames["confidences"][:3].copy()
    conf[1] = 0.0  # frame 1 has no proposals at all
    result = hybridfit.fit(frames["proposals"][:3], conf, budget=300)
    assert list(result.failed) == [False, True, False]
    assert "no proposals" in result.errors[1]
    assert np.isnan(result.joints[1]).all() and np.isfinite(result.joints[[0, 2]]).all()


@pytest.mark.parametrize("mutate, message", [
    (lambda p, c: (p[:, :, :, :2], c), r"shape \(frames, joints, k, 3\)"),
    (lambda p, c: (p, c[:, :, :2]), "'confidences' must have shape"),
    (lambda p, c: (np.where(np.arange(p.shape[0])[:, None, None, None] == 2, np.nan, p), c), "NaN or inf.*frame 2"),
    (lambda p, c: (p, -c), "negative"),
])
def test_bad_input_is_refused_naming_the_problem(frames, mutate, message):
    p, c = mutate(frames["proposals"].copy(), frames["confidences"].copy())
    with pytest.raises(HybridfitError, match=message):
        hybridfit.fit(p, c)


def test_budget_too_small_is_refused_before_fitting(frames):
    with pytest.raises(HybridfitError, match="budget 20 is too small for optimizer stepwise-pso"):
        hybridfit.fit(frames["proposals"], frames["confidences"], budget=20)


def test_synthetic_proposals_layout():
    d = hybridfit.synthetic_proposals(5, k=4, seed=2)
    assert d["proposals"].shape == (5, 21, 4, 3) and d["confidences"].shape == (5, 21, 4)
    assert d["ground_truth"].shape == (5, 21, 3) and d["params"].shape == (5, 27)
    assert np.all(np.diff(d["confidences"], axis=-1) <= 0)  # sorted by confidence
    again = hybridfit.synthetic_proposals(5, k=4, seed=2)
    np.testing.assert_array_equal(d["proposals"], again["proposals"])
    s = summary(d["proposals"][:, :, 0], d["ground_truth"])
    assert 5 < s["mean_error_mm"] < 40
    with pytest.raises(HybridfitError, match="k >= 1"):
        hybridfit.synthetic_proposals(3, k=0)


def test_an_interrupt_keeps_the_finished_frames(frames, interrupt_at):
    interrupt_at(2)
    result = hybridfit.fit(frames["proposals"][:4], frames["confidences"][:4], budget=300)
    assert result.interrupted
    assert list(result.failed) == [False, False, True, True]
    assert result.errors == {2: "interrupted", 3: "interrupted"}
    assert np.isfinite(result.joints[:2]).all()


@pytest.mark.parametrize("other", [{"scale": 1.1}, {"limits_deg": {"index_mcp_flexion": [0.0, 45.0]}}])
def test_a_fit_after_another_models_fit_is_the_same(frames, other):
    """What fit keeps between calls (the model's stages, neutral pose and bounds, by model
    settings and point names) never hands one model's to another."""
    from hybridfit import stages

    def fit(config):
        return hybridfit.fit(frames["proposals"][:3], frames["confidences"][:3], budget=300, seed=1,
                             model_config=config)

    stages._STRUCTURES.clear()
    stages._LAST.clear()
    alone = fit(other)  # the other model fitted first, with nothing kept
    first = fit({})
    between = fit(other)
    again = fit({})
    np.testing.assert_array_equal(between.params, alone.params)
    np.testing.assert_array_equal(between.objective, alone.objective)
    np.testing.assert_array_equal(again.params, first.params)
    np.testing.assert_array_equal(again.objective, first.objective)
    assert not np.array_equal(between.params, first.params)


def test_the_scale_warning_and_the_inliers_count_frames_with_proposals_only(frames):
    p, c = frames["proposals"][:3].copy(), frames["confidences"][:3].copy()
    c[1] = 0.0  # no proposals: not a frame of the spread, no inliers
    with pytest.warns(UserWarning, match="are the proposals in millimetres"):
        result = hybridfit.fit(p / 1000.0, c, budget=300)
    assert result.inliers[1] == 0 and result.failed[1]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert hybridfit.fit(p, c, budget=300).inliers[[0, 2]].min() > 10


@settings(max_examples=40, deadline=None)
@given(shape=st.tuples(st.integers(1, 5), st.integers(1, 8), st.integers(1, 3)), seed=st.integers(0, 2**32 - 1))
def test_the_proposals_spread_is_the_median_distance_of_the_top_proposals_from_their_centre(shape, seed):
    from hybridfit.fitting.frames import proposal_spread

    rng = np.random.default_rng(seed)
    F, Q, K = shape
    proposals = rng.normal(0, 30, (F, Q, K, 3))
    confidences = rng.integers(0, 3, (F, Q, K)).astype(float)  # ties: the first most confident
    used = (confidences > 0).any(axis=(1, 2))
    got = proposal_spread(proposals, confidences)
    if not used.any():
        assert np.isnan(got)
        return
    top = np.take_along_axis(proposals[used], confidences[used].argmax(-1)[..., None, None], axis=2)[:, :, 0]
    assert got == np.median(np.linalg.norm(top - np.median(top, axis=1, keepdims=True), axis=-1))
