"""hand27 through every stage with no core change that names it: synth test/train --model,
train, propose, estimate, calibrate --model --dataset icvl, fit --model --dataset icvl."""

from __future__ import annotations

import tomllib

import numpy as np

import hybridfit
from hybridfit.cli import main
from hybridfit.datasets.folder import load_dataset
from hybridfit.datasets.skeletons import dataset_model_config

from ...cli._icvl_files import write_results

GRID = """
viewpoints_deg = [[0, 0, 0], [0, 0, 30]]
[articulations_deg]
thumb = [[-10, -20, 5, -10, 0], [40, 30, 30, 10, 20]]
index = [[5, 0, 5, 5], [80, 0, 100, 70]]
"""


def test_skeletons_map_onto_hand27_with_their_derived_points():
    config = dataset_model_config("hand27", {}, "icvl")
    assert config == dataset_model_config("hand26", {}, "icvl") and "icvl_palm" in config["derived_points"]
    model = hybridfit.create("model", "hand27", config)
    assert model.point_matrix(["icvl_palm"]).sum() == 1.0


def test_synthetic_data_forest_and_fits(tmp_path, capsys):
    grid, test = tmp_path / "grid.toml", tmp_path / "test"
    grid.write_text(GRID)
    assert main(["synth", "train", "--model", "hand27", "--config", str(grid), "--out", str(tmp_path / "train")]) == 0
    assert main(["synth", "test", "--model", "hand27", "--frames", "6", "--out", str(test)]) == 0
    train = load_dataset(tmp_path / "train")
    assert train.frames == 2 * 2 * 2 and np.asarray(train.params).shape[1] == 28
    assert load_dataset(test).meta["config"]["model"] == "hand27"
    forest = tmp_path / "forest.npz"
    assert main(["train", str(tmp_path / "train"), "--out", str(forest), "--trees", "1", "--max-depth", "8",
                 "--pixels-per-frame", "50", "--jobs", "1"]) == 0
    props = tmp_path / "props.npz"
    assert main(["propose", str(forest), str(test), "--out", str(props)]) == 0
    assert main(["fit", str(props), "--model", "hand27", "--budget", "300", "--out", str(tmp_path / "fit.npz")]) == 0
    assert main(["estimate", str(forest), str(test), "--model", "hand27", "--budget", "300",
                 "--out", str(tmp_path / "est.npz")]) == 0
    fit = np.load(tmp_path / "fit.npz")
    assert fit["params"].shape == (6, 28) and not fit["failed"].any()


def test_calibrate_and_fit_on_icvl_points(tmp_path, capsys):
    gt, truth = write_results(tmp_path, frames=6)
    config = tmp_path / "hand27.toml"
    assert main(["calibrate", "--model", "hand27", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "0:5",
                 "--out", str(config), "--rounds", "1", "--budget", "400", "--hand", "right"]) == 0
    assert "hand27 calibrated" in config.read_text().splitlines()[0]
    settings = tomllib.loads(config.read_text())
    assert "icvl_palm" in settings["derived_points"] and len(settings["bone_lengths"]) == 15
    props = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(props)]) == 0
    out = tmp_path / "f.npz"
    assert main(["fit", str(props), "--model", "hand27", "--model-config", str(config), "--dataset", "icvl",
                 "--budget", "600", "--out", str(out)]) == 0
    assert np.load(out)["params"].shape == (6, 28)
