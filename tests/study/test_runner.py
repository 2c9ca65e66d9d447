"""Running studies: results in SQLite, caching, failures, locks, executors, resume after SIGKILL."""

from __future__ import annotations

import csv
import os
import signal
import sqlite3
import subprocess
import sys
import time

import numpy as np
import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study import load_spec, parse_spec, run_study
from hybridfit.study.report import aggregate
from hybridfit.study.runner import LOCK_NAME
from hybridfit.study.store import Store

from .conftest import TINY, write


def frame_rows(out):
    """Each complete trial's frames, keyed by trial key (times left out)."""
    db = sqlite3.connect(out / "study.db")
    rows = db.execute("SELECT t.key, t.state, f.frame, f.joint_errors, f.objective, f.evaluations, f.failed "
                      "FROM trials t JOIN frames f ON f.trial_id = t.id ORDER BY t.key, f.frame").fetchall()
    db.close()
    return rows


def run(study, out, **kw):
    kw.setdefault("progress", False)
    kw.setdefault("log", lambda m: None)
    return run_study(study, out, **kw)


def test_results_report_and_skip_on_rerun(tiny_file, tmp_path):
    study = load_spec(tiny_file)
    s = run(study, tmp_path / "out")
    assert (s.total, s.ran, s.failed) == (8, 8, 0)
    store = Store(tmp_path / "out" / "study.db")
    done = store.trials("complete")
    assert len([t for t in done if t["method"] == "fit"]) == 8
    assert store.get_meta("schema_version") == 1
    fr = store.frames(done[-1]["id"])
    assert fr["errors"].shape == (4, 21) and np.isfinite(fr["errors"]).all()
    rows = aggregate(store)
    store.close()
    for name in ("report.md", "results.csv", "success_rate.png", "error_vs_k.png", "variants.png", "per_joint.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0, name
    with open(tmp_path / "out" / "results.csv") as fh:
        table = {r["variant"]: r for r in csv.DictReader(fh)}
    assert set(table) == {r["variant"] for r in rows}
    for r in rows:  # the CSV is the database, aggregated
        assert float(table[r["variant"]]["mean_error_mm_mean"]) == pytest.approx(r["mean_error_mm_mean"], rel=1e-5)
        assert float(table[r["variant"]]["success_40mm_mean"]) == pytest.approx(r["success_40mm_mean"], abs=1e-6)
    before = frame_rows(tmp_path / "out")
    again = run(study, tmp_path / "out")
    assert (again.skipped, again.ran) == (8, 0)
    assert frame_rows(tmp_path / "out") == before


def test_failing_trial_is_recorded_and_study_goes_on(tmp_path, monkeypatch):
    """A trial that fails while it runs (here: its fits raise for budget 399) is recorded; the others go on.
    (A budget below the optimiser's minimum is refused before any trial runs: test_limits.py.)"""
    from hybridfit.study import runner

    real = runner.fit

    def fails_at_399(*args, **kwargs):
        if kwargs["budget"] == 399:
            raise HybridfitError("the input of this trial cannot be fitted")
        return real(*args, **kwargs)

    monkeypatch.setattr(runner, "fit", fails_at_399)
    text = TINY.split("[sweep.grid]")[0] + '[sweep.grid]\nbudget = [400, 399]\n'
    s = run(load_spec(write(tmp_path, text)), tmp_path / "out", executor="serial")  # the patch lives in this process
    assert (s.ran, s.failed) == (4, 2)
    store = Store(tmp_path / "out" / "study.db")
    failed = store.trials("failed")
    store.close()
    assert len(failed) == 2 and all("cannot be fitted" in t["error"] for t in failed)
    assert "cannot be fitted" in (tmp_path / "out" / "report.md").read_text()


def test_shared_steps_are_cached(tmp_path, monkeypatch):
    """A second study on the same data and cache neither retrains the forest nor re-proposes."""
    import hybridfit.forest
    from hybridfit.fitting.estimator import HybridEstimator

    calls = {"train": 0, "propose": 0}
    train, propose = hybridfit.forest.train_forest_dataset, HybridEstimator.propose_dataset

    def counted_train(*a, **k):
        calls["train"] += 1
        return train(*a, **k)

    def counted_propose(*a, **k):
        calls["propose"] += 1
        return propose(*a, **k)

    monkeypatch.setattr(hybridfit.forest, "train_forest_dataset", counted_train)
    monkeypatch.setattr(HybridEstimator, "propose_dataset", counted_propose)
    base = {
        "name": "depth", "seeds": 1,
        "data": {"kind": "synthetic-depth",
                 "train": {"articulations_deg": {"thumb": [[-10, -20, 5, 0], [40, 30, 30, 20]],
                                                 "index": [[0, 0, 0, 0], [60, 0, 70, 40]],
                                                 "middle": [[0, 0, 0, 0]], "ring": [[0, 0, 0, 0]],
                                                 "little": [[0, 0, 0, 0]]},
                           "viewpoints_deg": [[0, 0, 0], [0, 0, 30]]},
                 "test": {"frames": 3},
                 "forest": {"n_trees": 1, "max_depth": 8, "min_samples": 10, "pixels_per_frame": 100,
                            "n_features": 20, "n_thresholds": 5, "node_subsample": 200}},
        "base": {"budget": 300, "proposal_set": 50},
        "sweep": {"grid": {"k": [1, 2]}},
    }
    cache = tmp_path / "cache"
    run(parse_spec(base), tmp_path / "a", cache_dir=cache)
    assert calls == {"train": 1, "propose": 2}
    other = {**base, "sweep": {"grid": {"optimizer_config.schedule": ["joint", "stepwise"], "k": [1, 2]}}}
    s = run(parse_spec(other), tmp_path / "b", cache_dir=cache)
    assert calls == {"train": 1, "propose": 2} and s.failed == 0
    assert (tmp_path / "b" / "error_vs_k.png").is_file()
    # the same data as folders: a data set and a trained forest named in the study file
    test = next(p for p in (cache / "test-data").iterdir() if p.is_dir())
    forest = next((cache / "forest").glob("*.npz"))
    folders = {**base, "data": {"kind": "dataset", "test": str(test), "forest_file": str(forest), "frames": 2}}
    s = run(parse_spec(folders), tmp_path / "c", cache_dir=cache)
    assert (s.ran, s.failed) == (2, 0) and calls["train"] == 1


def test_concurrent_run_is_refused_and_stale_lock_replaced(tiny_file, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / LOCK_NAME).write_text(f"{os.getppid()} {os.uname().nodename}\n")  # a live process
    with pytest.raises(HybridfitError, match="another study run"):
        run(load_spec(tiny_file), out)
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (out / LOCK_NAME).write_text(f"{dead.pid} {os.uname().nodename}\n")
    assert run(load_spec(tiny_file), out).failed == 0
    assert not (out / LOCK_NAME).exists()


@pytest.mark.parametrize("executor", ["processes", "dask"])
def test_parallel_executors_match_serial(tiny_file, tmp_path, executor):
    study = load_spec(tiny_file, quick=True)
    run(study, tmp_path / "serial", executor="serial", report=False)
    s = run(study, tmp_path / executor, executor=executor, jobs=2, dask_processes=False, report=False)
    assert (s.ran, s.failed) == (4, 0)
    assert frame_rows(tmp_path / executor) == frame_rows(tmp_path / "serial")


RESUMABLE = """
name = "resume"
seeds = [1, 2, 3, 4]
[data]
kind = "synthetic-proposals"
frames = 20
[base]
budget = 3000
[sweep.grid]
"optimizer_config.root_share" = [0.2, 0.3, 0.4, 0.5]
"""


def test_resume_after_sigkill_gives_the_uninterrupted_results(tmp_path):
    path = write(tmp_path, RESUMABLE)
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "hybridfit", "study", str(path), "--out", str(out), "--executor", "serial"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    done = 0
    while time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
        try:
            db = sqlite3.connect(out / "study.db", timeout=1)
            done = db.execute("SELECT count(*) FROM trials WHERE state = 'complete' AND method = 'fit'").fetchone()[0]
            db.close()
        except sqlite3.Error:
            continue
        if done >= 2:
            break
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert done >= 2
    killed = Store(out / "study.db")
    states = [t["state"] for t in killed.trials() if t["method"] == "fit"]
    killed.close()
    assert states.count("complete") < 16, "the run finished before it was killed"
    s = run(load_spec(path), out)  # resume: the stale lock is replaced, finished trials kept
    assert s.skipped >= 2 and s.skipped + s.ran == 16 and s.failed == 0
    run(load_spec(path), tmp_path / "clean")
    assert frame_rows(out) == frame_rows(tmp_path / "clean")


def test_report_shows_only_the_current_study_file(tiny_file, tmp_path):
    run(load_spec(tiny_file), tmp_path / "out")
    smaller = write(tmp_path, TINY.replace("k = [1, 3]", "k = [3]"), "smaller.toml")
    s = run(load_spec(smaller), tmp_path / "out")
    assert (s.total, s.skipped, s.ran) == (4, 4, 0)
    store = Store(tmp_path / "out" / "study.db")
    names = {r["variant"] for r in aggregate(store) if r["method"] == "fit"}
    store.close()
    assert names == {"k=3, optimizer_config.schedule=stepwise", "k=3, optimizer_config.schedule=joint"}


def test_a_bug_stops_the_study_unless_asked_to_keep_going(tmp_path, monkeypatch):
    """Bad input is a failed trial (above); a bug (here: a plugin raising ZeroDivisionError) is
    recorded too but stops the study, the finished trials kept, unless keep_going."""
    from hybridfit.errors import PluginError
    from hybridfit.study import runner

    real = runner.run_trial
    calls = []

    def buggy(settings, *rest):
        calls.append(settings["budget"])
        if settings["budget"] == 300:
            raise ZeroDivisionError("a plugin's bug")
        return real(settings, *rest)

    monkeypatch.setattr(runner, "run_trial", buggy)
    text = TINY.split("[sweep.grid]")[0] + '[sweep.grid]\nbudget = [400, 300]\n'
    with pytest.raises(PluginError, match="ZeroDivisionError.*the study stops"):
        run(load_spec(write(tmp_path, text)), tmp_path / "stop", executor="serial")
    store = Store(tmp_path / "stop" / "study.db")
    assert len(store.trials("failed")) == 1 and len(calls) < 4
    store.close()
    s = run(load_spec(write(tmp_path, text)), tmp_path / "go", executor="serial", keep_going=True)
    assert (s.ran, s.failed) == (4, 2)
