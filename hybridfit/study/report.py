"""Reports from the study database: ``results.csv``, ``results.json``, ``report.md`` and the plots.

Everything is computed from ``study.db`` alone, so a report can be regenerated at any time
(``hybridfit study FILE --report-only``). Per trial (one seed): mean joint error over all
frames and joints, median of the frames' mean errors, fingertip error, success rates (share
of frames whose worst joint is within 20/40/80 mm; failed frames count as failures), mean
objective, evaluations and time per frame. Per variant: the mean and standard deviation
(ddof = 1; 0 for one seed) of these over the seeds.

``results.json`` is the study's record, the one a results page is rendered from: the
hybridfit version, machine, date and command of the run that measured the trials, the
report's table as shown (``tables``: Markdown, names escaped) and every variant's settings
and metrics (``variants``, as in ``results.csv``, names as written).

Names (the study's, variants', grid values, errors) are the user's text: report.md shows them
inert (:func:`hybridfit.text.markdown`: no tag, link, heading or table break), results.csv
holds no formula (:func:`hybridfit.text.csv_cell`), the plots draw them as plain text.
"""

from __future__ import annotations

import csv
import json
import os
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np

from ..io import atomic_open
from ..metrics import SUCCESS_THRESHOLDS_MM as THRESHOLDS
from ..metrics import fingertips, success_rate
from ..text import csv_cell, markdown
from .spec import METRICS, Study
from . import plots
from .store import DB_NAME, Store, storage_error

LABELS = {"mean_error_mm": "mean error (mm)", "median_error_mm": "median frame error (mm)",
          "fingertip_error_mm": "fingertip error (mm)", "success_20mm": "success @20 mm",
          "success_40mm": "success @40 mm", "success_80mm": "success @80 mm", "objective": "objective",
          "evaluations": "evaluations", "time_per_frame_s": "time per frame (ms)", "failed_frames": "failed frames"}


def trial_metrics(frames: dict[str, np.ndarray], joint_names) -> dict[str, float]:
    """The metrics of one trial from its frames (see the module docstring)."""
    e = frames["errors"]
    tips = fingertips(joint_names)
    ok = np.isfinite(e).all(axis=1)
    s = success_rate(e, (20, 40, 80))
    nan = float("nan")
    return {
        "mean_error_mm": float(np.nanmean(e)) if ok.any() else nan,
        "median_error_mm": float(np.median(e[ok].mean(axis=1))) if ok.any() else nan,
        "fingertip_error_mm": float(np.nanmean(e[:, tips])) if tips and ok.any() else nan,
        "success_20mm": float(s[0]), "success_40mm": float(s[1]), "success_80mm": float(s[2]),
        "objective": float(np.nanmean(frames["objective"])) if np.isfinite(frames["objective"]).any() else nan,
        "evaluations": float(np.mean(frames["evaluations"])),
        "time_per_frame_s": float(np.mean(frames["time_s"])),
        "failed_frames": float(np.sum(~ok)),
    }


def aggregate(store: Store) -> list[dict[str, Any]]:
    """One dict per variant (baselines first, then the sweep in order): its name, method,
    settings, seeds, frames, ``<metric>_mean`` / ``<metric>_std``, the success curve
    (``curve``, over ``THRESHOLDS``), per-joint mean errors and joint names."""
    groups: dict[str, list[dict]] = {}
    keys = store.get_meta("trial_keys", list)
    keys = None if keys is None else set(keys)
    labels = store.get_meta("trial_labels", dict) or {}
    for t in store.trials("complete"):
        if keys is not None and t["key"] not in keys:
            continue  # from an earlier version of the study file
        if t["key"] in labels:  # the current study file names it (it may have been run by another)
            t = {**t, "variant": labels[t["key"]][0], "variant_index": labels[t["key"]][1]}
        groups.setdefault(t["variant"], []).append(t)
    rows = []

    def order(g):
        t = g[1][0]
        return t["variant_index"], t["method"], t["settings"].get("k", 0), t["settings"].get("proposal_set", 0), g[0]

    for name, ts in sorted(groups.items(), key=order):
        per_seed, curves, joints, frames_n = [], [], [], 0
        names = ts[0]["joint_names"] or []
        for t in ts:
            fr = store.frames(t["id"])
            per_seed.append(trial_metrics(fr, names))
            curves.append(success_rate(fr["errors"], THRESHOLDS))
            with np.errstate(all="ignore"):
                joints.append(np.nanmean(fr["errors"], axis=0))
            frames_n = len(fr["errors"])
        row = {"variant": name, "method": ts[0]["method"], "settings": ts[0]["settings"],
               "variant_index": ts[0]["variant_index"], "seeds": len(ts), "frames": frames_n,
               "curve": np.mean(curves, axis=0), "per_joint": np.nanmean(joints, axis=0), "joint_names": names}
        for m in METRICS:
            v = np.array([p[m] for p in per_seed], float)
            row[f"{m}_mean"] = float(np.mean(v))
            row[f"{m}_std"] = float(np.std(v, ddof=1)) if len(v) > 1 else 0.0
        rows.append(row)
    return rows


def _setting(row: dict, key: str) -> Any:
    s = row["settings"]
    if key == "optimizer_config":
        return json.dumps(s.get(key, {}), sort_keys=True) if row["method"] == "fit" else ""
    return s.get(key, "")


CSV_SETTINGS = ("k", "proposal_set", "budget", "model", "objective", "optimizer", "optimizer_config")


def write_csv(path: Path, rows: list[dict]) -> None:
    header = ["variant", "method", *CSV_SETTINGS, "seeds", "frames"] + [f"{m}_{s}" for m in METRICS
                                                                         for s in ("mean", "std")]
    with atomic_open(path, "w", newline="", encoding="utf-8", errors="backslashreplace") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for r in rows:
            w.writerow([csv_cell(r["variant"]), r["method"], *(csv_cell(_setting(r, k)) for k in CSV_SETTINGS),
                        r["seeds"], r["frames"]] + [f"{r[f'{m}_{s}']:.6g}" for m in METRICS for s in ("mean", "std")])


def _cell(r: dict, m: str) -> str:
    mean, std = r[f"{m}_mean"], r[f"{m}_std"]
    if not np.isfinite(mean):
        return "-"
    if m == "time_per_frame_s":  # shown in ms, as in the plots (results.csv keeps seconds)
        mean, std = 1000 * mean, 1000 * std
    digits = 3 if m.startswith("success") else 2
    f = f"{mean:.{digits}f}"
    return f + (f" ± {std:.{digits}f}" if r["seeds"] > 1 else "")


def write_report(out: str | os.PathLike, study: Study | None = None) -> Path:
    """Write results.csv, the plots and report.md into ``out`` from its study.db; returns report.md.

    Each file is written atomically through :func:`hybridfit.io.atomic_open` (a temporary file
    made exclusively under a random name, then renamed into place): no link planted in the
    folder, at a temporary or a final name, is ever written through."""

    out = Path(out)
    store = Store(out / DB_NAME)
    try:
        rows = aggregate(store)
        meta = store.get_meta("study", dict) or {}
        measured = store.get_meta("measured", dict) or {}
        keys = set(store.get_meta("trial_keys", list) or [])
        failed = [t for t in store.trials("failed") + store.trials("running") if not keys or t["key"] in keys]
    except sqlite3.Error as err:  # locked, damaged: one line naming the database
        failure = storage_error(out / DB_NAME, err)
        if failure is None:
            raise
        raise failure from None
    finally:
        store.close()
    write_csv(out / "results.csv", rows)
    spec = study.report if study is not None else None
    figures = plots.make_plots(out, rows, spec)
    metrics = spec.metrics if spec is not None else ["mean_error_mm", "fingertip_error_mm", "success_20mm",
                                                     "success_40mm", "success_80mm", "time_per_frame_s"]
    lines = [f"# Study: {markdown(meta.get('name', '?'))}", ""]
    if meta.get("description"):
        lines += [*(markdown(line) for line in str(meta["description"]).strip().splitlines()), ""]
    data = (meta.get("spec") or {}).get("data", {})
    lines += [f"Data: `{data.get('kind', '?')}`; {rows[0]['frames'] if rows else 0} frames per trial. "
              "Values are means over seeds ± their standard deviation; errors in mm over all frames and joints; "
              "success @t = share of frames whose worst joint is within t mm. Oracle = the proposal closest to "
              "the truth per joint; top-1 proposal = the most confident proposal (plain regression).", ""]
    head = ["variant", "seeds", *[LABELS.get(m, m) for m in metrics]]
    cells = [[markdown(r["variant"]), str(r["seeds"]), *(_cell(r, m) for m in metrics)] for r in rows]
    lines += ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    lines += ["| " + " | ".join(c) + " |" for c in cells]
    lines += ["", "All metrics (mean and std per variant): [results.csv](results.csv)", ""]
    if failed:
        lines += ["## Failed or unfinished trials", ""]
        lines += [f"- {markdown(t['variant'])}, seed {t['seed']}: {t['state']}: {markdown(t['error'] or '')}"
                  for t in failed]
        lines.append("")
    for title, name in figures:
        lines += [f"## {title}", "", f"![{title}]({name})", ""]
    path = out / "report.md"
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))
    write_record(out / "results.json", meta, measured, {"columns": head, "rows": cells}, rows)
    return path


def write_record(path: Path, meta: dict, measured: dict, table: dict, rows: list[dict]) -> None:
    """``results.json`` (see the module docstring): the report's ``table`` (its columns and
    the cells of its rows) and the aggregated ``rows``."""
    variants = [{"variant": r["variant"], "method": r["method"], **{k: _setting(r, k) for k in CSV_SETTINGS},
                 "seeds": r["seeds"], "frames": r["frames"],
                 **{f"{m}_{s}": r[f"{m}_{s}"] if np.isfinite(r[f"{m}_{s}"]) else None for m in METRICS
                    for s in ("mean", "std")}} for r in rows]
    record = {"name": meta.get("name"), **{k: measured.get(k) for k in ("version", "machine", "date", "command")},
              "tables": {"results": table}, "variants": variants}
    with atomic_open(path, "w") as fh:
        fh.write(json.dumps(record, indent=1) + "\n")
