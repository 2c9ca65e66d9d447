"""`hybridfit evaluate`."""

import numpy as np
from PIL import Image

from hybridfit.cli import main

from ._icvl_files import write_results


def test_results_files_against_ground_truth_with_plot(tmp_path, capsys):
    gt, _ = write_results(tmp_path, name="gt.txt")
    noisy, _ = write_results(tmp_path, noise=10, seed=2, name="noisy.txt")
    plot = tmp_path / "s.png"
    assert main(["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(gt), "--compare", str(noisy),
                 "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("gt.txt"))
    assert line.split()[1:3] == ["0.00", "0.00"] and line.split()[-1] == "1.000"
    assert "noisy.txt" in out and "thumb_root" in out and "success@40" in out
    assert Image.open(plot).size[0] > 300


def test_proposals_give_top1_and_oracle(tmp_path, capsys):
    gt, truth = write_results(tmp_path, name="gt.txt")
    bad, _ = write_results(tmp_path, noise=30, seed=3, name="bad.txt")
    p = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(bad), str(gt), "--confidences", "2", "1",
                 "--ground-truth", str(gt), "--out", str(p)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(p)]) == 0
    out = capsys.readouterr().out
    oracle = next(ln for ln in out.splitlines() if "Oracle" in ln)
    top1 = next(ln for ln in out.splitlines() if "top-1" in ln)
    assert oracle.split()[2] == "0.00" and float(top1.split()[2]) > 10


def test_frames_and_missing_truth(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=4, name="gt.txt")
    assert main(["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "2:"]) == 0
    assert capsys.readouterr().out.startswith("2 frames")
    np.savez(tmp_path / "f.npz", joints=np.zeros((4, 16, 3)))
    assert main(["evaluate", str(tmp_path / "f.npz")]) == 2
    assert "no ground truth" in capsys.readouterr().err
