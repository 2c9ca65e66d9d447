"""`hybridfit fit` and `hybridfit plugins` from the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main


@pytest.fixture(scope="module")
def proposals_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "synthetic.npz"
    assert main(["synth", "proposals", "--frames", "4", "--out", str(path), "--seed", "3"]) == 0
    return path


def test_plugins_lists_the_reference_plugins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for name in ("hand26", "clamped-confidence", "soft-l1", "clamped-then-soft-l1", "pso", "stepwise-pso",
                 "levenberg-marquardt"):
        assert name in out
    assert "[hybridfit]" in out


def test_fit_writes_the_documented_keys(proposals_file, tmp_path, capsys):
    out = tmp_path / "fits.npz"
    assert main(["fit", str(proposals_file), "--out", str(out), "--budget", "600", "--jobs", "2"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert "mean joint error" in printed[2]
    with np.load(out) as fits:
        assert {"params", "joints", "objective", "evaluations", "joint_names", "schedule"} <= set(fits.files)
        assert fits["params"].shape == (4, 27) and (fits["evaluations"] == 600).all()
        assert list(fits["joint_names"]) == list(hybridfit.create("model", "hand26").joint_names)
        (run,) = json.loads(str(fits["schedule"]))
    # the default schedule: PSO on the palm, then each finger, then a local stage on soft-L1,
    # every stage's evaluations in the budget, as the line after "fitted" says
    stages = run["stages"]
    assert run["frames"] == 4 and sum(s["budget"] for s in stages) == 600
    assert [s["name"] for s in stages] == ["palm", "thumb", "index", "middle", "ring", "little", "local"]
    assert {s["optimizer"]["name"] for s in stages[:-1]} == {"pso"}
    assert stages[-1]["optimizer"]["name"] == "levenberg-marquardt" and stages[-1]["budget"] % 28 == 0
    assert printed[1] == ("schedule: " + ", ".join(f"{s['name']} pso {s['budget']}" for s in stages[:-1])
                          + f", local levenberg-marquardt on soft-l1 {stages[-1]['budget']}"
                          + " (objective clamped-then-soft-l1)")


def test_fit_help_describes_the_schedule(capsys):
    assert main(["fit", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for words in ("The fit is its schedule", "clamped-then-soft-l1", "Levenberg-Marquardt", "local_share",
                  "key schedule"):
        assert words in text
    assert "--no-polish" not in text


def test_fit_help_says_what_runs(capsys):
    """The help as printed: percentages as such (its description is not %-formatted) and the
    default objective it names is the one a fit runs."""
    assert main(["fit", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "%%" not in text and "30% of the search budget" in text
    assert "default: clamped-confidence" not in text and "default: clamped-then-soft-l1" in text


def test_plugin_settings_from_toml(proposals_file, tmp_path):
    cfg = tmp_path / "opt.toml"
    cfg.write_text('schedule = "joint"\n')
    out = tmp_path / "fits.npz"
    assert main(["fit", str(proposals_file), "--out", str(out), "--budget", "300", "--optimizer-config", str(cfg)]) == 0
    cfg.write_text('schedule = "diagonal"\n')
    assert main(["fit", str(proposals_file), "--out", str(out), "--optimizer-config", str(cfg)]) == 2
    # inline TOML is the same settings as the file holding it
    cfg.write_text("local_share = 0\n")
    inline = tmp_path / "inline.npz"
    assert main(["fit", str(proposals_file), "--out", str(out), "--budget", "600", "--optimizer-config", str(cfg)]) == 0
    assert main(["fit", str(proposals_file), "--out", str(inline), "--budget", "600",
                 "--optimizer-config", "local_share = 0"]) == 0
    with np.load(out) as a, np.load(inline) as b:
        np.testing.assert_array_equal(a["params"], b["params"])
        assert "local" not in str(a["schedule"]) and str(a["schedule"]) == str(b["schedule"])


def corrupt(tmp_path):
    path = tmp_path / "corrupt.npz"
    path.write_bytes(b"PK\x03\x04 this is not a zip archive")
    return path


def missing_key(tmp_path):
    path = tmp_path / "nokey.npz"
    np.savez(path, proposals=np.zeros((1, 21, 1, 3)))
    return path


def nan_frame(tmp_path):
    d = hybridfit.synthetic_proposals(3, seed=1)
    d["proposals"][1, 4, 0, 2] = np.nan
    path = tmp_path / "nan.npz"
    np.savez(path, **d)
    return path


@pytest.mark.parametrize("make, args, message", [
    (lambda t: t / "absent.npz", [], "absent.npz: no such file"),
    (corrupt, [], "corrupt.npz: not a readable .npz file"),
    (missing_key, [], "missing key 'confidences'"),
    (nan_frame, [], "NaN or inf values (first in frame 1)"),
    (None, ["--optimizer", "psx"], "unknown optimizer 'psx'; did you mean 'pso'?"),
    (None, ["--budget", "9"], "budget 9 is too small"),
])
def test_user_errors_are_one_line_with_exit_code_2(proposals_file, tmp_path, capsys, make, args, message):
    source = proposals_file if make is None else make(tmp_path)
    code = main(["fit", str(source), "--out", str(tmp_path / "x.npz"), *args])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "x.npz").exists()


def test_an_interrupted_fit_saves_finished_frames_and_exits_130(proposals_file, tmp_path, interrupt_at):
    interrupt_at(1)
    out = tmp_path / "partial.npz"
    assert main(["fit", str(proposals_file), "--out", str(out), "--budget", "300"]) == 130
    with np.load(out) as fits:
        assert list(fits["failed"]) == [False, True, True, True]
        assert np.isfinite(fits["joints"][0]).all()


def paper_schedule(tmp_path):
    """The options of the optimiser's own result at exactly its budget: every stage on the
    paper's objective, no local stage (inline TOML, as ``fit --help`` says)."""
    return ["--objective", "clamped-confidence", "--optimizer-config", "local_share = 0"]


def test_a_tracked_sequence_runs_the_schedule_of_a_fit(proposals_file, tmp_path, capsys):
    local, paper = tmp_path / "local.npz", tmp_path / "paper.npz"
    options = ["--budget", "600", "--track"]
    assert main(["fit", str(proposals_file), "--out", str(local), *options]) == 0
    assert "local levenberg-marquardt on soft-l1" in capsys.readouterr().out
    assert main(["fit", str(proposals_file), "--out", str(paper), *options, *paper_schedule(tmp_path)]) == 0
    assert "local" not in capsys.readouterr().out.splitlines()[1]
    with np.load(local) as p, np.load(paper) as r:
        assert "lost" in p.files and not np.array_equal(p["joints"], r["joints"])
        assert (p["evaluations"] == 600).all() and (r["evaluations"] == 600).all()
        assert [s["name"] for s in json.loads(str(p["schedule"]))[0]["stages"]][-1] == "local"
        assert "local" not in [s["name"] for s in json.loads(str(r["schedule"]))[0]["stages"]]
        hand = hybridfit.create("model", str(p["model"]), json.loads(str(p["model_settings"])))
        np.testing.assert_allclose(hand.forward(p["params"]), p["model_joints"], atol=1e-6, rtol=0)


@pytest.mark.parametrize("options", [[], ["paper"], ["--model", "hand27", "--seed", "4"]])
def test_python_and_the_command_line_give_the_same_fit_bit_for_bit(proposals_file, tmp_path, options):
    out = tmp_path / "fits.npz"
    paper = options == ["paper"]
    cli = paper_schedule(tmp_path) if paper else options
    assert main(["fit", str(proposals_file), "--out", str(out), "--budget", "500", *cli]) == 0
    with np.load(proposals_file) as d:
        kwargs = {"model": "hand27" if "hand27" in options else "hand26", "seed": 4 if "--seed" in options else 0}
        if paper:
            kwargs |= {"objective": "clamped-confidence", "optimizer_config": {"local_share": 0.0}}
        result = hybridfit.fit(d["proposals"], d["confidences"], budget=500, **kwargs)
    with np.load(out) as fits:
        for key, value in result.to_npz().items():
            np.testing.assert_array_equal(fits[key], value, err_msg=key)
