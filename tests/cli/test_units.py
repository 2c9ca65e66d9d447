"""Units and formats are checked where they are read (issue #21): calibrate, evaluate,
proposals from-results and fit refuse metres, xyz given as uvd, zero rows and duplicate
names with one line and exit 2, instead of a nonsense result with exit 0."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main
from hybridfit.datasets.results import write_uvd

from ._icvl_files import write_results


def one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.startswith("hybridfit: error:") and err.count("\n") == 1, err
    return err


def _metres(tmp_path):
    """A ground-truth results file whose depths are in metres."""
    gt, _ = write_results(tmp_path, name="gt.txt")
    from hybridfit.datasets.results import read_uvd

    write_uvd(tmp_path / "metres.txt", read_uvd(gt, "icvl") * [1, 1, 0.001], "icvl")
    return gt, tmp_path / "metres.txt"


@pytest.mark.parametrize("command", ["calibrate", "evaluate", "from-results"])
def test_results_in_metres_are_refused_by_every_reader(tmp_path, capsys, command):
    gt, metres = _metres(tmp_path)
    out = tmp_path / "out"
    argv = {"calibrate": ["calibrate", "--dataset", "icvl", "--ground-truth", str(metres), "--out", f"{out}.toml"],
            "evaluate": ["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(metres)],
            "from-results": ["proposals", "from-results", str(metres), "--dataset", "icvl", "--out", f"{out}.npz"]}
    err = one_line_error(capsys, main(argv[command]))
    assert f"{metres}: the depths d have median 0.4" in err and "in metres?" in err
    assert not list(tmp_path.glob("out*"))


def test_evaluate_refuses_fits_and_truth_in_metres(tmp_path, capsys):
    """Both in metres used to give 0.02 mm and 100 % success."""
    d = hybridfit.synthetic_proposals(3, seed=2)
    fits = tmp_path / "fits.npz"
    np.savez(fits, joints=d["ground_truth"] / 1000 + 0.00001, ground_truth=d["ground_truth"] / 1000,
             joint_names=d["joint_names"])
    err = one_line_error(capsys, main(["evaluate", str(fits)]))
    assert "fits.npz: 'ground_truth' spreads over 0.0" in err and "in metres?" in err


def test_duplicate_joint_names_are_refused(tmp_path, capsys):
    d = hybridfit.synthetic_proposals(2, seed=2)
    names = [str(n) for n in d["joint_names"]]
    names[5] = names[9]
    np.savez(tmp_path / "p.npz", **{**d, "joint_names": np.asarray(names)})
    err = one_line_error(capsys, main(["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "o.npz")]))
    assert f"p.npz: joint_names: {names[9]!r} is listed 2 times (points 5, 9)" in err


def test_a_zero_row_is_named_by_its_line(tmp_path, capsys):
    gt, _ = write_results(tmp_path, name="gt.txt")
    lines = gt.read_text().splitlines()
    lines[2] = " ".join(["0"] * 48)
    gt.write_text("\n".join(lines) + "\n")
    err = one_line_error(capsys, main(["proposals", "from-results", str(gt), "--dataset", "icvl",
                                       "--out", str(tmp_path / "p.npz")]))
    assert f"{gt}:3: all values are 0" in err
