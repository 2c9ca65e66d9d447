"""A study's mistakes fail before any trial runs (issue #21): a budget too small for a trial's
optimiser (exit 2, naming the trial), and a sweep of more than MAX_TRIALS trials without
--allow-large."""

from __future__ import annotations

import sqlite3

import hybridfit
from hybridfit.cli import main
from hybridfit.study import load_spec
from hybridfit.study.runner import MAX_TRIALS, check_size, count_trials
from hybridfit.task import Task

from .conftest import write

SMALL_BUDGET = """
name = "budgets"
seeds = 1
[data]
kind = "synthetic-proposals"
frames = 2
k = 3
[base]
budget = 400
[sweep.grid]
budget = [400, 5]
"""


def test_a_budget_too_small_in_the_grid_fails_before_any_trial(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["study", str(write(tmp_path, SMALL_BUDGET)), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    # the least budget of the default schedule's search stages (its local stage is left out at such budgets)
    frame = hybridfit.synthetic_proposals(1, k=3, seed=0)
    need = hybridfit.create("optimizer", "stepwise-pso").min_budget(Task(hybridfit.Problem(
        hybridfit.create("model", "hand26"), hybridfit.create("objective", "clamped-then-soft-l1"),
        frame["proposals"][0], frame["confidences"][0]), 5))
    assert 5 < need < 400
    assert err.splitlines()[-1] == ("hybridfit: error: trial budget=5: budget 5 is too small for optimizer "
                                    f"stepwise-pso: it needs at least {need} evaluations; no trial was run")
    with sqlite3.connect(out / "study.db") as db:
        assert db.execute("SELECT COUNT(*) FROM trials WHERE method = 'fit'").fetchone()[0] == 0


def test_a_huge_sweep_needs_allow_large(tmp_path, capsys):
    text = SMALL_BUDGET.replace("seeds = 1", "seeds = 60").replace("[400, 5]", str(list(range(100, 300))))
    path = write(tmp_path, text)
    study = load_spec(path)
    assert count_trials(study) == 200 * 60 > MAX_TRIALS
    code = main(["study", str(path), "--out", str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and err == (f"hybridfit: error: {path}: 12,000 trials planned (variants x seeds), more than "
                                 "10,000: check the sweep, or pass --allow-large to run them all\n")
    assert not (tmp_path / "run").exists()
    check_size(study, allow_large=True)  # the flag lets it through


def test_count_trials_matches_the_expansion(tiny_file):
    from hybridfit.study.expand import expand, trials

    study = load_spec(tiny_file)
    assert count_trials(study) == len(trials(study, expand(study), "key")) == 8
