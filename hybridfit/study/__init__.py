"""Declarative studies: sweep budgets, k, |P~| and plugins over a study's data, with seeds.

``spec`` (TOML -> validated ``Study`` -> variants and trials), ``data`` and ``cache`` (shared
steps computed once, cached by content hash), ``executors`` (serial, process pool, dask),
``store`` (SQLite results), ``runner`` (``run_study``), ``report`` and ``plots``.
"""

from .report import write_report
from .runner import run_study
from .spec import Study, expand, load_spec, parse_spec, trials

__all__ = ["Study", "expand", "load_spec", "parse_spec", "run_study", "trials", "write_report"]
