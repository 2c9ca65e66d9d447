"""hybridfit.fit over frames: shapes, accuracy, determinism across jobs, failures, mapping."""

from __future__ import annotations

import numpy as np
import pytest

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
