"""`hybridfit study` from the command line."""

from __future__ import annotations

import hashlib
import json
import shutil

import pytest

from hybridfit.cli import main
from hybridfit.text import markdown
from tests.study.conftest import TINY, old_database


def test_quick_study_end_to_end_and_report_only(tmp_path, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    out = tmp_path / "out"
    assert main(["study", str(study), "--quick", "--out", str(out), "--jobs", "2"]) == 0
    assert "4 trials: 0 already complete, 4 run, 0 failed" in capsys.readouterr().out
    report = (out / "report.md").read_text()
    assert markdown("k=3, optimizer_config.schedule=joint") in report and "success_rate.png" in report
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
        seconds = {markdown(r["variant"]): float(r["time_per_frame_s_mean"]) for r in csv.DictReader(fh)}  # as shown
    table = [[c.strip() for c in ln.strip("|").split("|")] for ln in (out / "report.md").read_text().splitlines()
             if ln.startswith("| ")]  # (no variant name of this study holds a "|")
    column = table[0].index("time per frame (ms)")
    timed = [row for row in table[2:] if row[column] != "-"]
    assert len(timed) == 4
    for row in timed:
        assert float(row[column]) == round(1000 * seconds[row[0]], 2)


# ------------------------------------------------------------------ the user's files and planted links


@pytest.fixture(scope="module")
def finished_study(tmp_path_factory):
    """A tiny study file and the folder of its finished --quick run (copy it before changing it)."""
    root = tmp_path_factory.mktemp("finished")
    study = root / "tiny.toml"
    study.write_text(TINY)
    assert main(["study", str(study), "--quick", "--out", str(root / "out")]) == 0
    return study, root / "out"


def test_the_record_names_the_command_that_ran_the_study(finished_study):
    study, done = finished_study
    record = json.loads((done / "results.json").read_text())
    assert record["command"] == f"hybridfit study {study} --quick" and record["tables"]["results"]["rows"]


def test_report_follows_no_link_planted_at_a_temporary_or_final_name(finished_study, tmp_path):
    study, done = finished_study
    d = tmp_path / "d"
    shutil.copytree(done, d)
    victims = {}
    for name in ("report.md.tmp", "results.csv.tmp", "report.md", "results.csv", "success_rate.png",
                 "variants.png", "per_joint.png"):
        victims[name] = tmp_path / f"victim-{name}"
        victims[name].write_text("precious\n")
        (d / name).unlink(missing_ok=True)
        (d / name).symlink_to(victims[name])
    assert main(["study", str(study), "--quick", "--out", str(d), "--report-only"]) == 0
    for name, victim in victims.items():
        assert victim.read_text() == "precious\n", name
    for name in ("report.md", "results.csv", "success_rate.png", "variants.png", "per_joint.png"):
        assert not (d / name).is_symlink() and (d / name).stat().st_size > 100, name  # the link itself replaced
    assert (d / "report.md.tmp").is_symlink() and (d / "results.csv.tmp").is_symlink()  # left alone
    assert not [p.name for p in d.iterdir() if p.name.startswith(".")]  # no temporary file left


USERS_FILES = {"results.csv": "sample,value\n1,2\n", "report.md": "# my notes\n", "figure.png": "not really a png"}


def test_a_folder_that_is_not_a_studys_is_refused_and_left_alone(tmp_path, capsys):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    mine = tmp_path / "myproj"
    mine.mkdir()
    for name, text in USERS_FILES.items():
        (mine / name).write_text(text)
    for extra in ([], ["--report-only"]):
        assert main(["study", str(study), "--quick", "--out", str(mine), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(mine) in err and ("not a study's folder" in err or "no study.db" in err)
        assert sorted(p.name for p in mine.iterdir()) == sorted(USERS_FILES)  # no study.db, no lock: nothing
        assert all((mine / name).read_text() == text for name, text in USERS_FILES.items())
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["study", str(study), "--quick", "--out", str(empty)]) == 0  # an empty folder is fine


def digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize("kind", ["unversioned", "stamped", "no-meta"])
def test_a_study_database_from_before_schema_versioning_is_refused_untouched(tmp_path, capsys, kind):
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    out = tmp_path / "old"
    out.mkdir()
    old_database(out / "study.db", stamped=kind == "stamped", meta=kind != "no-meta")
    before = digest(out)
    for extra in ([], ["--report-only"]):
        assert main(["study", str(study), "--quick", "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and str(out / "study.db") in err and "before schema versioning" in err, err
        assert digest(out) == before  # not stamped, not switched to WAL, nothing added
