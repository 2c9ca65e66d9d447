"""The Optuna mirror of a running study: read back through Optuna's own API, and served by a
real optuna-dashboard."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study import parse_spec
from hybridfit.study.expand import expand, trials

from .conftest import TINY

optuna = pytest.importorskip("optuna", reason="optuna is not installed: pip install -e '.[optuna]'")
from hybridfit.study.live import OptunaMirror, metrics_of  # noqa: E402


def study_trials(tmp_path, seeds="2"):
    study = parse_spec(__import__("tomllib").loads(TINY.replace("seeds = 2", f"seeds = {seeds}")), root=tmp_path)
    return study, trials(study, expand(study), "data-key")


def result(mean: float, F: int = 3, J: int = 21) -> dict:
    errors = np.full((F, J), mean)
    errors[0, 0] += 3.0  # not all equal: the mean is the mean of all of them
    return {"errors": errors, "objective": np.full(F, -1.5), "evaluations": np.full(F, 400), "failed": np.zeros(F, bool),
            "messages": {}, "time_per_frame": 0.002, "joint_names": [f"j{i}" for i in range(J)]}


def test_each_finished_trial_is_read_back_with_its_settings_value_and_metrics(tmp_path):
    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    study, ts = study_trials(tmp_path)
    mirror = OptunaMirror(url, study.name, ts)
    for i, t in enumerate(ts[:3]):
        mirror.add(t, metrics_of(result(10.0 + i)))
    mirror.add(ts[3], None, error="a plugin bug")
    back = optuna.load_study(study_name="tiny", storage=url)
    done = back.get_trials(states=(optuna.trial.TrialState.COMPLETE,))
    assert len(done) == 3 and len(back.trials) == 4 and back.direction == optuna.study.StudyDirection.MINIMIZE
    first = done[0]
    assert first.params == {"k": ts[0].variant.overrides["k"], "optimizer_config.schedule": "stepwise",
                            "variant": ts[0].variant.name, "seed": ts[0].seed}
    assert first.value == pytest.approx(metrics_of(result(10.0))["mean_error_mm"]) and first.value > 10.0
    assert first.user_attrs["hybridfit_key"] == ts[0].key and first.user_attrs["evaluations"] == 400
    assert first.user_attrs["time_per_frame_s"] == pytest.approx(0.002)
    failed = back.get_trials(states=(optuna.trial.TrialState.FAIL,))
    assert failed[0].user_attrs["error"] == "a plugin bug" and failed[0].value is None
    assert back.best_trial.params["variant"] == ts[0].variant.name


def test_a_resumed_run_records_each_trial_once(tmp_path):
    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    study, ts = study_trials(tmp_path)
    OptunaMirror(url, study.name, ts).add(ts[0], metrics_of(result(5.0)))
    again = OptunaMirror(url, study.name, ts)
    again.add(ts[0], metrics_of(result(5.0)))
    again.add(ts[1], metrics_of(result(6.0)))
    assert len(optuna.load_study(study_name="tiny", storage=url).trials) == 2


def test_the_largest_documented_seed_is_recorded_exactly(tmp_path):
    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    study, ts = study_trials(tmp_path, seeds="[18446744073709551615, 3]")
    mirror = OptunaMirror(url, study.name, ts)
    big = next(t for t in ts if t.seed == 2**64 - 1)
    mirror.add(big, metrics_of(result(5.0)))
    (back,) = optuna.load_study(study_name="tiny", storage=url).trials
    assert back.params["seed"] == str(2**64 - 1)


def test_an_unusable_storage_is_one_line(tmp_path):
    study, ts = study_trials(tmp_path)
    with pytest.raises(HybridfitError, match="--optuna-storage nosuch://x: cannot open the Optuna storage"):
        OptunaMirror("nosuch://x", study.name, ts)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


DASHBOARD = shutil.which("optuna-dashboard", path=str(Path(sys.executable).parent)) or shutil.which("optuna-dashboard")


@pytest.mark.skipif(DASHBOARD is None, reason="optuna-dashboard is not installed: pip install optuna-dashboard")
def test_a_real_optuna_dashboard_serves_the_study_while_it_runs(tmp_path):
    url = f"sqlite:///{tmp_path / 'optuna.db'}"
    study, ts = study_trials(tmp_path)
    mirror = OptunaMirror(url, study.name, ts)
    mirror.add(ts[0], metrics_of(result(7.0)))
    port = _free_port()
    server = subprocess.Popen([DASHBOARD, url, "--host", "127.0.0.1", "--port", str(port)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        def get(path):
            for _ in range(100):
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
                        return json.loads(r.read())
                except OSError:
                    if server.poll() is not None:
                        pytest.fail(server.stderr.read().decode())
                    time.sleep(0.2)
            pytest.fail("optuna-dashboard did not answer")

        (listed,) = get("/api/studies")["study_summaries"]
        assert listed["study_name"] == "tiny"
        sid = listed["study_id"]
        assert len(get(f"/api/studies/{sid}")["trials"]) == 1
        mirror.add(ts[1], metrics_of(result(8.0)))  # a trial finishes while the dashboard runs
        for _ in range(100):  # the dashboard refreshes what it serves every few seconds
            shown = get(f"/api/studies/{sid}")["trials"]
            if len(shown) == 2:
                break
            time.sleep(0.3)
        assert [t["values"][0] for t in shown] == pytest.approx([metrics_of(result(v))["mean_error_mm"] for v in (7, 8)])
    finally:
        server.terminate()
        server.wait(10)


def test_a_study_run_with_optuna_storage_records_every_trial_and_a_resume_adds_none(tmp_path, tiny_file, capsys):
    from hybridfit.cli import main
    from hybridfit.study.report import aggregate
    from hybridfit.study.store import Store

    url = f"sqlite:///{tmp_path / 'live.db'}"
    args = ["study", str(tiny_file), "--quick", "--out", str(tmp_path / "o")]
    assert main([*args, "--optuna-storage", url]) == 0
    back = optuna.load_study(study_name="tiny", storage=url)
    store = Store(tmp_path / "o" / "study.db")
    stored = {row["key"]: row for row in store.trials("complete") if row["variant_index"] >= 0}  # baselines aside
    assert len(back.trials) == len(stored) == 4  # 2 k x 2 schedules x 1 seed (--quick)
    rows = {r["variant"]: r for r in aggregate(store)}
    for t in back.trials:
        assert t.user_attrs["hybridfit_key"] in stored
        assert t.value == pytest.approx(rows[t.params["variant"]]["mean_error_mm_mean"])  # one seed: the report's mean
    store.close()
    assert main([*args, "--optuna-storage", url]) == 0  # nothing left to run, nothing added twice
    assert len(optuna.load_study(study_name="tiny", storage=url).trials) == 4


def test_an_earlier_runs_trials_are_added_when_the_mirror_starts(tmp_path, tiny_file):
    from hybridfit.cli import main

    args = ["study", str(tiny_file), "--quick", "--out", str(tmp_path / "o")]
    assert main(args) == 0  # run without a mirror
    url = f"sqlite:///{tmp_path / 'live.db'}"
    assert main([*args, "--optuna-storage", url]) == 0
    assert len(optuna.load_study(study_name="tiny", storage=url).get_trials(
        states=(optuna.trial.TrialState.COMPLETE,))) == 4


def test_a_storage_that_fails_mid_run_is_reported_once_and_the_study_finishes(tmp_path):
    study, ts = study_trials(tmp_path)
    logged = []
    mirror = OptunaMirror(f"sqlite:///{tmp_path / 'optuna.db'}", study.name, ts, log=logged.append)

    def gone(*a, **k):
        raise RuntimeError("database is locked")

    mirror.study.add_trial = gone
    for t in ts[:3]:
        mirror.finished(t, result(5.0), None)
    assert len(logged) == 1 and "recording trials stopped (RuntimeError: database is locked)" in logged[0]
