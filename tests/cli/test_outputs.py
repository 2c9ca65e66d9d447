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
    err = capsys.readouterr().err
    assert code == expected, err
    assert "Traceback" not in err and err.startswith("hybridfit: error:") and err.count("\n") == 1, err
    return err


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
