"""The report's record, results.json: what the results page is rendered from (the report's
table as shown, every variant's metrics, and the version, machine, date and command of the
run that measured them)."""

from __future__ import annotations

import csv
import json

import hybridfit
from hybridfit.study import load_spec, run_study, write_report


def test_results_json_is_the_reports_table_with_the_run_that_measured_it(tiny_file, tmp_path):
    out = tmp_path / "out"
    study = load_spec(tiny_file, quick=True)
    run_study(study, out, progress=False, log=lambda m: None, command="hybridfit study tiny.toml --quick")
    record = json.loads((out / "results.json").read_text())
    assert record["name"] == "tiny" and record["version"] == hybridfit.__version__
    assert record["command"] == "hybridfit study tiny.toml --quick" and len(record["date"]) == 10
    assert {"cpu", "cores", "python", "numpy", "numba"} <= set(record["machine"])
    table = record["tables"]["results"]
    shown = [line for line in (out / "report.md").read_text().splitlines() if line.startswith("| ")]
    assert shown[0] == "| " + " | ".join(table["columns"]) + " |"
    assert shown[1].startswith("| ---") and shown[2:] == ["| " + " | ".join(row) + " |" for row in table["rows"]]
    with open(out / "results.csv") as fh:
        csv_rows = list(csv.DictReader(fh))
    assert [v["variant"] for v in record["variants"]] == [r["variant"] for r in csv_rows]
    assert all(float(r["mean_error_mm_mean"]) == float(f"{v['mean_error_mm_mean']:.6g}")
               for r, v in zip(csv_rows, record["variants"]))


def test_a_rewritten_report_keeps_the_run_that_measured_it(tiny_file, tmp_path, monkeypatch):
    out = tmp_path / "out"
    study = load_spec(tiny_file, quick=True)
    run_study(study, out, progress=False, log=lambda m: None, command="first")
    measured = json.loads((out / "results.json").read_text())
    monkeypatch.setattr("hybridfit._environment.platform.python_version", lambda: "0.0.0")
    write_report(out, study)  # --report-only, on another day or machine
    run_study(study, out, progress=False, log=lambda m: None, command="second")  # nothing left to run
    again = json.loads((out / "results.json").read_text())
    assert (again["command"], again["machine"], again["date"]) == ("first", measured["machine"], measured["date"])
