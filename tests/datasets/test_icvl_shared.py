"""The shared real ICVL files (skipped where ../shared/data/icvl is absent)."""

from pathlib import Path

import numpy as np
import pytest

from hybridfit.cli import main
from hybridfit.datasets import ICVL
from hybridfit.datasets.results import read_xyz
from hybridfit.metrics import summary

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "icvl"
pytestmark = pytest.mark.skipif(not DATA.is_dir(), reason="shared ICVL data absent")


def test_lrf_error_matches_the_readme():
    truth = read_xyz(DATA / "icvl_test_groundtruth_label.txt", "icvl")
    s = summary(read_xyz(DATA / "lrf_cvpr14_predictions.txt", "icvl"), truth)
    assert s["mean_error_mm"] == pytest.approx(12.58, abs=0.01) and s["success@40mm"] == pytest.approx(0.709, abs=1e-3)


def test_proposals_are_in_the_same_frame_as_the_labels():
    truth = read_xyz(DATA / "icvl_test_groundtruth_label.txt", "icvl")
    top1 = np.load(DATA / "poier2015_proposals.npz")["proposals"][:, :, 0]
    assert np.linalg.norm(top1 - truth, axis=-1).mean() == pytest.approx(10.66, abs=0.01)


def test_the_papers_proposals_fit_as_they_are(tmp_path):
    z = np.load(DATA / "poier2015_proposals.npz")
    np.savez(tmp_path / "p.npz", **{k: z[k][:3] for k in z.files})  # the same keys, 3 frames
    assert main(["fit", str(tmp_path / "p.npz"), "--dataset", "icvl", "--budget", "600",
                 "--out", str(tmp_path / "f.npz")]) == 0
    assert np.load(tmp_path / "f.npz")["joints"].shape == (3, 16, 3)


def test_labels_file_without_names_is_refused(tmp_path):
    from hybridfit import HybridfitError

    with pytest.raises(HybridfitError, match=r"icvl_test_groundtruth_label.txt:1: expected an image name"):
        ICVL(DATA / "icvl_test_groundtruth_label.txt")
