"""`hybridfit train / propose / estimate` accept ICVL, NYU and MSRA folders directly.

Readers, the forest, the fit and the output files all use camera coordinates (y down, z
forward), so the outputs compare point for point with the readers' annotations.
"""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit.cli import main
from hybridfit.datasets import open_dataset


@pytest.mark.parametrize("folder", ["icvl_dir", "nyu_dir", "msra_dir"])
def test_train_propose_estimate_on_a_real_folder(folder, request, tmp_path):
    data = request.getfixturevalue(folder)
    ds = open_dataset(data)
    forest, proposals, fits = tmp_path / "forest.npz", tmp_path / "p.npz", tmp_path / "f.npz"
    small = ["--trees", "1", "--max-depth", "8", "--pixels-per-frame", "60", "--seed", "1"]
    assert main(["train", str(data), "--out", str(forest), *small]) == 0
    assert main(["propose", str(forest), str(data), "--out", str(proposals), "-k", "2", "--proposal-set", "50"]) == 0
    with np.load(proposals) as p:
        assert p["proposals"].shape == (len(ds), len(ds.joint_names), 2, 3)
        assert list(p["joint_names"]) == ds.joint_names
        np.testing.assert_allclose(p["ground_truth"], ds.joints_xyz)
        # trained on these very frames: the best proposal lies near the annotation, both in
        # camera coordinates (a sign error would put it hundreds of mm away)
        best = np.linalg.norm(p["proposals"] - p["ground_truth"][:, :, None], axis=-1).min(-1)
        assert np.median(best) < 25.0, np.median(best)
    assert main(["estimate", str(forest), str(data), "--out", str(fits), "--budget", "300", "-k", "2"]) == 0
    with np.load(fits) as f:
        assert f["joints"].shape == (len(ds), len(ds.joint_names), 3)
        assert np.median(np.linalg.norm(f["joints"] - ds.joints_xyz, axis=-1)) < 40.0


@pytest.mark.parametrize("folder,dataset", [("icvl_dir", "icvl"), ("nyu_dir", "nyu"), ("msra_dir", "msra")])
def test_propose_then_fit_is_estimate(folder, dataset, request, tmp_path):
    """`propose` + `fit` fits the very frames `estimate` fits: the same proposals, the same
    poses bit for bit (same seed and budget), in the same coordinates; `fit` takes the
    dataset (its derived points) from the proposals file."""
    data = request.getfixturevalue(folder)
    forest, proposals = tmp_path / "forest.npz", tmp_path / "p.npz"
    two_step, one_step = tmp_path / "fit.npz", tmp_path / "estimate.npz"
    small = ["--trees", "1", "--max-depth", "8", "--pixels-per-frame", "60", "--seed", "1"]
    assert main(["train", str(data), "--out", str(forest), *small]) == 0
    fit_options = ["--budget", "200", "--seed", "3"]
    assert main(["propose", str(forest), str(data), "--out", str(proposals), "-k", "2"]) == 0
    assert main(["fit", str(proposals), "--out", str(two_step), *fit_options]) == 0  # the npz names its dataset
    assert main(["estimate", str(forest), str(data), "--out", str(one_step), "-k", "2", *fit_options]) == 0
    with np.load(proposals) as p, np.load(two_step) as a, np.load(one_step) as b:
        np.testing.assert_array_equal(p["proposals"], b["proposals"])
        np.testing.assert_array_equal(p["ground_truth"], b["ground_truth"])
        np.testing.assert_array_equal(a["params"], b["params"])
        np.testing.assert_array_equal(a["joints"], b["joints"])


def test_a_study_runs_on_a_real_folder(nyu_dir, tmp_path):
    """The study's dataset kind reads any data set through the one protocol: NYU folders
    train the forest, give proposals and ground truth, and trials fit its derived points."""
    from hybridfit.study import parse_spec, run_study

    spec = {"name": "nyu", "seeds": 1,
            "data": {"kind": "dataset", "test": str(nyu_dir), "train": str(nyu_dir),
                     "forest": {"n_trees": 1, "max_depth": 8, "pixels_per_frame": 60}},
            "base": {"budget": 200, "proposal_set": 50}, "sweep": {"grid": {"k": [1, 2]}}}
    s = run_study(parse_spec(spec), tmp_path / "out", cache_dir=tmp_path / "cache", report=False)
    assert (s.ran, s.failed) == (2, 0)
