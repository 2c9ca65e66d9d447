"""Study results never silently go stale or get mislabelled (issue #11): keys know the code
versions and the data's content, labels come from the current study file, frame seeds from
the frame's index, killed runs' temporary files are cleaned, only used frames are rendered."""

from __future__ import annotations

import os

import numpy as np
import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study import cache as cache_module
from hybridfit.study import data as data_module
from hybridfit.study import load_spec, parse_spec, run_study
from hybridfit.study.cache import Cache
from hybridfit.study.data import StudyData, file_hash
from hybridfit.study.plots import _series
from hybridfit.study.report import aggregate
from hybridfit.study.runner import run_trial
from hybridfit.study.store import Store

from .conftest import TINY, write


def run(study, out):
    return run_study(study, out, progress=False, log=lambda m: None, report=False)


def test_an_upgrade_recomputes_trials_and_cache_entries(tiny_file, tmp_path, monkeypatch):
    study = load_spec(tiny_file, quick=True)
    assert run(study, tmp_path / "out").ran == 4
    assert run(study, tmp_path / "out").ran == 0  # same code: every trial reused
    newer = {**cache_module.code_versions(), "hybridfit": "99.0"}
    monkeypatch.setattr(cache_module, "code_versions", lambda: newer)
    monkeypatch.setattr(data_module, "code_versions", lambda: newer)
    s = run(study, tmp_path / "out")
    assert s.ran == 4 and s.skipped == 0
    entries = list((tmp_path / "out" / "cache" / "synthetic-proposals").glob("*.npz"))
    assert len(entries) == 2  # the data was generated again, by the "new" code


def test_code_versions_name_hybridfit_and_the_plugin_distributions():
    from importlib import metadata

    versions = cache_module.code_versions()
    assert versions["hybridfit"].startswith(metadata.version("hybridfit") + "+src.") and all(versions.values())


def test_an_edited_source_file_changes_the_source_hash(tmp_path, monkeypatch):
    package = tmp_path / "edited_plugin_package"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "model.py").write_text("SCALE = 1.0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    before = cache_module.source_hash(["edited_plugin_package"])
    assert cache_module.source_hash(["edited_plugin_package"]) == before
    (package / "model.py").write_text("SCALE = 1.1\n")
    assert cache_module.source_hash(["edited_plugin_package"]) != before


def test_a_folder_hash_covers_its_depth_images(tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    (folder / "meta.json").write_text("{}")
    (folder / "labels.npz").write_bytes(b"labels")
    (folder / "depth").mkdir()
    (folder / "depth" / "0000.png").write_bytes(b"one")
    before = file_hash(folder)
    (folder / "depth" / "0000.png").write_bytes(b"two")
    assert file_hash(folder) != before


def test_labels_come_from_the_current_study_file(tmp_path):
    first = write(tmp_path, TINY.replace('"optimizer_config.schedule" = ["stepwise", "joint"]', "")
                  + '\n[[sweep.variants]]\nname = "old name"\n', "a.toml")
    second = write(tmp_path, TINY.replace('"optimizer_config.schedule" = ["stepwise", "joint"]', "")
                   + '\n[[sweep.variants]]\nname = "new name"\n', "b.toml")
    out = tmp_path / "out"
    run(load_spec(first), out)
    s = run(load_spec(second), out)
    assert s.ran == 0  # the same trials, reused ...
    store = Store(out / "study.db")
    names = {r["variant"] for r in aggregate(store) if r["method"] == "fit"}
    store.close()
    assert names == {"new name, k=1", "new name, k=3"}  # ... under this file's names


def test_frame_seeds_do_not_shift_when_earlier_frames_are_empty(frames):
    data = {k: frames[k][:3] for k in ("proposals", "confidences", "ground_truth")}
    data["joint_names"] = frames["joint_names"]
    settings = {"model": "hand26", "objective": "clamped-confidence", "objective_config": {},
                "optimizer": "stepwise-pso", "optimizer_config": {}, "budget": 400, "search_radius_mm": 60.0}
    full = run_trial(settings, {}, 5, {**data, "empty": np.zeros(3, bool)})
    emptied = {**data, "confidences": data["confidences"].copy(), "empty": np.array([True, False, False])}
    emptied["confidences"][0] = 0.0
    part = run_trial(settings, {}, 5, emptied)
    assert np.isnan(part["errors"][0]).all() and part["messages"][0] == "no foreground pixels"
    np.testing.assert_array_equal(part["errors"][1:], full["errors"][1:])


def test_quick_validates_what_quick_overrides(tmp_path):
    path = write(tmp_path, TINY.replace("budget = 400", "budget = -5").replace("seeds = 1", "seeds = 1\nbase = { budget = 400 }"))
    parse_spec({**__import__("tomllib").loads(path.read_text()), "base": {"budget": 400}})  # fine when overridden
    with pytest.raises(HybridfitError, match=r"base\.budget"):
        load_spec(path, quick=True)


def test_only_the_training_frames_used_are_rendered(tmp_path):
    study = parse_spec({"name": "s", "data": {"kind": "synthetic-depth", "train_subset": 3,
                                               "test": {"frames": 2}}}, root=tmp_path)
    data = StudyData(study.data, Cache(tmp_path / "cache"), log=lambda m: None)
    _, train = data._datasets()
    from hybridfit.datasets.folder import load_dataset
    from hybridfit.synthetic.poses import grid_poses

    ds = load_dataset(train)
    expected = data._train_subset()
    assert len(ds) == 3 and len(expected) == 3
    np.testing.assert_allclose(ds.params, grid_poses(study.data.train)[expected])


def test_budget_plot_legend_uses_variant_names():
    rows = [{"variant": f"{name}, budget={b}", "settings": {"budget": b, "optimizer_config": {"schedule": s}},
             "method": "fit"} for name, s in (("stepwise", "stepwise"), ("joint PSO", "joint")) for b in (400, 800)]
    assert sorted(_series(rows, "budget")) == ["joint PSO", "stepwise"]


def test_a_binary_results_file_in_a_study_is_named(tmp_path):
    binary = tmp_path / "predictions.txt"
    binary.write_bytes(bytes(range(256)) * 4)
    study = parse_spec({"name": "b", "data": {"kind": "proposals", "file": "predictions.txt", "dataset": "icvl",
                                               "ground_truth": "predictions.txt"}}, root=tmp_path)
    data = StudyData(study.data, Cache(tmp_path / "cache"), log=lambda m: None)
    with pytest.raises(HybridfitError, match="predictions.txt: not a text file"):
        data.proposals(1, 0)
