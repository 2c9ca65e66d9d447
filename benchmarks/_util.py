"""Small helpers shared by the benchmark scripts: timing medians and Markdown tables."""

from __future__ import annotations

import time

import numpy as np


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


def table(header: list[str], rows: list[list]) -> str:
    """A Markdown table."""
    fmt = lambda v: f"{v:.3g}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)
