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
