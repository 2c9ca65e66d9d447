"""Small helpers shared by the benchmark scripts: timing medians, Markdown tables and the
record every benchmark writes.

The record, ``benchmarks/results/NAME.json`` (each script's ``--json``), is what the results
page is rendered from (``python benchmarks/render_results.py``)::

    {"name": ..., "version": hybridfit.__version__, "machine": {cpu, cores, cpus, system,
     python, numpy, numba}, "command": "python benchmarks/bench_x.py ...", "date": "YYYY-MM-DD",
     "tables": {TABLE: {"columns": [...], "rows": [[cell, ...], ...]}}, ...figures...}

Table cells are the strings the page shows; a script may add its raw figures beside them.
"""

from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "benchmarks" / "results"


def median_time(fn, repeat: int = 7, number: int = 1, clock=time.perf_counter) -> float:
    """Median time of ``fn()`` in seconds over ``repeat`` runs of ``number`` calls each (wall
    time, or another ``clock`` such as ``time.process_time``)."""
    times = []
    for _ in range(repeat):
        t = clock()
        for _ in range(number):
            fn()
        times.append((clock() - t) / number)
    return float(np.median(times))


def cell(v) -> str:
    """A table cell: floats to 3 significant digits, anything else as it prints."""
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def table(header: list[str], rows: list[list]) -> str:
    """A Markdown table."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def table_record(header: list[str], rows: list[list]) -> dict:
    """The record's form of :func:`table`: its columns and the cells as printed."""
    return {"columns": list(header), "rows": [[cell(v) for v in row] for row in rows]}


def default_record(script: str | Path) -> Path:
    """A benchmark script's record by default: ``benchmarks/results/NAME.json`` of ``bench_NAME.py``."""
    return RESULTS / f"{Path(script).stem.removeprefix('bench_')}.json"


def json_argument(parser, name: str) -> None:
    """Add ``--json`` (default ``benchmarks/results/NAME.json``) to a benchmark's parser."""
    parser.add_argument("--json", default=str(RESULTS / f"{name}.json"), metavar="PATH",
                        help=f"where the record goes (default benchmarks/results/{name}.json, which the results "
                             "page is rendered from)")


def this_command(argv: list[str] | None = None) -> str:
    """The command that ran this script, as typed from the repository's root."""
    argv = sys.argv if argv is None else argv
    script = Path(argv[0]).resolve()
    shown = script.relative_to(REPO) if script.is_relative_to(REPO) else script
    return shlex.join(["python", str(shown), *argv[1:]])


def machine() -> dict:
    """The machine measured on (CPU model, cores, system, Python, numpy and numba)."""
    from hybridfit._environment import machine

    return machine()


def write_record(path: str | Path, tables: dict[str, dict], command: str | None = None, **figures) -> Path:
    """Write the record (see the module docstring) of this run to ``path``: its ``tables``
    (name -> :func:`table_record`) and any raw ``figures``; ``command``: what ran it (default
    this script's command line)."""
    import hybridfit

    path = Path(path)
    record = {"name": path.stem, "version": hybridfit.__version__, "machine": machine(),
              "command": command or this_command(),
              "date": time.strftime("%Y-%m-%d"), "tables": tables, **figures}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record, indent=1) + "\n")
    print(f"record -> {path}", file=sys.stderr)
    return path
