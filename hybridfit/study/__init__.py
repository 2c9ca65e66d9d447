"""Declarative studies: sweep budgets, k, |P~| and plugins over a study's data, with seeds.

``spec`` (the schema), ``load`` (TOML -> validated ``Study``), ``expand`` (variants and
trials), ``data`` and ``cache`` (shared steps computed once, cached by content hash),
``executors`` (serial, process pool, dask), ``store`` (SQLite results), ``runner``
(``run_study``), ``report`` (tables from the store) and ``plots`` (figures from the report's
rows). Imports go one way: runner -> data, cache, executors, store; report -> plots, store.
"""

from .expand import expand, trials
from .load import load_spec, parse_spec
from .report import write_report
from .runner import run_study
from .spec import Study

__all__ = ["Study", "expand", "load_spec", "parse_spec", "run_study", "trials", "write_report"]
