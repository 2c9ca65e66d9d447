"""examples/hybridfit-random-restart: a real third-party plugin distribution.

It is pip-installed (offline: no dependencies, no build isolation) into a temporary
folder put on this interpreter's path, never into the environment itself, so the
environment is left as it was even if the test dies; the registry then finds it by its
entry point like any installed plugin.
"""

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.cli import main

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "hybridfit-random-restart"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    target = tmp_path_factory.mktemp("site")
    source = tmp_path_factory.mktemp("src") / EXAMPLE.name  # setuptools builds in the source tree: use a copy
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
         "--target", str(target), str(source)],
        check=True, capture_output=True, text=True,
    )
    sys.path.insert(0, str(target))
    importlib.invalidate_caches()
    registry.refresh()
    yield target
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.startswith("hybridfit_random_restart")]:
        del sys.modules[name]
    importlib.invalidate_caches()
    registry.refresh()


def test_registered_and_listed(installed, capsys):
    assert "random-restart" in registry.names("optimizer")
    assert main(["plugins"]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "random-restart" in ln)
    assert "[hybridfit-random-restart]" in line and "FAILED" not in line
    # a fresh interpreter sees it too
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", "from hybridfit.cli import main; main(['plugins'])"],
                         env=env, capture_output=True, text=True, check=True).stdout
    assert "random-restart" in out


@pytest.mark.parametrize("check", testing.checks("optimizer"), ids=lambda c: c.__name__)
def test_passes_the_conformance_suite(installed, check):
    check(registry.create("optimizer", "random-restart"))


def test_fit_from_the_command_line(installed, tmp_path, capsys):
    data = hybridfit.synthetic_proposals(3, seed=4)
    np.savez(tmp_path / "frames.npz", **data)
    code = main(["fit", str(tmp_path / "frames.npz"), "--out", str(tmp_path / "fit.npz"),
                 "--optimizer", "random-restart", "--budget", "400"])
    assert code == 0 and "fitted 3/3 frames" in capsys.readouterr().out
    with np.load(tmp_path / "fit.npz") as fit:
        assert (fit["evaluations"] == 400).all() and np.isfinite(fit["joints"]).all()


def test_stepwise_wraps_it(installed):
    data = hybridfit.synthetic_proposals(1, seed=5)
    fit = hybridfit.fit(data["proposals"], data["confidences"], budget=600,
                        optimizer="stepwise", optimizer_config={"optimizer": "random-restart"})
    assert not fit.failed.any() and fit.evaluations[0] == 600
