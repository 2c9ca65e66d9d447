"""docs/results.md is the renderer's output from the committed records: it cannot go stale, a
record not yet measured says so with its command, every table names a version and a machine,
and the page holds at most 400 lines."""

from __future__ import annotations

import json
import re

import pytest

import render_results
from render_results import PAGE, TEMPLATE, render
from run_all import JOBS, command

RECORD = {"name": "x", "version": "9.9.9", "command": "python benchmarks/bench_x.py --frames 3", "date": "2030-01-02",
          "machine": {"cpu": "Some CPU", "cores": 1, "cpus": 4, "system": "Linux 6", "python": "3.11.7",
                      "numpy": "2.0", "numba": "0.60"},
          "tables": {"a": {"columns": ["what", "mm"], "rows": [["fit | polished", "1.00"]]},
                     "b": {"title": "Second", "columns": ["k"], "rows": [["3"]]}}}


def test_the_committed_page_is_the_renderers_output_of_the_committed_records():
    assert PAGE.read_text() == render(TEMPLATE.read_text()), \
        "docs/results.md is stale: run python benchmarks/render_results.py"
    assert render_results.main(["--check"]) == 0


def test_the_page_holds_at_most_400_lines():
    assert PAGE.read_text().count("\n") <= render_results.MAX_LINES == 400


def test_every_table_on_the_page_names_the_version_and_the_machine():
    lines = PAGE.read_text().splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("|") and (i == 0 or not lines[i - 1].startswith("|"))]
    assert len(starts) >= 5
    for i in starts:
        above = lines[i - 2]
        assert lines[i - 1] == "" and re.search(r"hybridfit \d+\.\d+\.\d+ on .*(cores|machine)", above), (i, above)


def test_a_missing_record_is_not_yet_measured_with_its_command(tmp_path):
    page = render("{{ core }}\n\n{{ d_max }}\n", tmp_path / "b", tmp_path / "s")
    core, d_max = (next(j for j in JOBS if j.name == n) for n in ("core", "d_max"))
    assert page == f"not yet measured: run `{command(core)}`\n\nnot yet measured: run `{command(d_max)}`\n"
    assert "python benchmarks/bench_core.py" in command(core)
    assert command(d_max).startswith("hybridfit study studies/d_max.toml")


def test_a_record_renders_its_tables_each_under_its_version_machine_and_command(tmp_path):
    (tmp_path / "core.json").write_text(json.dumps(RECORD))
    page = render("# T\n\n{{ core }}\n\ntext\n\n{{ core b }}\n", tmp_path, tmp_path)
    head = ("*hybridfit 9.9.9 on Some CPU, 1 of 4 cores (Linux 6, Python 3.11.7, numpy 2.0, numba 0.60), 2030-01-02:* "
            "`python benchmarks/bench_x.py --frames 3`")
    assert page == (f"# T\n\n{head}\n\n| what | mm |\n|---|---|\n| fit \\| polished | 1.00 |\n\n"
                    f"**Second.** {head}\n\n| k |\n|---|\n| 3 |\n\ntext\n\n**Second.** {head}\n\n| k |\n|---|\n| 3 |\n")


@pytest.mark.parametrize("broken", [{"version": None}, {"machine": {}}])
def test_a_record_without_its_version_or_machine_is_refused(tmp_path, broken):
    (tmp_path / "core.json").write_text(json.dumps({**RECORD, **broken}))
    with pytest.raises(ValueError, match="version and the machine"):
        render("{{ core }}\n", tmp_path, tmp_path)


def test_a_placeholder_naming_nothing_or_a_missing_table_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="no benchmark or study"):
        render("{{ no_such_thing }}\n", tmp_path, tmp_path)
    (tmp_path / "core.json").write_text(json.dumps(RECORD))
    with pytest.raises(ValueError, match="no table c"):
        render("{{ core c }}\n", tmp_path, tmp_path)


def test_a_placeholders_title_heads_its_first_table_or_its_missing_line(tmp_path):
    (tmp_path / "core.json").write_text(json.dumps(RECORD))
    page = render("{{ core a b | Speed, per frame }}\n\n{{ peers | Peers }}\n", tmp_path, tmp_path)
    captions = [line for line in page.splitlines() if "hybridfit 9.9.9" in line]
    assert captions[0].startswith("**Speed, per frame.** *hybridfit") and captions[1].startswith("**Second.** ")
    assert page.endswith("**Peers.** not yet measured: run `taskset -c 0 python benchmarks/bench_peers.py`\n")


def test_others_names_the_jobs_the_page_does_not_show(tmp_path):
    (tmp_path / "render.json").write_text(json.dumps(RECORD))
    line = render("{{ core }}\n{{ others }}\n", tmp_path, tmp_path).splitlines()[-1]
    assert re.findall(r"`(\w+)`", line) == [j.name for j in JOBS if j.name != "core"]
    assert "`render` (hybridfit 9.9.9, 2030-01-02)" in line and "`peers` (not yet measured)" in line


def test_the_anchors_other_pages_use_are_headings_of_the_page():
    """Links into results.md from the docs and README name headings that exist (mkdocs checks the
    docs' own; README's are checked here)."""
    slugs = {re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower())  # Python-Markdown's toc slugify
             for h in re.findall(r"^#+ (.+)$", PAGE.read_text(), re.M)}
    root = PAGE.parents[1]
    links = set()
    for path in [root / "README.md", *(root / "docs").glob("*.md")]:
        links |= set(re.findall(r"results\.md#([\w-]+)", path.read_text()))
    assert links and links <= slugs, links - slugs


def test_no_html_from_a_record_reaches_the_page_and_a_studys_escaped_cells_stay_as_they_are(tmp_path):
    record = {**RECORD, "command": "hybridfit study <i>x</i>`.toml", "note": "<script>alert(1)</script>",
              "machine": {**RECORD["machine"], "cpu": "<b>CPU</b>"},
              "tables": {"a": {"title": "<img src=x onerror=alert(1)>", "columns": ["<th>"],
                               "rows": [["<script>alert(1)</script> | x"], ["a \\| b &lt;i&gt;"]]}}}
    (tmp_path / "core.json").write_text(json.dumps(record))
    page = render("{{ core }}\n", tmp_path, tmp_path)
    code = "``hybridfit study <i>x</i>`.toml``"  # the command as written, in a code span (shown, not run)
    assert code in page and "<" not in page.replace(code, "")
    assert "| &lt;script&gt;alert(1)&lt;/script&gt; \\| x |" in page  # a raw cell: its HTML inert, its | escaped
    assert "| a \\| b &lt;i&gt; |" in page  # a study's report escaped it already: not escaped twice
    assert "&lt;b&gt;CPU&lt;/b&gt;" in page and "**&lt;img src=x onerror=alert(1)&gt;.**" in page
