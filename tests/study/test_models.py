"""A study with the model as a sweep dimension: each model gets its own calibration (cached
per model) and the dataset's derived points, whichever model it is."""

from __future__ import annotations

import hybridfit
from hybridfit.study import parse_spec
from hybridfit.study.cache import Cache
from hybridfit.study.data import StudyData
from hybridfit.study.spec import TrialSettings

from ..cli._icvl_files import write_results


def test_each_model_is_calibrated_on_its_own(tmp_path):
    gt, _ = write_results(tmp_path, frames=5, noise=2.0)
    study = parse_spec({"name": "m", "data": {"kind": "proposals", "file": gt.name, "dataset": "icvl",
                                               "ground_truth": gt.name,
                                               "calibrate": {"frames": "0:4", "rounds": 1, "budget": 200}}},
                       root=tmp_path)
    logged = []
    cache = Cache(tmp_path / "cache")
    data = StudyData(study.data, cache, log=logged.append)
    configs = {m: data.model_config(TrialSettings(model=m)) for m in ("hand26", "hand27")}
    assert sum("calibrating hand26" in line for line in logged) == 1
    assert sum("calibrating hand27" in line for line in logged) == 1
    assert [kind for kind, _ in cache.made].count("calibration") == 2
    for m, config in configs.items():
        model = hybridfit.create("model", m, config)
        assert "icvl_palm" in model.derived_points and len(config["bone_lengths"]) == 15
    again = StudyData(study.data, Cache(tmp_path / "cache"), log=logged.append)
    assert again.model_config(TrialSettings(model="hand27")) == configs["hand27"]  # from the cache
    assert sum("calibrating" in line for line in logged) == 2
