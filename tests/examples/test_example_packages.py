"""examples/hybridfit-{tripod-hand,numpy-objective,numpy-pso}: a third-party model, objective
and optimiser, each a real distribution installed offline into a temporary folder (as
``test_random_restart_package.py`` does), found by its entry point and run through the
conformance suite and a fit."""

import importlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DOCS = Path(__file__).resolve().parents[2] / "docs" / "plugins.md"
PACKAGES = {  # folder: (module, ((kind, registered name), ...))
    "hybridfit-tripod-hand": ("hybridfit_tripod_hand", (("model", "tripod-hand"),)),
    "hybridfit-numpy-objective": ("hybridfit_numpy_objective", (("objective", "clamped-point"),
                                                                 ("objective", "numpy-clamped"))),
    "hybridfit-numpy-pso": ("hybridfit_numpy_pso", (("optimizer", "numpy-pso"),)),
}


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    target = tmp_path_factory.mktemp("site")
    for folder in PACKAGES:
        source = tmp_path_factory.mktemp("src") / folder  # setuptools builds in the source tree: use a copy
        shutil.copytree(EXAMPLES / folder, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
        subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                        "--no-index", "--target", str(target), str(source)], check=True, capture_output=True, text=True)
    sys.path.insert(0, str(target))
    importlib.invalidate_caches()
    registry.refresh()
    yield target
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.startswith(tuple(module for module, _ in PACKAGES.values()))]:
        del sys.modules[name]
    importlib.invalidate_caches()
    registry.refresh()


CASES = [(kind, name, check) for _, plugins in PACKAGES.values() for kind, name in plugins
         for check in testing.checks(kind)]


@pytest.mark.parametrize("kind, name, check", CASES, ids=[f"{n}-{c.__name__}" for _, n, c in CASES])
def test_passes_the_conformance_suite(installed, kind, name, check):
    assert name in registry.names(kind)
    check(registry.create(kind, name))


def test_the_per_point_objective_runs_compiled_and_fits_like_the_built_in(installed):
    """clamped-point is the paper's formula as a per-point function: the core compiles it into
    its loops (a valid point_loss) and fits as with the built-in clamped-confidence, the local
    stage's Levenberg-Marquardt steps taken on its derivatives too."""
    from hybridfit.objective import point_loss_of

    objective = registry.create("objective", "clamped-point")
    assert point_loss_of(objective) is not None
    data = hybridfit.synthetic_proposals(6, k=3, seed=2)
    ours = hybridfit.fit(data["proposals"], data["confidences"], objective="clamped-point", budget=600, seed=1)
    built_in = hybridfit.fit(data["proposals"], data["confidences"], objective="clamped-confidence", budget=600,
                             seed=1)
    local = json.loads(ours.schedule)[0]["stages"][-1]
    assert (local["name"], local["optimizer"]["name"], local["objective"]["name"]) == (
        "local", "levenberg-marquardt", "clamped-point")
    np.testing.assert_allclose(ours.params, built_in.params, rtol=0, atol=1e-6)


def test_the_numpy_objective_is_bind_only_and_scores_like_the_per_point_one(installed):
    from hybridfit.objective import normalise_confidences, point_loss_of

    numpy_clamped = registry.create("objective", "numpy-clamped", {"d_max_mm": 30.0})
    per_point = registry.create("objective", "clamped-point", {"d_max_mm": 30.0})
    assert point_loss_of(numpy_clamped) is None
    rng = np.random.default_rng(4)
    Q, K, N = 9, 3, 17
    proposals = rng.normal(0.0, 30.0, (Q, K, 3))
    weights = normalise_confidences(rng.random((Q, K)) * (rng.random((Q, 1)) > 0.2))  # some points without any
    points = proposals[None, :, 0] + rng.normal(0.0, 25.0, (N, Q, 3))
    for subset in (np.arange(Q), np.array([1, 4, 7]), np.array([5])):
        want = per_point.bind(proposals, weights)(points, subset)
        np.testing.assert_allclose(numpy_clamped.bind(proposals, weights)(points, subset), want, rtol=1e-12,
                                   atol=1e-12)
    # bind only: no derivatives to take, so the default schedule's local stage is gradient-free
    # (the PSO refiner, its swarm started near the fit); the built-in objective with that local stage
    data = hybridfit.synthetic_proposals(3, k=3, seed=2)
    fit = hybridfit.fit(data["proposals"], data["confidences"], objective="numpy-clamped", budget=600, seed=1)
    local = json.loads(fit.schedule)[0]["stages"][-1]
    assert (local["name"], local["optimizer"]["name"]) == ("local", "pso") and (fit.evaluations == 600).all()
    built_in = hybridfit.fit(data["proposals"], data["confidences"], objective="clamped-confidence", budget=600,
                             seed=1, optimizer_config={"local_optimizer": "pso",
                                                       "local_config": {"init_share": 1.0, "init_sigma": 0.02}})
    np.testing.assert_allclose(fit.params, built_in.params, rtol=0, atol=1e-6)


def test_the_complete_objective_of_the_plugin_guide_runs_and_passes_the_suite(tmp_path):
    """docs/plugins.md's complete per-point objective, run as a user's script (numba caches its
    function beside the file), then its objective through the conformance suite."""
    import re

    code = next(block for block in re.findall(r"```python\n(.*?)```", DOCS.read_text(), re.S)
                if "def point_loss" in block and "hybridfit.fit(" in block)
    script = tmp_path / "my_objective.py"
    script.write_text(code)
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    sys.path.insert(0, str(tmp_path))
    try:
        import my_objective

        testing.check_objective(my_objective.ClampedPoint())
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("my_objective", None)


def test_the_numpy_optimizer_runs_stepwise_and_fits(installed):
    data = hybridfit.synthetic_proposals(6, k=3, seed=3)
    fit = hybridfit.fit(data["proposals"], data["confidences"], budget=1200, seed=0, optimizer="stepwise",
                        optimizer_config={"optimizer": "numpy-pso", "refine_share": 0.25})
    assert not fit.failed.any() and (fit.evaluations == 1200).all()
    error = np.linalg.norm(fit.model_joints - data["ground_truth"], axis=-1).mean()
    assert error < 20.0


def test_the_model_is_fitted_to_its_own_synthetic_proposals(installed):
    model = registry.create("model", "tripod-hand")
    data = hybridfit.synthetic_proposals(4, k=3, seed=1, model=model)
    fit = hybridfit.fit(data["proposals"], data["confidences"], model="tripod-hand", budget=1500, seed=0)
    assert not fit.failed.any()
    assert np.linalg.norm(fit.model_joints - data["ground_truth"], axis=-1).mean() < 20.0
