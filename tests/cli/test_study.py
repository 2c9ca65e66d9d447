"""`hybridfit study` from the command line."""

from __future__ import annotations

from hybridfit.cli import main
from tests.study.conftest import TINY


def test_quick_study_end_to_end_and_report_only(tmp_path, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    out = tmp_path / "out"
    assert main(["study", str(study), "--quick", "--out", str(out), "--jobs", "2"]) == 0
    assert "4 trials: 0 already complete, 4 run, 0 failed" in capsys.readouterr().out
    report = (out / "report.md").read_text()
    assert "k=3, optimizer_config.schedule=joint" in report and "success_rate.png" in report
    (out / "report.md").unlink()
    assert main(["study", str(study), "--quick", "--out", str(out), "--report-only"]) == 0
    assert (out / "report.md").is_file() and (out / "results.csv").is_file()
    assert main(["study", str(study), "--quick", "--out", str(out)]) == 0
    assert "4 already complete, 0 run" in capsys.readouterr().out


def test_bad_study_file_is_one_line_naming_file_and_field(tmp_path, capsys):
    study = tmp_path / "bad.toml"
    study.write_text(TINY.replace("[base]", '[base]\noptimizer = "nope"'))
    assert main(["study", str(study), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(study) in err and "base.optimizer: unknown optimizer 'nope'" in err


def test_scheduler_needs_dask(tmp_path, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    assert main(["study", str(study), "--out", str(tmp_path / "o"), "--scheduler", "tcp://x:1"]) == 2
    assert "--scheduler needs --executor dask" in capsys.readouterr().err


def test_no_progress_bar_is_written_into_logs_and_times_are_in_ms(tmp_path, capsys):
    import csv

    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    out = tmp_path / "out"
    assert main(["study", str(study), "--quick", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "trial/s" not in err and "it/s" not in err  # stderr is not a terminal here
    with open(out / "results.csv") as fh:
        seconds = {r["variant"]: float(r["time_per_frame_s_mean"]) for r in csv.DictReader(fh)}
    table = [[c.strip() for c in ln.strip("|").split("|")] for ln in (out / "report.md").read_text().splitlines()
             if ln.startswith("| ")]  # (no variant name of this study holds a "|")
    column = table[0].index("time per frame (ms)")
    timed = [row for row in table[2:] if row[column] != "-"]
    assert len(timed) == 4
    for row in timed:
        assert float(row[column]) == round(1000 * seconds[row[0]], 2)
