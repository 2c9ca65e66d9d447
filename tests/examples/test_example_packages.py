"""examples/hybridfit-{tripod-hand,numpy-objective,numpy-pso}: a third-party model, objective
and optimiser, each a real distribution installed offline into a temporary folder (as
``test_random_restart_package.py`` does), found by its entry point and run through the
conformance suite and a fit."""

import importlib
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PACKAGES = {  # folder: (kind, registered name, module)
    "hybridfit-tripod-hand": ("model", "tripod-hand", "hybridfit_tripod_hand"),
    "hybridfit-numpy-objective": ("objective", "numpy-clamped", "hybridfit_numpy_objective"),
    "hybridfit-numpy-pso": ("optimizer", "numpy-pso", "hybridfit_numpy_pso"),
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
    for name in [m for m in sys.modules if m.startswith(tuple(module for _, _, module in PACKAGES.values()))]:
        del sys.modules[name]
    importlib.invalidate_caches()
    registry.refresh()


CASES = [(kind, name, check) for kind, name, _ in PACKAGES.values() for check in testing.checks(kind)]


@pytest.mark.parametrize("kind, name, check", CASES, ids=[f"{n}-{c.__name__}" for _, n, c in CASES])
def test_passes_the_conformance_suite(installed, kind, name, check):
    assert name in registry.names(kind)
    check(registry.create(kind, name))


def test_the_numpy_objective_scores_frames_in_batches_and_fits_like_the_built_in(installed):
    from hybridfit.objective import capability

    objective = registry.create("objective", "numpy-clamped")
    assert capability(objective, "score_frames") is not None
    data = hybridfit.synthetic_proposals(6, k=3, seed=2)
    ours = hybridfit.fit(data["proposals"], data["confidences"], objective="numpy-clamped", budget=600, seed=1)
    built_in = hybridfit.fit(data["proposals"], data["confidences"], budget=600, seed=1)
    np.testing.assert_allclose(ours.params, built_in.params, rtol=0, atol=1e-6)


def test_the_numpy_objective_keeps_aligned_buffers_per_thread_and_scores_like_fresh_ones(installed):
    """clamped_loss's kept scratch: on a cache line, one set per thread, and a call after a
    larger or smaller one (or beside one on another thread) scores as a first call does."""
    import threading

    from hybridfit_numpy_objective import clamped_loss, kept

    assert kept("probe", 1000).ctypes.data % 64 == 0
    rng = np.random.default_rng(4)

    def batch(F, N, m):
        proposals = rng.normal(0.0, 30.0, (F, m, 3, 3))
        points = proposals[:, None, :, 0] + rng.normal(0.0, 20.0, (F, N, m, 3))
        return testing.frames_arguments(points, np.arange(m), proposals, rng.random((F, m, 3)))

    batches = [batch(40, 29, 21), batch(7, 19, 3), batch(40, 28, 6)]
    first = [clamped_loss(p, q, w, 40.0) for p, _, q, w in batches]
    again = [clamped_loss(p, q, w, 40.0) for p, _, q, w in batches[::-1]][::-1]
    threaded = [None] * len(batches)

    def score(i):  # each thread's result must not change while the others run
        results = [clamped_loss(batches[i][0], batches[i][2], batches[i][3], 40.0) for _ in range(10)]
        threaded[i] = results[0] if all(np.array_equal(r, results[0]) for r in results) else None

    workers = [threading.Thread(target=score, args=(i,)) for i in range(len(batches))]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    for a, b, c in zip(first, again, threaded):
        np.testing.assert_array_equal(a, b)
        assert c is not None
        np.testing.assert_array_equal(a, c)


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
