"""Every option of every command has help, and ``--frames`` has one meaning (issue 32, item 5):
START:STOP or N (the first N) in every command that reads frames; N frames made in ``synth``."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from hybridfit.cli import build_parser, main
from hybridfit.datasets.folder import load_dataset
from hybridfit.cli._common import FRAMES_HELP, frames_range, positive_int

from .test_synth import SMALL_GRID


def commands(parser=None, name="hybridfit"):
    """(name, parser) of every command and subcommand."""
    parser = parser or build_parser()
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child, sub in action.choices.items():
                yield from commands(sub, f"{name} {child}")


def test_every_option_and_argument_has_help():
    missing = [f"{name} {a.option_strings or a.dest}" for name, parser in commands() for a in parser._actions
               if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) and not a.help]
    assert not missing, missing


def frames_options():
    return {name: next(a for a in parser._actions if "--frames" in a.option_strings) for name, parser in commands()
            if any("--frames" in a.option_strings for a in parser._actions)}


def test_frames_means_one_thing_in_every_command_that_reads_frames():
    found = frames_options()
    reading = {n for n in found if not n.startswith("hybridfit synth")}
    assert reading == {f"hybridfit {c}" for c in ("train", "propose", "estimate", "evaluate", "calibrate", "show",
                                                  "proposals from-results")}
    for name in reading:
        action = found[name]
        assert action.type is frames_range and action.metavar == "START:STOP" and FRAMES_HELP in action.help, name
    for name in {n for n in found if n.startswith("hybridfit synth")}:  # synth makes N frames
        action = found[name]
        assert action.type is positive_int and action.metavar == "N" and "frames to make" in action.help, name
    assert set(found) - reading == {"hybridfit synth proposals", "hybridfit synth train", "hybridfit synth test"}


@pytest.mark.parametrize("text, parsed", [("5", ":5"), ("2:7", "2:7"), (":3", ":3"), ("4:", "4:"), (":", ":"),
                                          ("-3:", "-3:")])
def test_frames_takes_start_stop_or_n(text, parsed):
    assert frames_range(text) == parsed


@pytest.mark.parametrize("text", ["0", "-2", "a", "1:2:3", "1-4", ""])
def test_a_bad_frames_value_is_refused(text):
    with pytest.raises(argparse.ArgumentTypeError, match="expected START:STOP or N"):
        frames_range(text)


def test_both_forms_select_the_same_frames_everywhere(capsys):
    parser = build_parser()
    for argv in (["train", "d", "--out", "f.npz"], ["evaluate", "p.npz"], ["show", "d", "--out", "a.gif"]):
        assert parser.parse_args([*argv, "--frames", "3"]).frames == parser.parse_args([*argv, "--frames", ":3"]).frames
    assert main(["evaluate", "p.npz", "--frames", "x"]) == 2
    assert "--frames: expected START:STOP or N (the first N frames), got 'x'" in capsys.readouterr().err


def test_synth_train_makes_n_frames_of_the_grid_spread_over_it(tmp_path, capsys):
    """synth train --frames N: a size option (the whole grid is 1.7 GB); the frames are the grid's own,
    drawn at random as a study's train_subset draws them."""
    from hybridfit.synthetic.poses import grid_poses, grid_subset

    config = tmp_path / "grid.toml"
    config.write_text(SMALL_GRID)
    out = tmp_path / "train"
    assert main(["synth", "train", "--out", str(out), "--config", str(config), "--frames", "3", "--seed", "4"]) == 0
    assert "wrote 3 of the training grid's 8 frames" in capsys.readouterr().out
    ds = load_dataset(out)
    chosen = grid_subset(8, 3, 4)
    assert ds.frames == 3 and list(chosen) == sorted(set(chosen))
    np.testing.assert_array_equal(ds.params, grid_poses({**_grid(config), "seed": 4})[chosen])
    assert grid_subset(8, 8, 4) is None and grid_subset(8, None, 4) is None  # all: the whole grid


def _grid(path):
    import tomllib

    return tomllib.loads(path.read_text())
