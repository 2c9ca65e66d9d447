"""Study plots leave matplotlib's backend to the process that imports them."""

import subprocess
import sys


def test_importing_and_plotting_keeps_the_process_backend(tmp_path):
    code = f"""
import matplotlib
matplotlib.use("svg")
from pathlib import Path
from hybridfit.study import plots
from hybridfit.metrics import SUCCESS_THRESHOLDS_MM as THRESHOLDS
rows = [{{"method": "fit", "curve": [0.5] * len(THRESHOLDS), "variant": "a"}}]
name = plots.plot_success(Path({str(tmp_path)!r}), rows)
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
print(name)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    png = tmp_path / done.stdout.strip()
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_labels_beside_the_bars_end_inside_the_axes():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from hybridfit.study import plots

    fig = Figure(figsize=(6, 3))
    ax = fig.subplots()
    ax.barh([0, 1], [14.0, 3.0])
    ax.set_xlim(0, 15)
    labels = [ax.text(14.5, 0, "14.0 mm, success@40 0.35 and a long tail"), ax.text(3.5, 1, "3.0 mm")]
    renderer = FigureCanvasAgg(fig).get_renderer()
    assert labels[0].get_window_extent(renderer).x1 > ax.get_window_extent(renderer).x1  # starts outside
    plots._fit_labels(fig, ax, labels)
    renderer = FigureCanvasAgg(fig).get_renderer()
    assert all(label.get_window_extent(renderer).x1 <= ax.get_window_extent(renderer).x1 + 0.5 for label in labels)


def test_a_series_of_differently_named_variants_is_labelled_by_its_settings():
    """Variants named with their budget ("joint (3400)", "joint (8281)") form one line of the
    budget plot; its label must not be the first variant's name, which quotes one budget."""
    from hybridfit.study import plots

    def row(name, budget, schedule):
        return {"variant": name, "settings": {"budget": budget, "optimizer_config": {"schedule": schedule}}}

    rows = [row("joint (8281)", 8281, "joint"), row("joint (3400)", 3400, "joint"),
            row("stepwise (3400)", 3400, "stepwise"), row("stepwise (8301)", 8301, "stepwise"),
            row("sweep, budget=300", 300, "refined"), row("sweep, budget=600", 600, "refined")]
    series = plots._series(rows, "budget")
    assert set(series) == {"joint", "stepwise", "sweep"}  # the words the names share
    assert [r["settings"]["budget"] for r in series["joint"]] == [8281, 3400]
    rows[1]["variant"] = "all at once (3400)"  # names that share no words: the settings, in words
    assert set(plots._series(rows, "budget")) == {"optimizer schedule: joint", "stepwise", "sweep"}


def _row(variant, budget, schedule, error=5.0, ms=1.0, **settings):
    return {"method": "fit", "variant": variant, "settings": {"budget": budget, "optimizer_config": {"schedule": schedule},
                                                               **settings},
            "mean_error_mm_mean": error, "mean_error_mm_std": 0.2, "time_per_frame_s_mean": ms / 1000,
            "time_per_frame_s_std": 0.1 / 1000}


def _legend(ax) -> list[str]:
    return [t.get_text() for t in ax.get_legend().get_texts()]


def test_legends_show_the_variants_names_or_their_settings_in_words():
    """A grid's variants are named by their settings (budget.toml: "budget=300,
    optimizer_config.schedule=joint"); no legend shows such an internal key (issue 32)."""
    from hybridfit.study import plots

    rows = [_row(f"budget={b}, optimizer_config.schedule={s}", b, s) for b in (300, 1200) for s in ("stepwise", "joint")]
    fig = plots.sweep_figure(rows, "budget")
    for ax in fig.axes:
        assert sorted(_legend(ax)) == ["optimizer schedule: joint", "optimizer schedule: stepwise"]
    assert plots.legend_label("budget=300, optimizer_config.optimizer=cmaes") == "budget: 300, optimizer: cmaes"
    assert plots.legend_label("stepwise (3400, the paper's)") == "stepwise (3400, the paper's)"
    assert plots.legend_label("k=3, model_config.scale=1.05") == "k: 3, model scale: 1.05"


def test_close_budgets_share_one_tick_label_and_no_labels_overlap():
    """stepwise_vs_joint's budgets 3400, 8281 and 8301: 8281 and 8301 printed on top of each other
    on the log axis (issue 32)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from hybridfit.study import plots

    rows = [_row("joint 91x91 (8281)", 8281, "joint"), _row("stepwise (8301)", 8301, "stepwise", stage_weights=[4]),
            _row("joint (3400)", 3400, "joint"), _row("stepwise (3400)", 3400, "stepwise")]
    fig = plots.sweep_figure(rows, "budget")
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.canvas.draw()
    for ax in fig.axes:
        labels = [t for t in ax.get_xticklabels() if t.get_text()]
        assert [t.get_text() for t in labels] == ["3400", "8281/8301"]
        boxes = sorted((t.get_window_extent(renderer) for t in labels), key=lambda b: b.x0)
        assert all(a.x1 < b.x0 for a, b in zip(boxes, boxes[1:]))
        assert [round(t) for t in ax.get_xticks()] == [3400, 8281, 8301]  # every budget keeps its tick
    wide = [_row(f"budget={b}", b, "joint") for b in (300, 600, 1200, 2400, 3400, 6800, 13600)]
    ax = plots.sweep_figure(wide, "budget").axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["300", "600", "1200", "2400", "3400", "6800", "13600"]


def _study_rows(n_fits=8, joints=("wrist", "thumb_tip", "index_tip")):
    """Report rows as aggregate gives them: Oracle and top-1 baselines, then n_fits variants."""
    import numpy as np

    from hybridfit.metrics import SUCCESS_THRESHOLDS_MM as THRESHOLDS

    def row(name, method, i):
        return {"variant": name, "method": method, "settings": {"budget": 400}, "curve": np.linspace(0, 1, len(THRESHOLDS)),
                "per_joint": np.full(len(joints), 5.0 + i), "joint_names": list(joints),
                "mean_error_mm_mean": 5.0 + i, "mean_error_mm_std": 0.1, "success_40mm_mean": 0.5}

    return ([row("Oracle (k=3)", "oracle", 0), row("top-1 (k=3)", "top1", 1)]
            + [row(f"variant {i}", "fit", i) for i in range(n_fits)])


def _figures(monkeypatch, tmp_path, rows, limit=12):
    """{file: figure} of the success, variants and per-joint plots of ``rows``."""
    from hybridfit.study import plots

    made = {}
    monkeypatch.setattr(plots, "_save", lambda fig, out, name, rows=None: made.setdefault(name, fig) and name)
    plots.plot_success(tmp_path, rows)
    plots.plot_variants(tmp_path, rows)
    plots.plot_per_joint(tmp_path, rows, limit)
    return made


def test_the_per_joint_plot_shows_every_variant_or_names_those_left_out(monkeypatch, tmp_path):
    """The stepwise-vs-joint study has 8 variants; the per-joint plot dropped two of them, the
    CLI's default among them, without a word (issue 40)."""
    rows = _study_rows(8)
    ax = _figures(monkeypatch, tmp_path, rows)["per_joint.png"].axes[0]
    assert _legend(ax) == ["top-1 (k=3)", *(f"variant {i}" for i in range(8))]  # all but the Oracle
    assert "not shown" not in ax.get_title()
    ax = _figures(monkeypatch, tmp_path, rows, limit=6)["per_joint.png"].axes[0]
    assert len(_legend(ax)) == 6 and ax.get_title().endswith("variant 5; variant 6; variant 7)")
    assert "not shown, per_joint_variants = 6" in ax.get_title()


def test_a_variant_keeps_its_colour_in_every_plot(monkeypatch, tmp_path):
    from matplotlib.colors import to_rgb

    rows = _study_rows(8)
    figs = _figures(monkeypatch, tmp_path, rows)
    success = {line.get_label(): to_rgb(line.get_color()) for line in figs["success_rate.png"].axes[0].get_lines()}
    per_joint = figs["per_joint.png"].axes[0]
    bars = {c.get_label(): to_rgb(c.patches[0].get_facecolor()) for c in per_joint.containers}
    variants = figs["variants.png"].axes[0]
    labels = [t.get_text() for t in variants.get_yticklabels()]
    ys = list(variants.get_yticks())
    barh = {labels[ys.index(round(p.get_y() + p.get_height() / 2))]: to_rgb(p.get_facecolor())
            for p in variants.patches}
    for r in rows:
        name = r["variant"]
        assert barh[name] == success[name], name
        if r["method"] != "oracle":
            assert bars[name] == success[name], name
    assert len(set(success.values())) == len(rows)  # and no two variants share one
