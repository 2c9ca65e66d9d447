"""`hybridfit fit --dataset` and `hybridfit export-results`."""

import numpy as np

from hybridfit.cli import main
from hybridfit.datasets import skeleton
from hybridfit.datasets.results import read_xyz

from ._icvl_files import write_results


def test_fit_names_the_skeleton_and_exports_it(tmp_path, capsys):
    gt, truth = write_results(tmp_path, frames=3)
    p = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)]) == 0
    z = dict(np.load(p))
    del z["joint_names"]  # like poier2015_proposals.npz
    np.savez(tmp_path / "bare.npz", **z)
    fits = tmp_path / "fits.npz"
    assert main(["fit", str(tmp_path / "bare.npz"), "--dataset", "icvl", "--budget", "600", "--out", str(fits)]) == 0
    f = np.load(fits)
    assert f["joints"].shape == (3, 16, 3) and list(f["joint_names"]) == list(skeleton("icvl").model_names)
    out = tmp_path / "fitted.txt"
    assert main(["export-results", str(fits), "--dataset", "icvl", "--out", str(out)]) == 0
    np.testing.assert_allclose(read_xyz(out, "icvl"), f["joints"], atol=0.01)
    assert np.nanmean(np.linalg.norm(f["joints"] - truth, axis=-1)) < 30


def test_without_joint_names_the_dataset_must_fit(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=2)
    p = tmp_path / "p.npz"
    main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)])
    z = dict(np.load(p))
    del z["joint_names"]
    np.savez(tmp_path / "bare.npz", **z)
    assert main(["fit", str(tmp_path / "bare.npz"), "--dataset", "msra", "--out", str(tmp_path / "f.npz")]) == 2
    assert "16 points, but the msra skeleton has 21" in capsys.readouterr().err


def test_export_refuses_fits_without_the_skeleton_points(tmp_path, capsys):
    np.savez(tmp_path / "f.npz", joints=np.zeros((2, 3, 3)), joint_names=np.array(["wrist", "index_tip", "thumb_tip"]))
    assert main(["export-results", str(tmp_path / "f.npz"), "--dataset", "icvl", "--out", str(tmp_path / "o.txt")]) == 2
    assert "no points for icvl's icvl_palm" in capsys.readouterr().err
