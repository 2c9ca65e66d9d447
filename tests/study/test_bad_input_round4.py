"""Bad input, round 4 (issue 39): the study runner and its report.

Names from a study file (the study's, its variants', grid values) and from data (joint names)
are refused at load when they hold control characters and are otherwise written inert:
report.md shows markup instead of running it, results.csv holds no formula, the plots draw
TeX and ``$`` as text. Data files that are not regular files, huge grids, the largest seed,
variants that are the same trials, a user error before any trial ran and a few confusing
study files are each one line (exit 2) or just work. Each test failed on the code before."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
import shutil
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import hybridfit
from hybridfit.cli import main
from hybridfit.errors import HybridfitError
from hybridfit.study import load_spec, parse_spec, run_study, write_report
from hybridfit.study import plots, report, runner
from hybridfit.study.store import DB_NAME, Store
from hybridfit.text import markdown

from .conftest import write

TINY = """
name = "t"
seeds = 1

[data]
kind = "synthetic-proposals"
frames = 3
k = 2

[base]
budget = 300
k = 2
"""

DATA = {"kind": "synthetic-proposals", "frames": 3, "k": 2}


def one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and len(err.splitlines()) == 1 and err.startswith("hybridfit: error: "), err
    return err.strip()


def quiet(m):
    pass


# ====================================================================== 1. markup and formulas in names

INJECTED = """
name = "<script>alert(1)</script>"
description = \"\"\"<img src=x onerror=alert(1)>
# not a heading
[x](javascript:alert(1))\"\"\"
seeds = 1

[data]
kind = "synthetic-proposals"
frames = 3
k = 2

[base]
budget = 300
k = 2

[[sweep.variants]]
name = "<img src=x onerror=alert(1)>"

[[sweep.variants]]
name = "[click](javascript:alert(1))"
budget = 301

[[sweep.variants]]
name = "# heading | cell"
budget = 302

[[sweep.variants]]
name = '=HYPERLINK("http://evil.example","x")'
budget = 303

[[sweep.variants]]
skeleton = "<b>bold</b>"
"""
NAMES = ["<img src=x onerror=alert(1)>", "[click](javascript:alert(1))", "# heading | cell",
         '=HYPERLINK("http://evil.example","x")', "skeleton=<b>bold</b>"]


@pytest.fixture(scope="module")
def injected(tmp_path_factory):
    root = tmp_path_factory.mktemp("injected")
    out = root / "out"
    run_study(load_spec(write(root, INJECTED)), out, progress=False, log=quiet,
              command="hybridfit study <i>x</i>`.toml")
    return out


def _table_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("|")]


def _pipes(line: str) -> int:
    """The table's own column separators in a line (escaped pipes are a cell's text)."""
    return len(re.findall(r"(?<!\\)\|", line.replace("\\\\", "")))


def test_markup_in_names_is_shown_not_run_in_the_report(injected):
    text = (injected / "report.md").read_text()
    assert "<" not in text and ">" not in text  # no tag at all: <script>, <img onerror>, <b>
    assert "](javascript" not in text.replace("\\](", "")  # no link
    assert [line for line in text.splitlines() if line.startswith("#")] == [  # the names' '#' make no heading
        "# Study: &lt;script&gt;alert(1)&lt;/script&gt;", "## Success rate",
        "## Error vs budget (objective evaluations per frame)", "## Mean error per variant", "## Error per joint"]
    table = _table_lines(text)
    assert len(table) == 2 + 4 + len(NAMES)  # head, rule, Oracle and top-1 (also of the skeleton), the variants
    assert len({_pipes(line) for line in table}) == 1  # every row has the head's columns
    for name in NAMES:
        assert f"| {markdown(name)} |" in text


def test_formulas_in_names_are_text_in_results_csv(injected):
    with open(injected / "results.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    cells = [c for row in rows for c in row]
    assert "'=HYPERLINK(\"http://evil.example\",\"x\")" in cells
    for c in cells:
        try:
            float(c)
        except ValueError:
            assert not c or c[0] not in "=+-@\t\r", c


def test_the_results_page_shows_a_studys_names_and_never_its_html(injected, tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    import render_results

    record = json.loads((injected / "results.json").read_text())
    page = "\n".join(render_results.block(record, injected / "results.json", []))
    assert "<" not in page.replace("`hybridfit study <i>x</i>`.toml``", "")  # only inside the command's code span
    assert "``hybridfit study <i>x</i>`.toml``" in page
    for name in NAMES:
        assert f"| {markdown(name)} |" in page  # as the report shows it, not escaped twice
    # a record with HTML in its own cells (by hand, or by an older hybridfit): made inert too
    record["tables"]["results"]["rows"][0][0] = "<img src=x onerror=alert(1)> | x"
    record["note"] = "<script>alert(1)</script>"
    page = "\n".join(render_results.block(record, injected / "results.json", []))
    assert "<img" not in page and "<script" not in page and "&lt;img src=x onerror=alert(1)&gt; \\| x" in page


@pytest.mark.parametrize("edit, field", [
    ({"name": "a\nb"}, "name"),
    ({"sweep": {"variants": [{"name": "x\ty", "budget": 300}]}}, "sweep.variants.0"),
    ({"sweep": {"variants": [{"name": "\x1b[31mred", "budget": 300}]}}, "sweep.variants.0"),
    ({"sweep": {"variants": [{"skeleton": "a\u202eb"}]}}, "sweep.variants.0"),
    ({"sweep": {"grid": {"skeleton": ["ok", "b\r\nc"]}}}, "sweep.grid"),
])
def test_control_characters_in_names_are_refused_at_load_naming_file_and_field(tmp_path, edit, field):
    raw = {"name": "t", "seeds": 1, "data": DATA, "base": {"budget": 300, "k": 2}, **edit}
    with pytest.raises(HybridfitError) as err:
        parse_spec(raw, "t.toml")
    msg = str(err.value)
    assert msg.startswith(f"t.toml: {field}") and "control characters" in msg and "\n" not in msg, msg


def test_control_characters_in_a_study_file_are_one_line(tmp_path, capsys):
    path = write(tmp_path, TINY.replace('name = "t"', 'name = "a\\nb"'))
    err = one_line_error(capsys, main(["study", str(path), "--out", str(tmp_path / "o")]))
    assert f"{path}: name: name 'a\\nb' holds control characters" in err
    assert not (tmp_path / "o").exists()


# ====================================================================== 2. TeX and $ in the plots


def fake_study(out: Path, names: list[str], joint_names: list[str], study_name: str = "s",
               error: str | None = None) -> Path:
    """A study folder whose study.db holds an Oracle row and a fitted row per name (labelled
    by the study file, as ``trial_labels`` does), made without fitting anything."""
    out.mkdir(parents=True, exist_ok=True)
    store = Store(out / DB_NAME)
    rng = np.random.default_rng(0)
    keys, labels = [], {}
    F, J = 3, len(joint_names)

    def add(key, label, index, method, settings):
        store.start(key, f"row {len(keys)}", index, method, settings, 0)
        store.complete(key, {"errors": rng.uniform(1, 50, (F, J)), "objective": np.ones(F),
                             "evaluations": np.full(F, 300), "failed": np.zeros(F, bool), "messages": {},
                             "time_per_frame": 0.01, "joint_names": joint_names})
        keys.append(key)
        labels[key] = [label, index]

    add("oracle", "Oracle (k=2)", -1, "oracle", {"method": "oracle", "k": 2, "proposal_set": 0})
    for i, name in enumerate(names):
        add(f"fit{i}", name, i, "fit", {"k": 2, "proposal_set": 200, "budget": 300 + i, "model": "hand26",
                                        "objective": "clamped-then-soft-l1", "optimizer": "stepwise-pso",
                                        "optimizer_config": {}})
    if error is not None:
        store.start("failed", names[0], 0, "fit", {"budget": 999}, 1)
        store.fail("failed", error)
        keys.append("failed")
    store.set_meta("study", {"name": study_name, "description": "", "spec": {"data": {"kind": "synthetic-proposals"}}})
    store.set_meta("trial_keys", keys)
    store.set_meta("trial_labels", labels)
    store.close()
    return out


TEX = [r"$\frac{1}{$", "a$b", r"\alpha^{", "$$", r"$\sqrt$", "thumb_tip"]


def test_tex_and_dollars_in_joint_and_variant_names_are_plotted_as_text(tmp_path):
    out = fake_study(tmp_path / "o", [r"$\frac{a}{$ budget", "cost $5", r"\$x$"], TEX, study_name="$x^$")
    write_report(out)
    for name in ("success_rate.png", "error_vs_budget.png", "variants.png", "per_joint.png"):
        assert (out / name).stat().st_size > 1000, name


def test_every_text_a_plot_draws_is_plain_text(tmp_path, monkeypatch):
    import matplotlib.text

    drawn = []
    real = plots._save

    def save(fig, out, name, rows=None):
        drawn.extend(t.get_text() for t in fig.findobj(matplotlib.text.Text))
        return real(fig, out, name, rows)

    monkeypatch.setattr(plots, "_save", save)
    plots.make_plots(tmp_path, _rows([r"$\alpha$", "a $ b"], ["$x$", "y"]))
    for text in (r"\$\alpha\$", r"a \$ b", r"\$x\$"):  # in the legends, the bars' and the joints' labels
        assert text in drawn, text
    assert not [t for t in drawn if re.search(r"(?<!\\)\$", t)]  # no unescaped $ anywhere: no mathtext


def _rows(names, joint_names):
    """Aggregated rows (as report.aggregate gives) of fitted variants with these names."""
    rows = []
    for i, name in enumerate(names):
        row = {"variant": name, "method": "fit", "variant_index": i, "seeds": 1, "frames": 3,
               "settings": {"k": 2, "proposal_set": 200, "budget": 300 + i}, "curve": np.linspace(0, 1, 81),
               "per_joint": np.arange(len(joint_names), dtype=float) + i, "joint_names": list(joint_names)}
        for m in report.METRICS:
            row[f"{m}_mean"], row[f"{m}_std"] = 10.0 + i, 1.0
        rows.append(row)
    return rows


# ====================================================================== 3. variants that are the same trials


def test_two_variants_with_the_same_settings_are_refused_naming_both(tmp_path, capsys):
    path = write(tmp_path, TINY + '[[sweep.variants]]\nname = "a"\nbudget = 300\n\n'
                                  '[[sweep.variants]]\nname = "b"\nk = 2\n')
    err = one_line_error(capsys, main(["study", str(path), "--out", str(tmp_path / "o")]))
    assert f"{path}: sweep.variants.1: variant 'b' has the same settings as variant 'a' (sweep.variants.0)" in err
    assert not (tmp_path / "o").exists()


def test_variants_that_differ_in_a_setting_are_kept(tmp_path):
    study = load_spec(write(tmp_path, TINY + '[[sweep.variants]]\nname = "a"\n\n[[sweep.variants]]\nname = "b"\n'
                                             'budget = 301\n'))
    assert [v.name for v in hybridfit.study.expand(study)] == ["a", "b"]


# ====================================================================== 4. data files that are no regular files


def _proposals_study(tmp_path, file: str) -> Path:
    return write(tmp_path, TINY.replace('kind = "synthetic-proposals"\nframes = 3\nk = 2',
                                        f'kind = "proposals"\nfile = "{file}"\ndataset = "icvl"'))


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_data_file_that_is_a_fifo_or_a_device_is_refused_in_one_line(tmp_path, capsys, kind):
    if kind == "fifo":
        target = tmp_path / "p.npz"
        os.mkfifo(target)
    else:
        target = Path("/dev/zero")
    path = _proposals_study(tmp_path, str(target))
    with pytest.raises(HybridfitError, match=rf"^{re.escape(str(path))}: data.file: {re.escape(str(target))} is not "
                                             "a regular file"):
        load_spec(path)
    err = one_line_error(capsys, main(["study", str(path), "--out", str(tmp_path / "o")]))
    assert "is not a regular file" in err and not (tmp_path / "o").exists()


def test_hashing_a_fifo_is_refused_not_a_hang(tmp_path):
    from hybridfit.study.data import file_hash

    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    outcome = []

    def hash_it():
        try:
            outcome.append(file_hash(fifo))
        except HybridfitError as err:
            outcome.append(err)

    thread = threading.Thread(target=hash_it, daemon=True)
    thread.start()
    thread.join(10)
    if thread.is_alive():  # the old code blocks in open(): let it go
        with open(fifo, "wb"):
            pass
        thread.join(10)
        pytest.fail("file_hash hung on a FIFO")
    assert isinstance(outcome[0], HybridfitError) and "not a regular file" in str(outcome[0])


# ====================================================================== 5. huge grids are counted, not expanded

HUGE = TINY + """
[sweep.grid]
budget = {budgets}
search_radius_mm = {radii}
proposal_set = {sets}
"""


def _huge(tmp_path, n: int = 100, quick: str = "") -> Path:
    return write(tmp_path, HUGE.format(budgets=list(range(300, 300 + n)), radii=[float(r) for r in range(10, 10 + n)],
                                       sets=list(range(1, n + 1))) + quick)


def test_a_huge_grid_is_refused_before_it_is_expanded(tmp_path, capsys, monkeypatch):
    import hybridfit.study.load as load

    def never(*args, **kwargs):
        raise AssertionError("the sweep was expanded")

    monkeypatch.setattr(load, "expand", never)
    path = _huge(tmp_path)
    t = time.perf_counter()
    with pytest.raises(HybridfitError, match="1,000,000 trials planned"):
        load_spec(path)
    err = one_line_error(capsys, main(["study", str(path), "--out", str(tmp_path / "o")]))
    assert time.perf_counter() - t < 10
    assert err == (f"hybridfit: error: {path}: 1,000,000 trials planned (variants x seeds), more than 10,000: check "
                   "the sweep, or pass --allow-large to run them all")


def test_a_quick_run_of_a_huge_study_expands_only_its_quick_sweep(tmp_path, monkeypatch):
    import hybridfit.study.load as load

    expanded = []
    real = load.expand

    def counted(study, where="study"):
        expanded.append(runner.count_trials(study))
        assert expanded[-1] <= runner.MAX_TRIALS, "the full sweep was expanded"
        return real(study, where)

    monkeypatch.setattr(load, "expand", counted)
    quick = '\n[quick.sweep.grid]\nbudget = [300]\nsearch_radius_mm = [60.0]\nproposal_set = [200]\n'
    study = load_spec(_huge(tmp_path, quick=quick), quick=True)
    assert runner.count_trials(study) == 1 and expanded == [1]


# ====================================================================== 6. the largest seed

def test_the_largest_documented_seed_runs_and_is_stored_as_given(tmp_path):
    big = 2**64 - 1
    path = write(tmp_path, TINY.replace("seeds = 1", f"seeds = [{big}, 5]"))
    out = tmp_path / "o"
    summary = run_study(load_spec(path), out, progress=False, log=quiet)
    assert (summary.ran, summary.failed) == (2, 0)
    store = Store(out / DB_NAME)
    try:
        assert [t["seed"] for t in store.trials() if t["method"] == "fit"] == [5, big]
    finally:
        store.close()
    assert "| base | 2 |" in (out / "report.md").read_text()
    again = run_study(load_spec(path), out, progress=False, log=quiet)  # resumes: both complete
    assert (again.skipped, again.ran) == (2, 0)


# ====================================================================== 7. nothing left behind by a user error


def test_a_user_error_before_any_trial_leaves_nothing_of_this_run(tmp_path, capsys, monkeypatch):
    path = write(tmp_path, TINY)
    out, cache = tmp_path / "o", tmp_path / "c.txt"
    cache.write_text("not a folder\n")
    err = one_line_error(capsys, main(["study", str(path), "--out", str(out), "--cache", str(cache)]))
    assert "the cache must be a folder" in err and not out.exists() and cache.read_text() == "not a folder\n"
    empty = tmp_path / "empty"  # the user's folder: kept, and only this run's files removed from it
    empty.mkdir()
    one_line_error(capsys, main(["study", str(path), "--out", str(empty), "--cache", str(cache)]))
    assert empty.is_dir() and list(empty.iterdir()) == []

    def refuse(*args, **kwargs):  # a user error once the cache folder is made, before any work
        raise HybridfitError("bad data")

    monkeypatch.setattr(runner, "StudyData", refuse)
    for extra in ([], ["--cache", str(tmp_path / "new" / "cache")]):
        assert one_line_error(capsys, main(["study", str(path), "--out", str(out), *extra])).endswith("bad data")
        assert not out.exists() and not (tmp_path / "new").exists()


def test_a_user_error_keeps_the_users_study_db_and_cache(tmp_path, capsys):
    path = write(tmp_path, TINY)
    out, mine = tmp_path / "o", tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine\n")
    assert main(["study", str(path), "--out", str(out)]) == 0
    capsys.readouterr()
    before = {p.relative_to(out): hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*") if p.is_file()}
    err = one_line_error(capsys, main(["study", str(path), "--out", str(out), "--cache", str(mine)]))
    assert "not a hybridfit cache" in err
    assert {p.relative_to(out): hashlib.sha256(p.read_bytes()).hexdigest() for p in out.rglob("*")
            if p.is_file()} == before
    assert [p.name for p in mine.iterdir()] == ["notes.txt"] and (mine / "notes.txt").read_text() == "mine\n"


def test_an_unreachable_scheduler_leaves_no_study_db_and_no_cache(tmp_path, capsys):
    pytest.importorskip("distributed")
    path = write(tmp_path, TINY)
    out = tmp_path / "o"
    err = one_line_error(capsys, main(["study", str(path), "--out", str(out), "--executor", "dask",
                                       "--scheduler", "tcp://127.0.0.1:9"]))
    assert "--scheduler tcp://127.0.0.1:9: no dask scheduler answered" in err
    assert not out.exists()


# ====================================================================== 8. confusing study files


def test_a_study_file_with_a_utf8_bom_is_read(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + TINY.encode())
    assert load_spec(path).name == "t"


def test_a_folder_given_as_the_study_file_is_one_line(tmp_path, capsys):
    err = one_line_error(capsys, main(["study", str(tmp_path), "--out", str(tmp_path / "o")]))
    assert err == f"hybridfit: error: {tmp_path}: is a folder; give a study file (TOML, see studies/)"


@pytest.mark.parametrize("data, expected", [
    ('kind = "proposals"\nfile = ["a.npz", "b.npz"]',
     "data.file: a list is for results files (one file per proposal rank, with dataset); an .npz holds every "
     "proposal: give one, file = \"a.npz\""),
    ('kind = "proposals"\nfile = [1, 2]',
     "data.file: expected a path (a string) or a list of paths, got a list holding a number"),
    ('kind = "proposals"\nfile = {a = 1}', "data.file: expected a path (a string) or a list of paths, got a table"),
    ('kind = "proposals"\nfile = "a.npz"\nground_truth = ["a.npz"]',
     "data.ground_truth: expected a path (a string), got a list"),
    ('kind = "dataset"\ntest = ["a", "b"]\nforest_file = "a.npz"', "data.test: expected a path (a string), got a list"),
])
def test_a_list_or_table_where_a_path_is_expected_is_one_line(tmp_path, capsys, data, expected):
    np.savez(tmp_path / "a.npz", **hybridfit.synthetic_proposals(3, k=2, seed=1))
    shutil.copy(tmp_path / "a.npz", tmp_path / "b.npz")
    path = write(tmp_path, TINY.replace('kind = "synthetic-proposals"\nframes = 3\nk = 2', data))
    err = one_line_error(capsys, main(["study", str(path), "--out", str(tmp_path / "o")]))
    assert err == f"hybridfit: error: {path}: {expected}"


# ====================================================================== 9. generated names

NAME_CHARS = st.sampled_from(list("<>&\"'|[]()#!*_`~\\$=+-@{}^:/ \t\r\n\x00\x1b\x7f\u202e\udcff") + ["\u00e9", "x"])
#: pieces of markup, formulas and TeX, so that generated names hold whole tags, links and $...$
PIECES = st.sampled_from(["<script>", "</b>", "<img src=x onerror=alert(1)>", "[a](javascript:alert(1))", "# ",
                          "=HYPERLINK(", "+1+", "@SUM(", "$", r"\frac{", "^{", "_", "| x |", "\n", "\udcff", "\x00"])
NAMES_ST = st.lists(PIECES | st.text(NAME_CHARS | st.characters(), max_size=4), min_size=1, max_size=5).map("".join)


@settings(max_examples=40, deadline=None)
@given(study_name=NAMES_ST, names=st.lists(NAMES_ST, min_size=2, max_size=2, unique=True))
def test_generated_names_are_refused_in_one_line_at_load_or_accepted_printable(study_name, names):
    variants = [{"name": n, "budget": 300 + i} for i, n in enumerate(names)]
    raw = {"name": study_name, "seeds": 1, "data": DATA, "base": {"budget": 300, "k": 2},
           "sweep": {"variants": variants}}
    try:
        study = parse_spec(raw, "t.toml")
    except HybridfitError as err:
        assert str(err).startswith("t.toml: ") and "\n" not in str(err) and "\r" not in str(err)
        return
    from hybridfit.text import control_characters

    assert not control_characters(study.name)
    assert not any(control_characters(v.name) for v in hybridfit.study.expand(study))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(study_name=NAMES_ST, names=st.lists(NAMES_ST, min_size=1, max_size=3, unique=True), error=NAMES_ST)
def test_generated_names_are_written_inert_in_report_md_and_results_csv(tmp_path_factory, study_name, names, error):
    out = fake_study(tmp_path_factory.mktemp("gen"), names, ["a", "b"], study_name=study_name, error=error)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plots, "make_plots", lambda out, rows, spec=None: [])  # the plots: the test below
        write_report(out)
    text = (out / "report.md").read_text()
    assert "<" not in text and ">" not in text and "\r" not in text
    own = "[results.csv](results.csv)"  # the report's one link
    assert text.count(own) == 1 and "](" not in text.replace(own, "").replace("\\](", "") and "![" not in text
    table = _table_lines(text)
    assert len(table) == 2 + 1 + len(names) and len({_pipes(line) for line in table}) == 1
    assert next(line for line in text.splitlines() if line.startswith("#")).startswith("# Study: ")
    assert sum(line.startswith("#") for line in text.splitlines()) == 2  # the title and the failed trials
    with open(out / "results.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert len(rows) == 2 + len(names)
    for c in (c for row in rows for c in row):
        try:
            float(c)
        except ValueError:
            assert not c or c[0] not in "=+-@\t\r", c


@pytest.mark.filterwarnings("ignore:Glyph")  # a control character has no glyph: drawn as a box
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(names=st.lists(NAMES_ST, min_size=1, max_size=2, unique=True),
       joints=st.lists(NAMES_ST, min_size=2, max_size=3))
def test_generated_names_are_plotted_without_a_crash(tmp_path_factory, names, joints):
    out = tmp_path_factory.mktemp("plots")
    figures = plots.make_plots(out, _rows(names, joints))
    assert [f for _, f in figures] == (["success_rate.png"] + (["error_vs_budget.png"] if len(names) > 1 else [])
                                       + ["variants.png", "per_joint.png"])
    assert all((out / f).stat().st_size > 1000 for _, f in figures)
