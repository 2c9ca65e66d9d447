"""`hybridfit calibrate`: writes a model config that `hybridfit fit` accepts."""

import tomllib

from hybridfit.cli import main

from ._icvl_files import write_results


def test_calibrate_writes_a_usable_model_config(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=6)
    model = tmp_path / "model.toml"
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "0:4", "--out", str(model),
                 "--rounds", "1", "--budget", "600", "--hand", "right"]) == 0
    out = capsys.readouterr().out
    assert "mm before" in out and "calibrated on 4 frames (right hand)" in out
    settings = tomllib.loads(model.read_text())
    assert "icvl_palm" in settings["derived_points"] and len(settings["bone_lengths"]) == 15
    p = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)]) == 0
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "600", "--out", str(tmp_path / "f.npz")]) == 0


def test_bad_frames_option(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=3)
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "5:9",
                 "--out", str(tmp_path / "m.toml")]) == 2
    assert "--frames 5:9: no frames selected out of 3" in capsys.readouterr().err
