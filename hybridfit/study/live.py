"""A running study, mirrored into an Optuna storage as each trial finishes.

``hybridfit study S.toml --out DIR --optuna-storage URL`` records every finished trial in the
Optuna study named after the study (``name``), so ``optuna-dashboard URL`` shows it while it
runs. ``study.db`` stays the source of truth (resume, the report); the mirror only adds:

- params: the variant's swept settings (dotted keys, as in ``[sweep.grid]``), its ``variant``
  name and the ``seed``; each param's distribution spans the values the study sweeps (a
  range for numbers, the choices for anything else), so the dashboard can compare them;
- value: the trial's mean joint error (mm), to minimise; a trial with no fitted frame, or
  one that failed, is recorded as a failed Optuna trial;
- user attrs: the other metrics of the report (median, fingertip and success rates,
  objective, evaluations, time per frame, failed frames), the trial key and the method.

A run first adds the trials ``study.db`` holds as finished and the storage does not (an
earlier run's, or one without the mirror), then each trial as it finishes; trials are matched
by their key, so the mirror of a study run in several goes holds each trial once. A storage
that fails during the run (a database server gone) is reported once and the study goes on:
the mirror is a view, never where results are kept.
"""

from __future__ import annotations

import json
import math
from typing import Any, Iterable

import numpy as np

from ..errors import HybridfitError
from ..optional import import_library
from .expand import Trial

REQUIREMENT = "optuna>=3.2"


def _flat(tree: dict, prefix: str = "") -> dict[str, Any]:
    out = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict) and value:
            out.update(_flat(value, name + "."))
        else:
            out[name] = value
    return out


def _param(value: Any) -> str | int | float | bool | None:
    """A value Optuna can hold as a param (lists and tables as JSON text)."""
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    return json.dumps(value, sort_keys=True, default=str)


def params_of(trial: Trial) -> dict[str, Any]:
    """The params a trial is recorded with (see the module docstring)."""
    return {**{k: _param(v) for k, v in _flat(trial.variant.overrides).items()},
            "variant": trial.variant.name, "seed": trial.seed}


def _exact(value):
    """An integer beyond float precision (a 64-bit seed) as text, which Optuna keeps exactly."""
    return str(value) if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 2**53 else value


def distributions_of(trials: Iterable[Trial], optuna) -> dict[str, Any]:
    """Each param's Optuna distribution over the values ``trials`` take."""
    seen: dict[str, set] = {}
    for t in trials:
        for k, v in params_of(t).items():
            seen.setdefault(k, set()).add(_exact(v))
    out = {}
    for name, values in seen.items():
        distinct = sorted(values, key=lambda v: (type(v).__name__, str(v)))
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in distinct)
        if numbers and len(distinct) > 1 and all(math.isfinite(v) for v in distinct):
            if all(isinstance(v, int) for v in distinct):
                out[name] = optuna.distributions.IntDistribution(min(distinct), max(distinct))
            else:
                out[name] = optuna.distributions.FloatDistribution(float(min(distinct)), float(max(distinct)))
        else:  # strings, tables, a single value
            out[name] = optuna.distributions.CategoricalDistribution(distinct)
    return out


class OptunaMirror:
    """Records finished trials of a study in the Optuna storage at ``url`` (see the module docstring)."""

    def __init__(self, url: str, study_name: str, trials: list[Trial], log=None):
        self.url, self.log, self.broken = url, log or (lambda message: None), False
        self.optuna = optuna = import_library("optuna", REQUIREMENT, "--optuna-storage")
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        try:
            self.study = optuna.create_study(storage=url, study_name=study_name, direction="minimize",
                                             load_if_exists=True)
        except Exception as err:  # a malformed URL, an unreachable server, a database of another kind
            raise HybridfitError(f"--optuna-storage {url}: cannot open the Optuna storage "
                                 f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from None
        if self.study.directions != [optuna.study.StudyDirection.MINIMIZE]:
            raise HybridfitError(f"--optuna-storage {url}: study {study_name!r} exists there and maximises; "
                                 "give another storage")
        self.distributions = distributions_of(trials, optuna)
        self.recorded = {t.user_attrs.get("hybridfit_key") for t in self.study.get_trials(deepcopy=False)}

    def add(self, trial: Trial, metrics: dict[str, float] | None, error: str | None = None) -> None:
        """Record ``trial`` with its report ``metrics`` (None with ``error`` when it failed)."""
        if trial.key in self.recorded:
            return
        optuna = self.optuna
        params = {k: _exact(v) for k, v in params_of(trial).items()}
        value = (metrics or {}).get("mean_error_mm", float("nan"))
        attrs = {"hybridfit_key": trial.key, "method": "fit"}
        attrs.update({k: (None if not np.isfinite(v) else float(v)) for k, v in (metrics or {}).items()
                      if k != "mean_error_mm"})
        if error is not None:
            attrs["error"] = str(error)[:2000]
        ok = error is None and np.isfinite(value)
        frozen = optuna.trial.create_trial(
            params=params, distributions={k: self.distributions[k] for k in params},
            value=float(value) if ok else None, user_attrs=attrs,
            state=optuna.trial.TrialState.COMPLETE if ok else optuna.trial.TrialState.FAIL)
        self.study.add_trial(frozen)
        self.recorded.add(trial.key)


    def backfill(self, trials: list[Trial], store) -> int:
        """Add the ``trials`` that ``store`` (a study.db) holds as complete and this storage
        does not; returns how many."""
        from .report import trial_metrics

        done = {row["key"]: row for row in store.trials("complete")}
        added = 0
        for t in trials:
            row = done.get(t.key)
            if row is not None and t.key not in self.recorded:
                self.add(t, trial_metrics(store.frames(row["id"]), row["joint_names"] or []))
                added += 1
        return added

    def finished(self, trial: Trial, result: dict | None, error) -> None:
        """Record a trial the run just stored (its ``result``, or the ``error`` it failed
        with); a storage error is logged once and ends the mirror, never the study."""
        if self.broken:
            return
        try:
            self.add(trial, metrics_of(result) if error is None else None,
                     None if error is None else str(error))
        except Exception as err:  # the storage, not the study: the run goes on
            self.broken = True
            self.log(f"--optuna-storage {self.url}: recording trials stopped ({type(err).__name__}: "
                     f"{str(err).splitlines()[0] if str(err) else ''}); study.db holds every result")


def metrics_of(result: dict) -> dict[str, float]:
    """The report's metrics (:func:`hybridfit.study.report.trial_metrics`) of a trial's result."""
    from .report import trial_metrics

    errors = np.asarray(result["errors"], float)
    frames = {"errors": errors, "objective": np.asarray(result["objective"], float),
              "evaluations": np.asarray(result["evaluations"], float),
              "time_s": np.full(len(errors), float(result["time_per_frame"]))}
    return trial_metrics(frames, result["joint_names"])
