"""The study's figures (matplotlib, PNG) from the aggregated rows of ``report.aggregate``.

success: success-rate curves per variant; k: error vs k, Oracle / top-1 / Optimised (the
paper's Fig. 3b); proposal_set: error vs |P~| (Fig. 3a); budget: error and time per frame vs
budget; variants: mean error per variant (e.g. stepwise vs joint at equal budget);
per_joint: mean error per joint. Error bars: standard deviation over seeds.

A variant has one colour in every figure of a study (:func:`variant_colours`, by its place in
the report's rows). The per-joint plot shows every variant but the Oracle, up to
``per_joint_variants`` (12 by default); any left out are named in its title.

Every name a figure draws (variants, joints) goes through :func:`_text`
(:func:`hybridfit.text.plain`): a ``$`` or TeX in a name is drawn as written, never parsed
as mathtext.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from ..io import atomic_open
from ..metrics import SUCCESS_THRESHOLDS_MM as THRESHOLDS
from ..text import plain

SWEEP_AXES = {"k": "proposals per joint k", "proposal_set": "|P~|: votes per joint into mean-shift",
              "budget": "budget (objective evaluations per frame)"}


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = json.dumps(v) if isinstance(v, (list, dict)) else v
    return out


def _varying(rows: list[dict], skip: str | None = None) -> list[str]:
    """Setting paths that differ between the fitted variants (except ``skip``)."""
    flats = [_flat(r["settings"]) for r in rows]
    keys = sorted({k for f in flats for k in f})
    return [k for k in keys if k != skip and len({str(f.get(k)) for f in flats}) > 1]


#: a setting in a variant's name as the study expands a grid: ``optimizer_config.schedule=joint``
_SETTING = re.compile(r"^([A-Za-z_]\w*(?:\.\w+)*)=(.*)$")


def _setting_words(key: str) -> str:
    """A setting's dotted key in words: ``optimizer_config.schedule`` -> 'optimizer schedule',
    ``optimizer_config.optimizer`` -> 'optimizer', ``search_radius_mm`` -> 'search radius mm'."""
    words: list[str] = []
    for part in key.split("."):
        part = part.removesuffix("_config").replace("_", " ")
        if not words or part != words[-1]:
            words.append(part)
    return " ".join(words)


def legend_label(variant: str) -> str:
    """A variant's name for a legend: as the study file names it, with the settings a grid adds to
    it (``optimizer_config.schedule=joint``) in words (``optimizer schedule: joint``)."""
    parts = []
    for part in variant.split(", "):
        m = _SETTING.match(part)
        parts.append(f"{_setting_words(m[1])}: {m[2]}" if m else part)
    return ", ".join(parts)


def _common_words(names: list[str]) -> str:
    """The words every name starts with ("joint" of "joint 91x91 (8281)" and "joint (3400)"),
    without a trailing bracket or punctuation; '' when they share none."""
    split = [n.split() for n in names]
    common = []
    for words in zip(*split):
        if len(set(words)) > 1:
            break
        common.append(words[0])
    while common and not common[-1].strip("([{,;:-+/"):
        common.pop()
    return " ".join(common).rstrip(",;:")


def _series(rows: list[dict], x: str) -> dict[str, list[dict]]:
    """Fitted variants grouped by their settings other than ``x``, labelled (in words, see
    :func:`legend_label`) with the variant name the study file gives (without the ``x=value`` part the
    sweep adds) when the group's variants share one, else with the words their names begin
    with ("joint" for "joint 91x91 (8281)" and "joint (3400)"), else with the settings that
    define the group."""
    vary = _varying(rows, x)
    members: dict[str, list[dict]] = {}
    for r in rows:
        f = _flat(r["settings"])
        members.setdefault(json.dumps([str(f.get(k)) for k in vary]), []).append(r)
    groups: dict[str, list[dict]] = {}
    for key, rs in members.items():
        names = list(dict.fromkeys(", ".join(p for p in r["variant"].split(", ") if not p.startswith(f"{x}="))
                                   for r in rs))
        defining = ", ".join(f"{k}={v}" for k, v in zip(vary, json.loads(key)) if v != "None")
        name = names[0] if len(names) == 1 else _common_words(names) or defining
        groups[legend_label(name) or "Optimised"] = rs
    return groups


def _text(name) -> str:
    """A name as matplotlib text: literal (no mathtext), characters UTF-8 cannot hold as escapes."""
    return plain(name, "utf-8")


def _subplots(*grid, figsize, **kwargs):
    """(figure, axes) of a standalone Figure: no pyplot state, and matplotlib's backend for
    the rest of the process is left alone (PNGs are written by the Agg canvas savefig picks)."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **kwargs)


#: the PNG text key listing the variants a figure draws (JSON), so a copy of it can be checked
#: against its study (``tests/test_docs.py`` does, for the docs' figures)
VARIANTS_KEY = "hybridfit variants"


def _save(fig, out: Path, name: str, rows: list[dict] | None = None) -> str:
    """Write the figure as ``out/name`` (PNG) atomically (:func:`hybridfit.io.atomic_open`),
    with the names of the variants it draws (``rows``) in its :data:`VARIANTS_KEY` text chunk."""
    from .. import __version__

    fig.tight_layout()
    metadata = {"Software": f"hybridfit {__version__}"}
    if rows is not None:
        metadata[VARIANTS_KEY] = json.dumps([str(r["variant"]) for r in rows], ensure_ascii=True)
    with atomic_open(out / name, "wb") as fh:
        fig.savefig(fh, format="png", dpi=110, metadata=metadata)
    return name


def variant_colours(rows: list[dict]) -> dict[str, tuple]:
    """{variant: colour}: one colour per variant for all of a study's figures, by its place in ``rows``."""
    palette = matplotlib.colormaps["tab20" if len(rows) > 10 else "tab10"].colors
    return {r["variant"]: palette[i % len(palette)] for i, r in enumerate(rows)}


def plot_success(out: Path, rows: list[dict]) -> str:
    fig, ax = _subplots(figsize=(10, 5))
    colours = variant_colours(rows)
    for r in rows:
        style = {"oracle": "--", "top1": ":"}.get(r["method"], "-")
        ax.plot(THRESHOLDS, r["curve"], style, color=colours[r["variant"]], lw=1.8,
                label=_text(legend_label(r["variant"])))
    ax.set(xlabel="distance threshold (mm)", ylabel="share of frames with all joints within threshold",
           title="Success rate (worst joint within threshold; dashed: Oracle, dotted: top-1)", xlim=(0, 80),
           ylim=(0, 1.01))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, out, "success_rate.png", rows)


def plot_sweep(out: Path, rows: list[dict], x: str, metric: str = "mean_error_mm") -> str:
    """Error (and for budgets time) against a swept setting; baselines as their own lines."""
    return _save(sweep_figure(rows, x, metric), out, f"error_vs_{x}.png")


def sweep_figure(rows: list[dict], x: str, metric: str = "mean_error_mm") -> Figure:
    """The figure of :func:`plot_sweep`."""
    fits = [r for r in rows if r["method"] == "fit"]
    panels = 2 if x == "budget" else 1
    fig, axes = _subplots(1, panels, figsize=(6.5 * panels, 4.8), squeeze=False)
    ax = axes[0, 0]
    for method, label, style in (("oracle", "Oracle (closest proposal)", "s--"),
                                 ("top1", "top-1 proposal (plain regression)", "^:")):
        b = sorted((r for r in rows if r["method"] == method), key=lambda r: r["settings"].get(x, 0))
        if not b:
            continue
        if x == "k" and method == "top1" or x == "budget":  # flat across x: a reference line
            ax.axhline(b[0][f"{metric}_mean"], color="grey" if method == "top1" else "black", ls=style[1:],
                       label=f"{label}: {b[0][f'{metric}_mean']:.1f} mm")
        elif x in b[0]["settings"]:
            ax.plot([r["settings"][x] for r in b], [r[f"{metric}_mean"] for r in b], style, label=label)
    for label, rs in _series(fits, x).items():
        rs = sorted(rs, key=lambda r: r["settings"][x])
        xs = [r["settings"][x] for r in rs]
        ax.errorbar(xs, [r[f"{metric}_mean"] for r in rs], yerr=[r[f"{metric}_std"] for r in rs], fmt="o-",
                    capsize=4, label=_text(label))
    ax.set(xlabel=SWEEP_AXES[x], ylabel="mean joint error (mm)", title=f"Mean joint error vs {SWEEP_AXES[x]}")
    ticks = sorted({r["settings"][x] for r in fits})
    for a in axes[0]:
        if x in ("budget", "proposal_set"):
            a.set_xscale("log")
            a.minorticks_off()
        a.set_xticks(ticks, [str(t) for t in ticks], fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if panels == 2:
        ax2 = axes[0, 1]
        for label, rs in _series(fits, x).items():
            rs = sorted(rs, key=lambda r: r["settings"][x])
            ms = np.array([1000 * r["time_per_frame_s_mean"] for r in rs])
            std = np.array([1000 * r["time_per_frame_s_std"] for r in rs])
            ax2.errorbar([r["settings"][x] for r in rs], ms, yerr=[np.minimum(std, ms), std], fmt="o-", capsize=4,
                         label=_text(label))  # a time is never below 0 ms
        ax2.set(xlabel=SWEEP_AXES[x], ylabel="time per frame (ms, one core)", title="Fitting time vs budget")
        ax2.grid(alpha=0.3)
        ax2.legend(fontsize=8)
    fig.tight_layout()
    for a in axes[0]:
        _share_close_ticks(fig, a, ticks)
    return fig


#: the least space between two x tick labels, pixels
TICK_GAP_PX = 4


def _share_close_ticks(fig, ax, ticks: list) -> None:
    """Label every x tick so that no two labels overlap: ticks too close for their labels to
    stand side by side (budgets 8281 and 8301 on a log axis) share one label, "8281/8301",
    at the first of them; the other keeps its tick mark."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    groups = [[t] for t in ticks]
    while True:
        text = {g[0]: "/".join(str(t) for t in g) for g in groups}
        ax.set_xticks(ticks, [text.get(t, "") for t in ticks], fontsize=8)
        canvas.draw()
        renderer = canvas.get_renderer()
        shown = {t.get_text(): t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_text()}
        boxes = [shown[text[g[0]]] for g in groups]
        close = [i for i in range(len(groups) - 1) if boxes[i].x1 + TICK_GAP_PX > boxes[i + 1].x0]
        if not close:
            return
        i = close[0]
        groups[i:i + 2] = [groups[i] + groups[i + 1]]


def plot_variants(out: Path, rows: list[dict]) -> str:
    """Horizontal bars: mean error per variant, success @40 mm written beside each bar."""
    fig, ax = _subplots(figsize=(8, 0.45 * len(rows) + 1.6))
    y = np.arange(len(rows))[::-1]
    colours = variant_colours(rows)
    means = [r["mean_error_mm_mean"] for r in rows]
    ax.barh(y, means, xerr=[r["mean_error_mm_std"] for r in rows], color=[colours[r["variant"]] for r in rows],
            hatch=["//" if r["method"] != "fit" else "" for r in rows], edgecolor="white", capsize=3)
    labels = [ax.text(m + max(means) * 0.02 + r["mean_error_mm_std"], yi, f"{m:.1f} mm, success@40 "
                      f"{r['success_40mm_mean']:.2f}", va="center", fontsize=7) for yi, r, m in zip(y, rows, means)]
    ax.set_yticks(y, [_text(legend_label(r["variant"])) for r in rows], fontsize=7)
    ax.set(xlabel="mean joint error (mm)", title="Mean joint error per variant (error bars: std over seeds; "
           "hatched: baselines)",
           xlim=(0, max(means) * 1.45))
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    _fit_labels(fig, ax, labels)
    return _save(fig, out, "variants.png", rows)


def _fit_labels(fig, ax, labels) -> None:
    """Widen the x axis (from 0) so that every label written beside a bar ends inside the
    axes: a label starting at x (data) and w pixels wide needs x / hi * W + w <= W for an
    axes W pixels wide, so hi >= x * W / (W - w); a label wider than 90 % of the axes gets
    one tenth of them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    renderer = FigureCanvasAgg(fig).get_renderer()
    width = ax.get_window_extent(renderer).width
    lo, hi = ax.get_xlim()
    for label in labels:
        start, w = label.get_position()[0], label.get_window_extent(renderer).width
        hi = max(hi, start * width / max(width - w, 0.1 * width) * 1.02)
    ax.set_xlim(lo, hi)


def plot_per_joint(out: Path, rows: list[dict], limit: int) -> str:
    """Bars per joint for every variant but the Oracle, up to ``limit``; the title names any left out."""
    candidates = [r for r in rows if r["method"] != "oracle"]
    shown, left_out = candidates[:limit], candidates[limit:]
    names = shown[0]["joint_names"]
    colours = variant_colours(rows)
    fig, ax = _subplots(figsize=(min(16.0, max(8.0, 0.1 * len(names) * len(shown) + 4)), 5.2))
    width = 0.8 / len(shown)
    for i, r in enumerate(shown):
        ax.bar(np.arange(len(names)) + (i - (len(shown) - 1) / 2) * width, r["per_joint"], width,
               color=colours[r["variant"]], label=_text(legend_label(r["variant"])))
    ax.set_xticks(np.arange(len(names)), [_text(n) for n in names], rotation=60, ha="right", fontsize=8)
    title = "Mean error per joint"
    if left_out:
        title += (f"\n(not shown, per_joint_variants = {limit}: "
                  + "; ".join(_text(legend_label(r["variant"])) for r in left_out) + ")")
    ax.set(ylabel="mean error (mm)", title=title)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, out, "per_joint.png", shown)


def make_plots(out: Path, rows: list[dict], spec=None) -> list[tuple[str, str]]:
    """Write the requested (or applicable) plots; returns (title, file name) pairs."""
    fits = [r for r in rows if r["method"] == "fit"]
    if not fits:
        return []
    wanted = "auto" if spec is None else spec.plots
    limit = 12 if spec is None else spec.per_joint_variants
    distinct = {x: len({r["settings"].get(x) for r in fits}) for x in SWEEP_AXES}
    if wanted == "auto":
        wanted = ["success", *[x for x in SWEEP_AXES if distinct[x] > 1], "variants", "per_joint"]
    figures = []
    for p in wanted:
        if p == "success":
            figures.append(("Success rate", plot_success(Path(out), rows)))
        elif p in SWEEP_AXES and distinct[p] > 1:
            figures.append((f"Error vs {SWEEP_AXES[p]}", plot_sweep(Path(out), rows, p)))
        elif p == "variants":
            figures.append(("Mean error per variant", plot_variants(Path(out), rows)))
        elif p == "per_joint":
            figures.append(("Error per joint", plot_per_joint(Path(out), rows, limit)))
    return figures
