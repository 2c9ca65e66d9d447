"""`hybridfit train`, `propose` and `estimate` from the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main
from hybridfit.forest import Forest

from ..forest.helpers import write_hand_dataset

FAST = ["--trees", "2", "--max-depth", "10", "--pixels-per-frame", "100"]


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return write_hand_dataset(tmp_path_factory.mktemp("data") / "hands", 12, seed=9, empty_frames=[11])


@pytest.fixture(scope="module")
def forest_file(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("forest") / "forest.npz"
    assert main(["train", str(data), "--out", str(out), *FAST, "--jobs", "2"]) == 0
    return out


def test_train_writes_a_loadable_forest(forest_file, data, tmp_path, capsys):
    forest = Forest.load(forest_file)
    assert forest.n_trees == 2 and forest.config.max_depth == 10
    assert forest.joint_names == tuple(hybridfit.create("model", "hand26").joint_names)
    cfg = tmp_path / "forest.toml"
    cfg.write_text("n_features = 20\nmin_samples = 30\n")
    out = tmp_path / "f.npz"
    assert main(["train", str(data), "--out", str(out), "--config", str(cfg), "--frames", "4", *FAST]) == 0
    assert "trained 2 trees" in capsys.readouterr().out
    assert Forest.load(out).config.n_features == 20


def test_propose_writes_a_valid_fit_input(forest_file, data, tmp_path, capsys):
    out = tmp_path / "proposals.npz"
    assert main(["propose", str(forest_file), str(data), "--out", str(out), "-k", "2", "--proposal-set", "100"]) == 0
    captured = capsys.readouterr()
    assert "frame 11: no foreground pixels" in captured.err and "oracle" in captured.out
    data_in = hybridfit.io.load_proposals(out)
    assert data_in["proposals"].shape == (12, 21, 2, 3) and data_in["ground_truth"].shape == (12, 21, 3)
    assert data_in["empty"].tolist() == [False] * 11 + [True]
    fits = tmp_path / "fits.npz"
    assert main(["fit", str(out), "--out", str(fits), "--budget", "600"]) == 3  # frame 11 has no proposals
    assert "frame 11: the frame has no proposals with positive confidence" in capsys.readouterr().err
    with np.load(fits) as f:
        assert f["failed"].tolist() == [False] * 11 + [True] and f["inliers"][:11].min() > 0


def test_propose_takes_a_range_of_frames(forest_file, data, tmp_path, capsys):
    """--frames START:STOP, as in evaluate and calibrate (it took only N here; issue 32)."""
    out = tmp_path / "proposals.npz"
    assert main(["propose", str(forest_file), str(data), "--out", str(out), "--frames", "8:10"]) == 0
    assert "proposals for 2 frames" in capsys.readouterr().out
    with np.load(out) as z:
        assert z["frames"].tolist() == [8, 9] and z["proposals"].shape[0] == 2


def test_estimate_end_to_end(forest_file, data, tmp_path, capsys):
    out = tmp_path / "fits.npz"
    assert main(["estimate", str(forest_file), str(data), "--out", str(out), "--budget", "600", "--frames", "3"]) == 0
    assert "fitted: mean joint error" in capsys.readouterr().out
    with np.load(out) as fits:
        assert fits["joints"].shape == (3, 21, 3) and not fits["failed"].any()
        assert {"proposals", "confidences", "empty", "ground_truth", "params", "parameter_names"} <= set(fits.files)
        frames = fits["frames"].tolist()
        hand = hybridfit.create("model", str(fits["model"]), json.loads(str(fits["model_settings"])))  # one rigid hand
        np.testing.assert_allclose(hand.points(fits["params"], [str(n) for n in fits["joint_names"]]), fits["joints"],
                                   atol=1e-6, rtol=0)
    assert main(["export-angles", str(out), "--out", str(tmp_path / "angles.csv")]) == 0
    rows = (tmp_path / "angles.csv").read_text().splitlines()
    assert [int(r.split(",")[0]) for r in rows[1:]] == frames  # the data set's frame indices


@pytest.mark.parametrize("argv, message", [
    (["propose", "{tmp}/nothing.npz", "{data}", "--out", "{tmp}/o.npz"], "nothing.npz: no such forest file"),
    (["propose", "{tmp}/bad.npz", "{data}", "--out", "{tmp}/o.npz"], "bad.npz: not a readable forest file"),
    (["estimate", "{forest}", "{tmp}/nodata", "--out", "{tmp}/o.npz"], "nodata"),
    (["train", "{data}", "--out", "{tmp}/o.npz", "--config", "{tmp}/bad.toml"], "n_tress"),
])
def test_errors_exit_2_with_one_line(argv, message, forest_file, data, tmp_path, capsys):
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    (tmp_path / "bad.toml").write_text("n_tress = 3\n")
    argv = [a.format(tmp=tmp_path, data=data, forest=forest_file) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
