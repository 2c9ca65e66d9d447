"""Studies with tracking trials and objectives that observe depth."""

from __future__ import annotations

import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study import parse_spec, run_study
from hybridfit.study.spec import TrialSettings
from hybridfit.study.store import Store

STUDY = {
    "name": "tracking", "seed": 1, "seeds": 1,
    "data": {"kind": "synthetic-proposals", "frames": 6, "k": 3},
    "base": {"budget": 200, "optimizer": "pso"},
    "baselines": [],
    "sweep": {"variants": [
        {"name": "independent"},
        {"name": "tracked", "tracking": {"on_lost": "continue"}},
        {"name": "tracked, every 2nd frame", "tracking": {"frame_step": 2}},
    ]},
}


def test_trials_without_tracking_keep_their_keys():
    assert "tracking" not in TrialSettings().as_dict()
    assert TrialSettings(tracking={"frame_step": 3}).as_dict()["tracking"]["frame_step"] == 3


def test_tracking_trials_run_and_frame_step_drops_frames(tmp_path):
    run_study(parse_spec(STUDY), tmp_path, progress=False, log=lambda m: None, report=False)
    store = Store(tmp_path / "study.db")
    try:
        trials = {t["variant"]: t for t in store.trials("complete")}
        frames = {name: store.frames(t["id"]) for name, t in trials.items()}
    finally:
        store.close()
    assert len(frames["independent"]["errors"]) == len(frames["tracked"]["errors"]) == 6
    assert len(frames["tracked, every 2nd frame"]["errors"]) == 3
    assert (frames["tracked"]["evaluations"] == 200).all()


def test_bad_tracking_setting_names_the_field():
    bad = {**STUDY, "sweep": {"variants": [{"tracking": {"on_lost": "panic"}}]}}
    with pytest.raises(HybridfitError, match="tracking.on_lost"):
        parse_spec(bad)


def test_depth_objective_on_data_without_depth_fails_the_trial_clearly(tmp_path):
    study = {**STUDY, "sweep": {"variants": [{"objective": "rendered-depth"}]}}
    with pytest.raises(HybridfitError, match="no depth images"):
        run_study(parse_spec(study), tmp_path, progress=False, log=lambda m: None, report=False)
