"""Outputs never destroy anything (issue #21): an output that is one of the run's inputs or
not a regular file is refused before any work, naming the option; a failed write is one
line naming the path, keeps the existing output and leaves no temporary file."""

from __future__ import annotations

import argparse
import hashlib
import os

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import build_parser, main

from ._icvl_files import write_results


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_error(capsys, code: int, expected: int = 2) -> str:
    """The one error line (after the progress a command logs, e.g. a study's)."""
    err = capsys.readouterr().err
    assert code == expected, err
    assert "Traceback" not in err and err.count("hybridfit: error:") == 1, err
    assert err.endswith("\n") and err.splitlines()[-1].startswith("hybridfit: error:"), err
    return err.splitlines()[-1]


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("outputs") / "frames.npz"
    np.savez(path, **hybridfit.synthetic_proposals(3, seed=3))
    return path


def _leaf_parsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from ([(name, sub)] if sub.get_default("func") else [])
                yield from _leaf_parsers(sub)


def test_every_command_declares_its_inputs_and_outputs():
    """The shared check (hybridfit.io.check_paths) sees only what a command declares."""
    leaves = list(_leaf_parsers(build_parser()))
    assert len(leaves) >= 12
    for name, sub in leaves:
        declared = sub.get_default("paths_declared")
        assert declared is not None, f"{name}: call _common.declare_paths(parser, inputs=..., outputs=...)"
        dests = {a.dest for a in sub._actions}
        for option in (o for group in declared for o in group):
            assert option.lstrip("-").replace("-", "_") in dests, f"{name}: declares {option}, no such option"


def _argv(kind, tmp_path, frames_file):
    """(argv, the input that --out points at)."""
    gt, _ = write_results(tmp_path, name="gt.txt")
    dummy = tmp_path / "forest.npz"
    dummy.write_bytes(b"any file: refused before it is read")
    (tmp_path / "data").mkdir()
    fits = tmp_path / "fits.npz"
    np.savez(fits, joints=np.zeros((2, 16, 3)))
    return {
        "fit": (["fit", str(frames_file), "--out", str(frames_file)], frames_file),
        "export-results": (["export-results", str(fits), "--dataset", "icvl", "--out", str(fits)], fits),
        "from-results": (["proposals", "from-results", str(gt), "--dataset", "icvl", "--out", str(gt)], gt),
        "calibrate": (["calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--out", str(gt)], gt),
        "propose": (["propose", str(dummy), str(tmp_path / "data"), "--out", str(dummy)], dummy),
        "estimate": (["estimate", str(dummy), str(tmp_path / "data"), "--out", str(dummy)], dummy),
        "evaluate --plot": (["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(gt), "--plot", str(gt)], gt),
    }[kind]


@pytest.mark.parametrize("kind", ["fit", "export-results", "from-results", "calibrate", "propose", "estimate",
                                  "evaluate --plot"])
def test_an_output_equal_to_an_input_is_refused(tmp_path, frames_file, capsys, kind):
    argv, target = _argv(kind, tmp_path, frames_file)
    before = digest(target)
    err = one_line_error(capsys, main(argv))
    option = "--plot" if kind == "evaluate --plot" else "--out"
    assert f"{option} {target}: is the input" in err and "never replaces an input" in err
    assert digest(target) == before


def test_a_link_to_the_input_is_the_input(tmp_path, frames_file, capsys):
    copy = tmp_path / "p.npz"
    copy.write_bytes(frames_file.read_bytes())
    os.link(copy, tmp_path / "hard.npz")
    os.symlink(copy, tmp_path / "soft.npz")
    for out in ("hard.npz", "soft.npz"):
        err = one_line_error(capsys, main(["fit", str(copy), "--out", str(tmp_path / out)]))
        assert "is the input proposals" in err
    assert digest(copy) == digest(frames_file) and (tmp_path / "soft.npz").is_symlink()


@pytest.mark.parametrize("special", ["fifo", "devnull"])
def test_a_special_file_as_output_is_refused(tmp_path, frames_file, capsys, special):
    target = tmp_path / special
    if special == "fifo":
        os.mkfifo(target)
    else:  # a link to /dev/null: were it replaced, only the link would go, not the system's /dev/null
        os.symlink(os.devnull, target)
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(target), "--budget", "100"]))
    assert f"--out {target}: is a" in err and "not a regular file" in err
    assert (special == "fifo" and target.is_fifo()) or (special == "devnull" and target.is_symlink())
    assert sorted(p.name for p in tmp_path.iterdir()) == [special]  # no temporary file either


def test_synth_refuses_to_replace_a_folder_holding_its_settings(tmp_path, capsys):
    folder = tmp_path / "set"
    folder.mkdir()
    (folder / "meta.json").write_text("{}")
    (folder / "grid.toml").write_text("frames = 2\n")
    err = one_line_error(capsys, main(["synth", "test", "--out", str(folder), "--config", str(folder / "grid.toml")]))
    assert "--out" in err and "holds the input --config" in err and (folder / "grid.toml").is_file()


# --------------------------------------------------------------- a failed write: one line, nothing lost


def _no_space(*args, **kwargs):
    raise OSError(28, "No space left on device")


def _half_then_no_space(fh, **arrays):
    fh.write(b"half")
    _no_space()


def _full_disk(kind, tmp_path, frames_file, monkeypatch):
    """(argv, the output that exists before) with writing made to fail like a full disk."""
    import matplotlib.figure
    import PIL.Image

    gt, truth = write_results(tmp_path, name="gt.txt")
    if kind in ("fit", "synth proposals"):
        monkeypatch.setattr(np, "savez", _half_then_no_space)
    if kind == "export-results":
        from hybridfit.cli import export_results

        fits = tmp_path / "fits.npz"
        np.savez(fits, joints=truth,
                 joint_names=np.asarray(hybridfit.datasets.skeletons.skeleton("icvl").model_names))
        monkeypatch.setattr(export_results, "write_xyz", lambda path, *a: (path.write_text("half"), _no_space()))
    if kind == "evaluate --plot":
        monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda self, path, **k: (open(path, "wb").write(b"x"),
                                                                                            _no_space()))
    if kind == "synth test":
        monkeypatch.setattr(PIL.Image.Image, "save", _no_space)
    out = {"synth test": tmp_path / "set", "evaluate --plot": tmp_path / "curve.png",
           "export-results": tmp_path / "fitted.txt"}.get(kind, tmp_path / "out.npz")
    if kind == "synth test":
        (out / "depth").mkdir(parents=True)
        (out / "meta.json").write_text('{"format": "hybridfit-dataset", "version": 1}')  # an earlier data set
    else:
        out.write_bytes(b"an earlier output")
    argv = {"fit": ["fit", str(frames_file), "--out", str(out), "--budget", "100"],
            "synth proposals": ["synth", "proposals", "--frames", "2", "--out", str(out)],
            "export-results": ["export-results", str(tmp_path / "fits.npz"), "--dataset", "icvl", "--out", str(out)],
            "evaluate --plot": ["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(gt), "--plot", str(out)],
            "synth test": ["synth", "test", "--frames", "2", "--out", str(out)]}[kind]
    return argv, out


@pytest.mark.parametrize("kind", ["fit", "synth proposals", "export-results", "evaluate --plot", "synth test"])
def test_a_full_disk_is_one_line_naming_the_path(tmp_path, frames_file, capsys, monkeypatch, kind):
    argv, out = _full_disk(kind, tmp_path, frames_file, monkeypatch)
    before = sorted(p.name for p in tmp_path.iterdir())
    err = one_line_error(capsys, main(argv))
    assert f"{out}: cannot write: No space left on device (nothing was replaced)" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no temporary file or folder left
    if kind == "synth test":
        assert (out / "meta.json").read_text() == '{"format": "hybridfit-dataset", "version": 1}'
    else:
        assert out.read_bytes() == b"an earlier output"


def test_a_full_disk_under_a_study_names_its_database(tmp_path, capsys, monkeypatch):
    import sqlite3

    from hybridfit.study import store

    from ..study.conftest import TINY

    study = tmp_path / "tiny.toml"
    study.write_text(TINY)

    def full(self, *args, **kwargs):
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(store.Store, "complete", full)
    err = one_line_error(capsys, main(["study", str(study), "--quick", "--out", str(tmp_path / "run")]))
    assert f"{tmp_path / 'run' / 'study.db'}: cannot write the study database: database or disk is full" in err


def test_a_study_out_under_a_file_is_one_line(tmp_path, capsys):
    """Tests run as root, where a read-only folder does not stop writes: a path under a file does."""
    from ..study.conftest import TINY

    study, blocker = tmp_path / "tiny.toml", tmp_path / "file"
    study.write_text(TINY)
    blocker.write_text("x")
    err = one_line_error(capsys, main(["study", str(study), "--out", str(blocker / "run")]))
    assert str(blocker) in err and blocker.read_text() == "x"


# --------------------------------------------------------------- impossible sizes and values, before any work


def _k0(tmp_path):
    d = hybridfit.synthetic_proposals(2, seed=1)
    d["proposals"], d["confidences"] = d["proposals"][:, :, :0], d["confidences"][:, :, :0]
    np.savez(tmp_path / "k0.npz", **d)
    return tmp_path / "k0.npz"


@pytest.mark.parametrize("command", ["fit", "evaluate", "show"])
def test_k_0_proposals_are_refused(tmp_path, capsys, command):
    path = _k0(tmp_path)
    argv = {"fit": ["fit", str(path), "--out", str(tmp_path / "o.npz")], "evaluate": ["evaluate", str(path)],
            "show": ["show", str(tmp_path / "set"), "--proposals", str(path), "--out", str(tmp_path / "o.png")]}
    if command == "show":
        assert main(["synth", "test", "--frames", "2", "--out", str(tmp_path / "set")]) == 0
        capsys.readouterr()
    err = one_line_error(capsys, main(argv[command]))
    assert "k0.npz: 'proposals' has no proposals per joint (k = 0)" in err


def test_synth_refuses_a_negative_seed_and_an_absurd_size_before_allocating(tmp_path, capsys):
    out = tmp_path / "p.npz"
    assert "--seed: expected a non-negative integer, got -1" in one_line_error(
        capsys, main(["synth", "proposals", "--seed", "-1", "--out", str(out)]))
    err = one_line_error(capsys, main(["synth", "proposals", "--frames", "1000000000", "--out", str(out)]))
    assert "1000000000 frames of synthetic proposals (k=3) would need" in err and "at most" in err
    err = one_line_error(capsys, main(["synth", "test", "--frames", "1000000000", "--out", str(tmp_path / "set")]))
    assert "1000000000 frames of 320x240 depth and part images would need" in err
    assert list(tmp_path.iterdir()) == []


def test_an_unreachable_dask_scheduler_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("distributed")
    import socket

    from hybridfit import cluster

    from ..study.conftest import TINY

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1)
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    study = tmp_path / "tiny.toml"
    study.write_text(TINY)
    err = one_line_error(capsys, main(["study", str(study), "--quick", "--out", str(tmp_path / "run"),
                                       "--executor", "dask", "--scheduler", f"tcp://127.0.0.1:{port}"]))
    assert f"--scheduler tcp://127.0.0.1:{port}: no dask scheduler answered within 1 s" in err
