"""bench_alternatives.py's smoke run (--quick): every row measured against pso in one run, its
record written as the results page reads records, the process's cores as they were."""

from __future__ import annotations

import json
import os

import bench_alternatives


def test_quick_run_measures_every_row_against_pso_and_writes_its_record(tmp_path, capsys):
    cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    path = tmp_path / "alternatives.json"
    assert bench_alternatives.main(["--quick", "--json", str(path)]) == 0
    record = json.loads(path.read_text())
    assert record["name"] == "alternatives" and record["version"] and record["machine"]
    assert record["budget"] == 600 and record["frames"] == 4 and record["repeat"] == 1
    table = record["tables"]["alternatives"]
    assert table["columns"] == bench_alternatives.COLUMNS
    labels = [row[0] for row in table["rows"]]
    assert labels[:3] == ["pso", "nlopt", "cmaes"] and bench_alternatives.HYBRID in labels
    assert set(labels) == set(bench_alternatives.SEARCH) | {bench_alternatives.HYBRID}  # measured or said why not
    figures = record["figures"]
    assert figures["pso"]["ratio"] == 1.0 and table["rows"][0][2] == "1x"
    for label, f in figures.items():
        assert f["ms"] > 0 and f["ratio"] > 0 and 0 < f["error"] < 100, (label, f)
    for label in set(labels) - set(figures):
        assert "not measured" in table["rows"][labels.index(label)][4]
    assert "| pso |" in capsys.readouterr().out
    if cores is not None:
        assert os.sched_getaffinity(0) == cores  # pinned while it measured, not after
