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
