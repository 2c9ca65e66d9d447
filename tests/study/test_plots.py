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
    assert set(series) == {"optimizer_config.schedule=joint", "optimizer_config.schedule=stepwise", "sweep"}
    assert [r["settings"]["budget"] for r in series["optimizer_config.schedule=joint"]] == [8281, 3400]
