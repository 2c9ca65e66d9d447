"""`hybridfit calibrate`: writes a model config that `hybridfit fit` accepts."""

import tomllib
from pathlib import Path

import pytest

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
    """calibrate's default model is hand29 (tuned: docs/results.md, Real hands), the file it
    writes names it, and fit takes the model from the file unless --model names another."""
    import numpy as np

    gt, _ = write_results(tmp_path, frames=4)
    model, p, f = tmp_path / "model.toml", tmp_path / "p.npz", tmp_path / "f.npz"
    assert main(["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--out", str(model), "--rounds", "0",
                 "--budget", "600", "--hand", "right"]) == 0
    assert tomllib.loads(model.read_text())["model"] == "hand29" and model.read_text().startswith("# hand29 ")
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(p)]) == 0
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "600", "--out", str(f)]) == 0
    assert np.load(f)["params"].shape[1] == 30  # hand29's parameters, not hand26's 27
    capsys.readouterr()
    assert main(["fit", str(p), "--model-config", str(model), "--model", "hand26", "--budget", "600",
                 "--out", str(tmp_path / "g.npz")]) == 2
    assert f"{model}: settings of model 'hand29' (its model key), not of --model hand26" in capsys.readouterr().err
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


# ------------------------------------------------------------------ self-calibration: --proposals, fit --calibrate

@pytest.fixture
def quick(monkeypatch):
    """Self-calibration with one short least-squares round (the same in every command)."""
    from hybridfit.fitting.calibrate import self_calibrate

    monkeypatch.setitem(self_calibrate.__kwdefaults__, "rounds", 1)
    monkeypatch.setitem(self_calibrate.__kwdefaults__, "max_nfev", 8)


def _subject(tmp_path, frames=12, name="p.npz", **kw):
    """A proposals file of a 1.1-scale hand26 subject (k = 3, with its ground truth)."""
    import numpy as np

    import hybridfit

    np.savez(tmp_path / name, **hybridfit.synthetic_proposals(frames, k=3, noise_mm=3.0, seed=5,
                                                              model_config={"scale": 1.1}, **kw))
    return tmp_path / name


def test_self_calibration_writes_a_usable_model_config(tmp_path, capsys, quick):
    import numpy as np

    p, model = _subject(tmp_path), tmp_path / "self.toml"
    assert main(["calibrate", "--proposals", str(p), "--model", "hand26", "--out", str(model), "--budget", "300"]) == 0
    out = capsys.readouterr().out
    assert "self-calibrated on 9 frames (right hand): fit " in out and "mm from the top proposals before" in out
    assert "against the file's ground_truth (not used to calibrate): mean fit error" in out
    text = model.read_text()
    assert text.startswith("# hand26 self-calibrated by `hybridfit calibrate --proposals` on 9 frames")
    settings = tomllib.loads(text)
    assert settings["model"] == "hand26" and len(settings["bone_lengths"]) == 15
    f = tmp_path / "f.npz"
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "300", "--out", str(f)]) == 0
    import json

    with np.load(f) as z:
        fitted = json.loads(str(z["model_settings"]))
    assert fitted["bone_lengths"] == settings["bone_lengths"]


def test_self_calibration_refuses_a_holdout_and_needs_one_source(tmp_path, capsys):
    p = _subject(tmp_path, frames=3)
    assert main(["calibrate", "--proposals", str(p), "--holdout", "0.2", "--out", str(tmp_path / "m.toml")]) == 2
    assert "--holdout: with --proposals nothing is held out" in capsys.readouterr().err
    gt, _ = write_results(tmp_path, frames=3)
    assert main(["calibrate", "--proposals", str(p), "--ground-truth", str(gt), "--dataset", "icvl",
                 "--out", str(tmp_path / "m.toml")]) == 2
    assert "not allowed with argument" in capsys.readouterr().err
    assert main(["calibrate", "--ground-truth", str(gt), "--out", str(tmp_path / "m.toml")]) == 2
    assert "--ground-truth needs --dataset" in capsys.readouterr().err
    assert not (tmp_path / "m.toml").exists()


def test_fit_calibrate_self_equals_calibrate_then_fit(tmp_path, capsys, quick):
    """`fit --calibrate self` fits with the skeleton `calibrate --proposals` writes, bit for
    bit, and its one line on stderr says how to keep it."""
    import numpy as np

    p = _subject(tmp_path)
    a, b, model = tmp_path / "a.npz", tmp_path / "b.npz", tmp_path / "p-hand26.toml"
    assert main(["fit", str(p), "--model", "hand26", "--calibrate", "self", "--budget", "300", "--out", str(a)]) == 0
    err = capsys.readouterr().err
    assert "the right-hand hand26 skeleton was self-calibrated on 9 frames of the proposals" in err
    keep = f"hybridfit calibrate --proposals {p} --model hand26 --budget 300 --out p-hand26.toml"
    assert keep in err and "then fit with --model-config p-hand26.toml" in err
    assert main(keep.split()[1:-1] + [str(model)]) == 0
    assert main(["fit", str(p), "--model-config", str(model), "--budget", "300", "--out", str(b)]) == 0
    with np.load(a) as x, np.load(b) as y:
        assert str(x["model_settings"]) == str(y["model_settings"])
        assert np.array_equal(x["joints"], y["joints"]) and np.array_equal(x["params"], y["params"])


def test_fit_calibrate_auto_needs_a_data_set_and_enough_frames(tmp_path, capsys):
    """auto: no data set (synthetic proposals), or a model config given, or too few frames: no
    self-calibration; the fits file's settings are the model's own."""
    import json

    import numpy as np

    from hybridfit.cli.fit import AUTO_MIN_FRAMES

    p = _subject(tmp_path, frames=AUTO_MIN_FRAMES)
    f = tmp_path / "f.npz"
    assert main(["fit", str(p), "--budget", "300", "--out", str(f)]) == 0  # no dataset: hand26 as it is
    assert "self-calibrated" not in capsys.readouterr().err
    with np.load(f) as z:
        assert str(z["model"]) == "hand26" and json.loads(str(z["model_settings"]))["scale"] == 1.0
    gt, _ = write_results(tmp_path, frames=AUTO_MIN_FRAMES - 1)
    q = tmp_path / "q.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(gt), "--out", str(q)]) == 0
    assert main(["fit", str(q), "--budget", "300", "--out", str(f)]) == 0  # a data set, too few frames
    assert "self-calibrated" not in capsys.readouterr().err
    with np.load(f) as z:
        assert str(z["model"]) == "hand26"


ICVL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "icvl"


@pytest.mark.skipif(not ICVL.is_dir(), reason="shared ICVL data absent")
def test_the_papers_icvl_proposals_fitted_by_default_beat_their_top_1(tmp_path, capsys):
    """Real data without a calibration: `hybridfit fit --dataset icvl` self-calibrates the
    skeleton on the proposals and beats their own top-1 (every 4th frame of the 1596)."""
    import numpy as np

    from hybridfit.datasets.results import read_xyz

    every = slice(None, None, 4)
    with np.load(ICVL / "poier2015_proposals.npz") as z:
        proposals, confidences = z["proposals"][every], z["confidences"][every]
    truth = read_xyz(ICVL / "icvl_test_groundtruth_label.txt", "icvl")[every]
    np.savez(tmp_path / "p.npz", proposals=proposals, confidences=confidences)
    f = tmp_path / "f.npz"
    assert main(["fit", str(tmp_path / "p.npz"), "--dataset", "icvl", "--out", str(f)]) == 0
    assert "the left-hand hand29 skeleton was self-calibrated on 100 frames" in capsys.readouterr().err
    with np.load(f) as r:
        fitted = np.linalg.norm(r["joints"] - truth, axis=-1).mean()
        assert str(r["model"]) == "hand29"
    top1 = np.linalg.norm(proposals[:, :, 0] - truth, axis=-1).mean()
    assert fitted < top1 - 0.3, (fitted, top1)


def test_a_stop_during_the_self_calibration_writes_nothing(tmp_path, capsys, monkeypatch):
    from hybridfit.fitting import calibrate as calibration

    def stop(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibration, "_least_squares", stop)
    p, f = _subject(tmp_path), tmp_path / "f.npz"
    assert main(["fit", str(p), "--calibrate", "self", "--budget", "300", "--out", str(f)]) == 130
    assert "interrupted during the self-calibration: nothing fitted" in capsys.readouterr().err
    assert not f.exists()
