"""`hybridfit --version`, and a bare `hybridfit`: the usage and every command with its help."""

from __future__ import annotations

import subprocess
import sys

import hybridfit
from hybridfit.cli import build_parser, main


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"hybridfit {hybridfit.__version__}\n"


def test_a_bare_hybridfit_prints_the_usage_and_the_commands(capsys):
    assert main([]) == 2  # a missing command is a user error
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err
    assert err.startswith("usage: hybridfit [-h] [--version] COMMAND ...") and "Traceback" not in err
    commands = build_parser()._subparsers._group_actions[0]
    for choice in commands._choices_actions:  # every command, with its one-line help
        assert f"    {choice.dest}" in err and choice.help.split()[0] in err
    assert {"export", "view", "show", "fit"} <= set(commands.choices)


def test_the_installed_script_prints_the_same():
    done = subprocess.run([sys.executable, "-m", "hybridfit"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stderr.startswith("usage: hybridfit") and "export" in done.stderr
    done = subprocess.run([sys.executable, "-m", "hybridfit", "--version"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout == f"hybridfit {hybridfit.__version__}\n"
