"""fit notices data of the other hand, and an uncalibrated model far from a dataset's
proposals (issue #21): one warning line each, with the option that fixes it."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main

ICVL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "icvl"


def run(argv: list[str]) -> tuple[int, list[str]]:
    """main's exit code and the warnings it gave."""
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        code = main(argv)
    return code, [str(w.message) for w in said]


def error_mm(out) -> float:
    with np.load(out) as fits:
        return float(hybridfit.metrics.summary(fits["joints"], fits["ground_truth"])["mean_error_mm"])


@pytest.fixture(scope="module")
def left(tmp_path_factory):
    path = tmp_path_factory.mktemp("hand") / "left.npz"
    np.savez(path, **hybridfit.synthetic_proposals(8, seed=4, model_config={"mirror": True}))
    return path


def test_left_hand_data_is_fitted_with_the_left_hand(left, tmp_path, capsys):
    code, said = run(["fit", str(left), "--out", str(tmp_path / "auto.npz"), "--budget", "600"])
    assert code == 0
    assert len(said) == 1 and "the proposals are of the left hand" in said[0] and "--hand right to keep" in said[0]
    assert run(["fit", str(left), "--out", str(tmp_path / "right.npz"), "--budget", "600", "--hand", "right"]) == (0, [])
    assert error_mm(tmp_path / "auto.npz") < 12 < 20 < error_mm(tmp_path / "right.npz")
    with np.load(tmp_path / "auto.npz") as a:
        assert main(["fit", str(left), "--out", str(tmp_path / "left.npz"), "--budget", "600", "--hand", "left"]) == 0
        with np.load(tmp_path / "left.npz") as b:
            assert np.array_equal(a["joints"], b["joints"])  # auto chose exactly what --hand left fits


def test_right_hand_data_says_nothing(tmp_path, capsys):
    np.savez(tmp_path / "right.npz", **hybridfit.synthetic_proposals(8, seed=4))
    assert run(["fit", str(tmp_path / "right.npz"), "--out", str(tmp_path / "o.npz"), "--budget", "600"]) == (0, [])


def test_an_uncalibrated_geometry_says_calibrate(tmp_path, capsys):
    d = hybridfit.synthetic_proposals(6, seed=4, noise_mm=2, model_config={"scale": 1.4})
    del d["joint_names"]  # the mediapipe skeleton's 21 points are hand26's joints
    np.savez(tmp_path / "big.npz", **d)
    argv = ["fit", str(tmp_path / "big.npz"), "--dataset", "mediapipe", "--out", str(tmp_path / "o.npz"), "--budget", "600"]
    code, said = run(argv)
    assert code == 0
    assert len(said) == 1 and "geometry does not match the mediapipe annotations" in said[0]
    assert "hybridfit calibrate --dataset mediapipe --ground-truth LABELS" in said[0]
    (tmp_path / "big.toml").write_text("scale = 1.4\n")
    assert run(argv + ["--model-config", str(tmp_path / "big.toml")]) == (0, [])


@pytest.mark.skipif(not ICVL.is_dir(), reason="shared ICVL data absent")
def test_the_papers_icvl_proposals_without_calibration_say_calibrate(tmp_path, capsys):
    with np.load(ICVL / "poier2015_proposals.npz") as z:
        np.savez(tmp_path / "p.npz", proposals=z["proposals"][100:140], confidences=z["confidences"][100:140])
    code, said = run(["fit", str(tmp_path / "p.npz"), "--dataset", "icvl", "--out", str(tmp_path / "o.npz"),
                      "--budget", "600", "--calibrate", "none"])  # the default self-calibrates (test_calibrate.py)
    assert code == 0
    assert len(said) == 1 and "hybridfit calibrate --dataset icvl" in said[0]


def test_permuted_point_names_are_warned_about(tmp_path):
    d = hybridfit.synthetic_proposals(6, seed=4)
    names = [str(n) for n in d["joint_names"]]
    np.savez(tmp_path / "p.npz", **{**d, "joint_names": np.asarray(names[10:] + names[:10])})
    code, said = run(["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "o.npz"), "--budget", "300"])
    assert code == 0 and len(said) == 1 and "further than any hand's geometry explains" in said[0]
