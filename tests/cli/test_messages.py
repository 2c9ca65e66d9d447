"""Every error names the file, key or option, with the closest valid choice (issue #21, 6)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main

from ._icvl_files import write_results


def one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.startswith("hybridfit: error:") and err.count("\n") == 1, err
    return err


@pytest.fixture
def icvl_proposals(tmp_path, capsys):
    """Proposals made from an ICVL results file: (with its skeleton, without 'dataset', without names)."""
    gt, _ = write_results(tmp_path, name="gt.txt")
    assert main(["proposals", "from-results", str(gt), "--dataset", "icvl", "--out", str(tmp_path / "p.npz")]) == 0
    capsys.readouterr()
    with np.load(tmp_path / "p.npz") as z:
        d = dict(z)
    del d["dataset"]
    np.savez(tmp_path / "no_dataset.npz", **d)
    del d["joint_names"]
    np.savez(tmp_path / "no_names.npz", **d)
    return tmp_path


def test_a_file_without_joint_names_says_pass_dataset(icvl_proposals, capsys):
    err = one_line_error(capsys, main(["fit", str(icvl_proposals / "no_names.npz"), "--out", str(icvl_proposals / "o")]))
    assert "no_names.npz: 16 points without joint_names, and model hand26 has 21 joints: pass --dataset " \
           "(16-point skeletons: icvl)" in err


@pytest.mark.parametrize("dataset", [None, "nyu"])
def test_another_skeletons_points_name_that_skeleton(icvl_proposals, capsys, dataset):
    argv = ["fit", str(icvl_proposals / "no_dataset.npz"), "--out", str(icvl_proposals / "o.npz")]
    err = one_line_error(capsys, main(argv + (["--dataset", dataset] if dataset else [])))
    assert "no_dataset.npz: model hand26 lacks 1 of the 16 points to fit: 'icvl_palm' (neither a joint nor a derived " \
           "point of it; its points: wrist, " in err
    assert err.rstrip().endswith("; icvl defines it as a derived point of its joints: pass --dataset icvl"), err
    argv += ["--dataset", "icvl"]  # the advice works
    assert main(argv + ["--budget", "300", "--calibrate", "none"]) == 0, capsys.readouterr().err


TRIPOD = Path(__file__).resolve().parents[2] / "examples" / "hybridfit-tripod-hand" / "src"


@pytest.fixture
def tripod_model(monkeypatch):
    """A registered model (the example package's tripod hand: wrist and three fingers) that lacks most of
    hand26's points."""
    from hybridfit import registry

    monkeypatch.syspath_prepend(str(TRIPOD))
    from hybridfit_tripod_hand import TripodHand

    real = registry.get
    monkeypatch.setattr(registry, "get", lambda kind, name: TripodHand if (kind, name) == ("model", "tripod-hand")
                        else real(kind, name))


@pytest.mark.parametrize("dataset", [None, "mediapipe", "mano"])
def test_a_model_lacking_the_datas_points_gets_one_message_naming_them(tripod_model, tmp_path, capsys, dataset):
    """Once "pass --dataset mano", then "pass --dataset mediapipe", then "mano" again (issue 32): now one
    message, whatever --dataset says, naming every point the model lacks and no --dataset that would not help."""
    np.savez(tmp_path / "p.npz", **hybridfit.synthetic_proposals(3, seed=3))  # hand26's 21 joints, named
    argv = ["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "o.npz"), "--model", "tripod-hand",
            "--calibrate", "none"]
    err = one_line_error(capsys, main(argv + (["--dataset", dataset] if dataset else [])))
    lacking = ", ".join(repr(f"{f}_{j}") for f, joints in [("thumb", ("cmc", "mcp", "ip", "tip"))] + [
        (f, ("mcp", "pip", "dip", "tip")) for f in ("index", "middle", "ring", "little")] for j in joints)
    assert f"p.npz: model TripodHand lacks 20 of the 21 points to fit: {lacking} (neither a joint nor a derived " \
           "point of it; its points: wrist, thumb1, thumb2, thumb3, index1, " in err, err
    assert err.rstrip().endswith("; fit with a model that has them (--model)") and "--dataset" not in err, err


@pytest.mark.parametrize("option", ["--model-config", "proposals", "--ground-truth"])
def test_a_folder_is_called_a_folder(tmp_path, capsys, option):
    folder = tmp_path / "adir"
    folder.mkdir()
    gt, _ = write_results(tmp_path, name="gt.txt")
    np.savez(tmp_path / "p.npz", **hybridfit.synthetic_proposals(2, seed=3))
    argv = {"--model-config": ["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "o.npz"), "--model-config",
                               str(folder)],
            "proposals": ["fit", str(folder), "--out", str(tmp_path / "o.npz")],
            "--ground-truth": ["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(folder)]}[option]
    err = one_line_error(capsys, main(argv))
    assert f"{folder}: is a folder, not a" in err and "no such" not in err


@pytest.mark.parametrize("command, text, expected", [
    ("calibrate", "scal = 1.1\n", "unknown key 'scal' for model hand29 (did you mean 'scale'?"),
    ("train", "n_tres = 2\n", "unknown key 'n_tres' for the forest (did you mean 'n_trees'?"),
    ("synth", "[intrinsics]\nfxx = 2\n", "unknown key 'intrinsics.fxx' for synth test (did you mean 'fx'?"),
])
def test_settings_files_name_the_file_and_the_closest_key(tmp_path, capsys, command, text, expected):
    cfg = tmp_path / "settings.toml"
    cfg.write_text(text)
    gt, _ = write_results(tmp_path, name="gt.txt")
    argv = {"calibrate": ["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--model-config", str(cfg),
                          "--out", str(tmp_path / "m.toml")],
            "train": ["train", str(tmp_path), "--config", str(cfg), "--out", str(tmp_path / "f.npz")],
            "synth": ["synth", "test", "--config", str(cfg), "--out", str(tmp_path / "set")]}[command]
    err = one_line_error(capsys, main(argv))
    assert f"{cfg}: {expected}" in err


def test_confidences_are_plain_numbers(tmp_path, capsys):
    gt, _ = write_results(tmp_path, name="gt.txt")
    err = one_line_error(capsys, main(["proposals", "from-results", str(gt), str(gt), "--dataset", "icvl",
                                       "--confidences", "1", "-1", "--out", str(tmp_path / "p.npz")]))
    assert "--confidences:" in err and "got 1, -1" in err and "np.float64" not in err


def test_the_study_lists_every_data_kind_and_the_closest(tmp_path, capsys):
    study = tmp_path / "s.toml"
    study.write_text('name = "s"\n[data]\nkind = "synthetic-stres"\n')
    err = one_line_error(capsys, main(["study", str(study), "--report-only"]))
    assert "synthetic-stress (did you mean 'synthetic-stress'?)" in err and "synthetic-proposals" in err


def test_evaluate_on_an_interrupted_fit_counts_the_failed_frames(tmp_path, capsys, interrupt_at):
    np.savez(tmp_path / "p.npz", **hybridfit.synthetic_proposals(5, seed=3))
    interrupt_at(3)
    assert main(["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "fits.npz"), "--budget", "200"]) == 130
    capsys.readouterr()
    assert main(["evaluate", str(tmp_path / "fits.npz")]) == 0
    printed = capsys.readouterr().out
    assert "fits.npz: 2 of 5 frames failed (2 interrupted)" in printed
    assert "over the 3 frames with an estimate in every input" in printed and "\n3 frames, 21 points" in printed
    with np.load(tmp_path / "fits.npz") as fits:
        s = hybridfit.metrics.summary(fits["joints"][:3], fits["ground_truth"][:3])
    row = next(line for line in printed.splitlines() if line.startswith("fits.npz "))
    assert row.split()[1] == f"{s['mean_error_mm']:.2f}" and row.split()[4] == f"{s['success@40mm']:.3f}"
