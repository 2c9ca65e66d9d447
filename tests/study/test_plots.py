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
