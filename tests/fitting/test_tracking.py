"""Tracking mode: each frame starts from the previous fit; a lost fit re-initialises from proposals."""

from __future__ import annotations

import json

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.synthetic.poses import sequence_poses
from hybridfit.fitting.tracking import track

MODEL = hybridfit.create("model", "hand26")
POSES = sequence_poses({"frames": 5, "seed": 4})
TRUTH = MODEL.forward(POSES)
CONF = np.ones(TRUTH.shape[:2] + (1,))


def run(proposals, **kw):
    return track(proposals, CONF, optimizer="pso", budget=120, seed=3, **kw)


def test_frames_start_from_the_previous_fit_and_runs_repeat_bit_for_bit():
    a = run(TRUTH[:, :, None], first_params=POSES[0])
    b = run(TRUTH[:, :, None], first_params=POSES[0])
    np.testing.assert_array_equal(a.params, b.params)
    assert not a.started_from_proposals.any() and not a.lost.any() and not a.failed.any()
    assert (a.evaluations == 120).all()
    no_start = run(TRUTH[:, :, None])
    assert no_start.started_from_proposals.tolist() == [True, False, False, False, False]


@pytest.mark.parametrize("schedule", ["pso", "default"])
@pytest.mark.parametrize("on_lost, restarted", [("reinit", True), ("continue", False)])
def test_a_lost_fit_reinitialises_from_proposals_only_under_reinit(on_lost, restarted, schedule):
    """PSO alone, and the default schedule, whose local stage (like every stage) stays in the
    search box: it cannot carry a lost fit onto the far proposals."""
    props = TRUTH[:, :, None].copy()
    props[2:] += np.array([400.0, 0.0, 0.0])  # the hand jumps far beyond the search radius
    if schedule == "pso":
        res = run(props, first_params=POSES[0], settings={"on_lost": on_lost})
    else:
        res = track(props, CONF, budget=600, seed=3, first_params=POSES[0], settings={"on_lost": on_lost})
        assert json.loads(res.schedule)[0]["stages"][-1]["name"] == "local" and (res.evaluations == 600).all()
    assert res.lost[2] and not res.lost[:2].any()
    assert bool(res.started_from_proposals[3]) is restarted
    assert bool(res.lost[3]) is not restarted


def test_bad_first_params_is_a_clear_error():
    with pytest.raises(HybridfitError, match="first_params"):
        run(TRUTH[:, :, None], first_params=POSES[0][:5])


def test_errors_that_would_fail_every_frame_are_raised_at_once():
    with pytest.raises(HybridfitError, match="budget 3 is too small"):
        track(TRUTH[:, :, None], CONF, optimizer="pso", budget=3)
    with pytest.raises(HybridfitError, match="depth"):
        track(TRUTH[:, :, None], CONF, objective="rendered-depth", optimizer="pso", budget=120)
