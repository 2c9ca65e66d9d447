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
    assert "floor " in out and "mm predictor fitted: " in out
    assert "mm before" in out and "calibrated on 3 frames (right hand)" in out and "mm held out (1 frames)" in out
    text = model.read_text()
    assert "on 3 frames spanning the pose range of frames 0-3, 1 held out spread over them" in text and "mm held out (1 frames)" in text.splitlines()[1]
    settings = tomllib.loads(text)
    assert "icvl_palm" in settings["derived_points"] and len(settings["bone_lengths"]) == 15
    p = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)]) == 0
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "600", "--out", str(tmp_path / "f.npz")]) == 0


def test_the_model_config_names_its_model_and_fit_uses_it(tmp_path, capsys):
    """calibrate's default model is hand27 (tuned: docs/results.md, Real hands), the file it
    writes names it, and fit takes the model from the file unless --model names another."""
    import numpy as np

    gt, _ = write_results(tmp_path, frames=4)
    model, p, f = tmp_path / "model.toml", tmp_path / "p.npz", tmp_path / "f.npz"
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--out", str(model), "--rounds", "0",
                 "--budget", "600", "--hand", "right"]) == 0
    assert tomllib.loads(model.read_text())["model"] == "hand27" and model.read_text().startswith("# hand27 ")
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)]) == 0
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "600", "--out", str(f)]) == 0
    assert np.load(f)["params"].shape[1] == 28  # hand27's parameters, not hand26's 27
    capsys.readouterr()
    assert main(["fit", str(p), "--model-config", str(model), "--model", "hand26", "--budget", "600",
                 "--out", str(tmp_path / "g.npz")]) == 2
    assert f"{model}: settings of model 'hand27' (its model key), not of --model hand26" in capsys.readouterr().err
    assert not (tmp_path / "g.npz").exists()
    assert main(["fit", str(p), "--budget", "600", "--out", str(f)]) == 0
    assert np.load(f)["params"].shape[1] == 27  # without a calibration: hand26, the paper's
    for text, said in (('model = "hand99"\n', "model: unknown model 'hand99'; did you mean"),
                       ("model = 3\n", "model must be a model plugin's name, got 3")):
        model.write_text(text)
        assert main(["fit", str(p), "--model-config", str(model), "--budget", "600", "--out", str(tmp_path / "h.npz")]) == 2
        assert f"{model}: {said}" in capsys.readouterr().err


def test_bad_frames_option(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=3)
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "5:9",
                 "--out", str(tmp_path / "m.toml")]) == 2
    assert "--frames 5:9: no frames selected out of 3" in capsys.readouterr().err


def test_holdout_zero_uses_every_frame(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=4)
    model = tmp_path / "model.toml"
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", "1:", "--holdout", "0",
                 "--out", str(model), "--rounds", "0", "--budget", "600", "--hand", "left"]) == 0
    assert "calibrated on 3 frames (left hand)" in capsys.readouterr().out
    assert "on 3 frames spanning the pose range of frames 1-3 of" in model.read_text()


def test_bad_holdout_option(tmp_path, capsys):
    gt, _ = write_results(tmp_path, frames=3)
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--holdout", "1.5",
                 "--out", str(tmp_path / "m.toml")]) == 2
    assert "--holdout: expected a number in [0, 1), got 1.5" in capsys.readouterr().err


def test_a_users_skeleton_file_goes_through_calibrate_from_results_and_fit(tmp_path):
    """--dataset takes a skeleton file wherever it takes a name (the file, not its name, is looked up)."""
    from pathlib import Path

    import hybridfit.datasets.skeletons as skeletons

    mine = tmp_path / "mine.toml"
    mine.write_text((Path(skeletons.__file__).parent / "skeleton_files" / "icvl.toml").read_text())
    gt, _ = write_results(tmp_path, frames=5)
    model, p = tmp_path / "model.toml", tmp_path / "p.npz"
    assert main(["calibrate", "--dataset", str(mine), "--ground-truth", str(gt), "--frames", "0:4", "--out",
                 str(model), "--rounds", "0", "--budget", "600", "--hand", "right"]) == 0
    assert main(["proposals", "from-results", "--dataset", str(mine), str(gt), "--ground-truth", str(gt),
                 "--out", str(p)]) == 0
    assert main(["fit", str(p), "--dataset", str(mine), "--model-config", str(model), "--budget", "600",
                 "--out", str(tmp_path / "f.npz")]) == 0
