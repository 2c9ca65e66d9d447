"""Rebuild docs/results.md from its template and the committed records.

    python benchmarks/render_results.py [--check]

The template, ``benchmarks/results_template.md``, is the page's prose; a line that is only
``{{ NAME [TABLE ...] [| TITLE] }}`` becomes the tables of the record NAME (all, or those
named; the first titled TITLE): ``benchmarks/results/NAME.json`` of a benchmark,
``studies/results/NAME.json`` of a study (``run_all.JOBS``), or a record no job writes, in
``benchmarks/results``. Each table is headed by the hybridfit version, the machine, the date
and the command that measured it; a record not yet measured becomes "not yet measured: run
`COMMAND`". ``{{ others }}`` lists the jobs whose records the page does not show. ``--check`` exits 1
if docs/results.md is not what the records give (or is longer than 400 lines).

A record's table cells, titles and notes are Markdown as the page shows it (a benchmark's bold
figure, a study's names as its report escaped them: :func:`hybridfit.text.markdown`), but never
HTML: ``<`` and ``>`` become entities, so no tag from a record reaches the page. The version,
date and machine are plain text (escaped), the command an inline code span.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hybridfit.text import markdown  # noqa: E402
from _util import REPO, RESULTS  # noqa: E402
from run_all import JOBS, STUDY_RESULTS, command, record_path  # noqa: E402

TEMPLATE = REPO / "benchmarks" / "results_template.md"
PAGE = REPO / "docs" / "results.md"
MAX_LINES = 400
PLACEHOLDER = re.compile(r"^\{\{ *([\w-]+)((?: +[\w-]+)*) *(?:\| *(.*?))? *\}\}$")


def describe(machine: dict) -> str:
    """The machine in a few words."""
    if "description" in machine:
        return machine["description"]
    cores = machine["cores"] if machine.get("cpus") in (None, machine["cores"]) else \
        f"{machine['cores']} of {machine['cpus']}"
    return (f"{machine['cpu']}, {cores} cores ({machine.get('system', '?')}, Python {machine.get('python', '?')}, "
            f"numpy {machine.get('numpy', '?')}, numba {machine.get('numba', '?')})")


def caption(record: dict, path: Path, title: str | None = None) -> str:
    """The line above a table: its title, and the version, machine, date and command of its record."""
    if not record.get("version") or not record.get("machine"):
        raise ValueError(f"{path}: a record names the hybridfit version and the machine it was measured on")
    how = (f"written down by hand: {no_html(record['hand_written'])}" if record.get("hand_written")
           else code(record["command"]))
    head = f"**{no_html(title)}.** " if title else ""
    return (f"{head}*hybridfit {markdown(record['version'])} on {markdown(describe(record['machine']))}, "
            f"{markdown(record.get('date', '?'))}:* {how}")


def no_html(text) -> str:
    """A record's Markdown with no HTML in it: ``<`` and ``>`` as entities (its ``&`` kept, so
    the entities of a study's escaped names stay what they show)."""
    return str(text).replace("<", "&lt;").replace(">", "&gt;")


def code(text) -> str:
    """``text`` on one line as an inline code span, shown as written (HTML in it is text): its
    fence has more backticks than any run of them in it."""
    text = " ".join(str(text).splitlines())
    fence = "`" * (1 + max(map(len, re.findall("`+", text)), default=0))
    pad = " " if text.startswith("`") or text.endswith("`") else ""
    return f"{fence}{pad}{text}{pad}{fence}"


def cell(value) -> str:
    """A table cell: one line, no HTML, its ``|`` escaped (one already escaped, as a study's
    report writes it, is kept as it is)."""
    return re.sub(r"(?<!\\)\|", r"\\|", no_html(value)).replace("\r", " ").replace("\n", " ")


def block(record: dict, path: Path, names: list[str], title: str | None = None) -> list[str]:
    """The Markdown of the record's tables ``names`` (all if empty), each with its caption
    (the first titled ``title``, if given)."""
    tables = record.get("tables") or {}
    unknown = [n for n in names if n not in tables] or ([] if tables else ["at all"])
    if unknown:
        raise ValueError(f"{path}: no table {', '.join(unknown)} (it has: {', '.join(tables) or 'none'})")
    lines: list[str] = []
    for i, name in enumerate(names or list(tables)):
        t = tables[name]
        lines += [caption(record, path, title if title and i == 0 else t.get("title")), "",
                  "| " + " | ".join(map(cell, t["columns"])) + " |", "|" + "---|" * len(t["columns"])]
        lines += ["| " + " | ".join(map(cell, row)) + " |" for row in t["rows"]]
        lines.append("")
    if record.get("note"):
        lines += [no_html(record["note"]), ""]
    return lines[:-1]


def render(template: str, benchmarks: Path = RESULTS, studies: Path = STUDY_RESULTS) -> str:
    """The page: the template with every placeholder replaced (see the module docstring)."""
    jobs = {j.name: j for j in JOBS}
    placed = {m.group(1) for line in template.splitlines() if (m := PLACEHOLDER.match(line.strip()))}
    out: list[str] = []
    for line in template.splitlines():
        m = PLACEHOLDER.match(line.strip())
        if not m:
            out.append(line)
            continue
        name, tables, title = m.group(1), m.group(2).split(), m.group(3)
        if name == "others":
            out.append(others([j for j in JOBS if j.name not in placed], benchmarks, studies))
            continue
        job = jobs.get(name)
        path = record_path(job, benchmarks, studies) if job else RESULTS / f"{name}.json"
        if path.is_file():
            out += block(json.loads(path.read_text()), path, tables, title)
        elif job:
            out.append((f"**{title}.** " if title else "") + f"not yet measured: run `{command(job)}`")
        else:
            raise ValueError(f"the template names {name!r}: no benchmark or study of that name, and no {path}")
    return "\n".join(out).rstrip("\n") + "\n"


def others(jobs: list, benchmarks: Path, studies: Path) -> str:
    """A line naming the jobs the page does not show, each with its record's version and date
    or "not yet measured"."""
    said = []
    for job in jobs:
        path = record_path(job, benchmarks, studies)
        if path.is_file():
            record = json.loads(path.read_text())
            said.append(f"`{job.name}` (hybridfit {markdown(record.get('version'))}, {markdown(record.get('date'))})")
        else:
            said.append(f"`{job.name}` (not yet measured)")
    return ", ".join(said) + "."


def write(page: Path | None = None, benchmarks: Path = RESULTS, studies: Path = STUDY_RESULTS) -> Path:
    """Render the template with the records in ``benchmarks`` and ``studies`` into ``page``
    (default docs/results.md); warns when the page is longer than MAX_LINES."""
    page = page or PAGE
    text = render(TEMPLATE.read_text(), benchmarks, studies)
    page.parent.mkdir(parents=True, exist_ok=True)
    page.write_text(text)
    if text.count("\n") > MAX_LINES:
        print(f"warning: {page} has {text.count(chr(10))} lines, more than {MAX_LINES}: shorten "
              f"{TEMPLATE.relative_to(REPO)}", file=sys.stderr)
    return page


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if docs/results.md is stale or too long")
    a = ap.parse_args(argv)
    if a.check:
        text = render(TEMPLATE.read_text())
        stale = PAGE.read_text() != text
        if stale:
            print(f"{PAGE.relative_to(REPO)} is stale: run python benchmarks/render_results.py", file=sys.stderr)
        if text.count("\n") > MAX_LINES:
            print(f"{PAGE.relative_to(REPO)}: {text.count(chr(10))} lines, more than {MAX_LINES}", file=sys.stderr)
        return int(stale or text.count("\n") > MAX_LINES)
    print(f"page -> {write().relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
