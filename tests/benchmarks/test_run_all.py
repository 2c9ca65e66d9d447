"""run_all.py's bookkeeping on a fake list of benchmarks: each runs in turn, one failing is
recorded and the rest still run, the exit code says so, --quick writes elsewhere than the
committed records, and the page is rendered at the end. (The real benchmarks are not run.)"""

from __future__ import annotations

import json
import sys

import pytest

import run_all
from _util import RESULTS
from run_all import Job


@pytest.fixture
def scripts(tmp_path):
    """Three fake benchmark scripts: two write their record, one fails."""
    writes = ("import json, sys\n"
              "path = sys.argv[sys.argv.index('--json') + 1]\n"
              "json.dump({'version': '0', 'machine': {'description': 'fake'}, 'command': 'fake', 'tables': {},\n"
              "           'args': sys.argv[1:sys.argv.index('--json')]}, open(path, 'w'))\n")
    (tmp_path / "bench_one.py").write_text(writes)
    (tmp_path / "bench_two.py").write_text("import sys\nprint('broken')\nsys.exit(3)\n")
    (tmp_path / "bench_three.py").write_text(writes)
    return [Job(name, ((str(tmp_path / f"bench_{name}.py"), "--full"),), ((str(tmp_path / f"bench_{name}.py"),
                                                                          "--tiny"),))
            for name in ("one", "two", "three")]


def test_a_failing_job_is_recorded_the_rest_run_and_the_exit_code_says_so(scripts, tmp_path, capsys):
    out = tmp_path / "quick"
    assert run_all.main(["--quick", "--out", str(out)], jobs=scripts) == 1
    captured = capsys.readouterr()
    assert "[2/3] two: FAILED (exit 3)" in captured.out and "[3/3] three: done" in captured.out
    assert "1 of 3 jobs failed: two (exit 3)" in captured.err
    for name in ("one", "three"):
        assert json.loads((out / "benchmarks" / f"{name}.json").read_text())["args"] == ["--tiny"]
    assert not (out / "benchmarks" / "two.json").exists()
    assert (out / "results.md").read_text().startswith("# Results")  # the page, rendered from the quick records


def test_only_runs_the_jobs_named_and_all_succeeding_exits_0(scripts, tmp_path, capsys):
    out = tmp_path / "quick"
    assert run_all.main(["--quick", "--out", str(out), "--only", "three"], jobs=scripts) == 0
    assert [p.name for p in (out / "benchmarks").iterdir()] == ["three.json"]
    assert "all 1 jobs done" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--only", "nope"], ["--out", "somewhere"]])
def test_bad_arguments_are_refused(scripts, argv, capsys):
    with pytest.raises(SystemExit) as exit_:
        run_all.main(argv, jobs=scripts)
    assert exit_.value.code == 2


def test_list_prints_each_job_and_its_command(scripts, capsys):
    assert run_all.main(["--list"], jobs=scripts) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in lines] == ["one", "two", "three"]
    assert lines[0].endswith("bench_one.py --full")


def test_the_committed_jobs_write_the_committed_records():
    """Every benchmark script has a job, every study file too; studies run with --studies only;
    each job's record is the one its script writes by default, or says where."""
    names = {j.name for j in run_all.JOBS}
    scripts = {p.stem.removeprefix("bench_") for p in RESULTS.parent.glob("bench_*.py")}
    assert scripts <= names
    assert {p.stem for p in (RESULTS.parents[1] / "studies").glob("*.toml")} <= {j.name for j in run_all.JOBS if j.study}
    tuning = next(j for j in run_all.JOBS if j.name == "strong_tuning")
    assert run_all.command(tuning).endswith("--json benchmarks/results/strong_tuning.json")
    assert "--json" not in run_all.command(next(j for j in run_all.JOBS if j.name == "strong"))


def test_a_study_job_keeps_the_studys_results_json(tmp_path, monkeypatch):
    calls = []

    def fake_run(argv, **kw):
        calls.append(argv)
        out = tmp_path / "work" / "tiny"
        out.mkdir(parents=True)
        (out / "results.json").write_text('{"version": "0"}')
        return type("Done", (), {"returncode": 0})()

    monkeypatch.setattr(run_all.subprocess, "run", fake_run)
    job = run_all.study(tmp_path / "tiny.toml")
    record = tmp_path / "studies" / "tiny.json"
    assert run_all.run_job(job, record, tmp_path / "work", quick=True) == 0
    assert calls[0][:4] == [sys.executable, "-m", "hybridfit", "study"] and "--quick" in calls[0]
    assert record.read_text() == '{"version": "0"}'


def test_a_full_run_starts_from_numba_caches_of_the_current_source(tmp_path, monkeypatch):
    """numba's cache files in the checkout's packages are deleted (a kernel inlining another
    module's function is not re-compiled when only that module changed); sources stay."""
    kept = [tmp_path / "hybridfit" / "kernels.py", tmp_path / "plugins" / "notes.txt"]
    gone = [tmp_path / "hybridfit" / "__pycache__" / "kernels.f-1.py311.nbi",
            tmp_path / "plugins" / "optimizers" / "__pycache__" / "pso.f-2.py311.1.nbc"]
    for f in kept + gone:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text("x")
    monkeypatch.setattr(run_all, "REPO", tmp_path)
    assert run_all.clear_numba_caches() == 2
    assert all(f.exists() for f in kept) and not any(f.exists() for f in gone)
