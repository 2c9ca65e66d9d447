"""README.md: its two set-up commands are exactly what CI runs and it stays short (its Python
and command-line examples run and print what it shows: tests/test_doc_examples.py)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

from hybridfit.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
SETUP = 'pip install -e ".[all,test,docs]" && hybridfit study studies/stepwise_vs_joint.toml --quick --out runs/stepwise_vs_joint'


def code_blocks(text: str, language: str) -> list[list[str]]:
    return [[line for line in block.splitlines() if line.strip()]
            for block in re.findall(rf"```{language}\n(.*?)```", text, re.S)]


def readme_commands() -> list[str]:
    return code_blocks(README, "bash")[0]


def test_readme_starts_with_install_and_test_commands():
    assert readme_commands() == [SETUP, "python -m pytest"]


def test_getting_started_gives_the_same_two_commands():
    page = (ROOT / "docs" / "getting-started.md").read_text()
    assert code_blocks(page, "bash")[0] == readme_commands()


#: .ci/run's line before the README's commands: headless Chromium for tests/cli/test_view.py, guarded so that a
#: machine without apt (or where it fails) still runs the tests (the browser tests are then skipped)
CHROMIUM = ('if command -v apt-get >/dev/null 2>&1; then { apt-get update -qq && DEBIAN_FRONTEND=noninteractive '
            'apt-get install -y -qq chromium >/dev/null; } || echo "chromium not installed: the browser tests will be '
            'skipped"; fi')
#: then Khronos' glTF validator for tests/exports/test_gltf.py, where npm is there, never failing the run
VALIDATOR = ('if command -v npm >/dev/null 2>&1; then npm install -g --silent gltf-validator >/dev/null 2>&1 || '
             'echo "gltf-validator not installed: its test will be skipped"; fi')


def test_ci_installs_chromium_then_runs_the_readme_commands_in_order():
    ci = [line for line in (ROOT / ".ci/run").read_text().splitlines() if line and not line.startswith(("#", "set ", "cd "))]
    assert ci == [CHROMIUM, VALIDATOR, *readme_commands()]


def test_the_chromium_line_never_fails_the_run(tmp_path):
    """Without apt-get on the PATH, and with an apt-get that fails, the line exits 0 (set -e goes on)."""
    import os

    for body in (None, "exit 100"):
        bin_dir = tmp_path / ("fails" if body else "none")
        bin_dir.mkdir()
        if body:
            (bin_dir / "apt-get").write_text(f"#!/bin/sh\n{body}\n")
            (bin_dir / "apt-get").chmod(0o755)
        done = subprocess.run(["/bin/bash", "-euo", "pipefail", "-c", CHROMIUM], capture_output=True, text=True,
                              env={**os.environ, "PATH": str(bin_dir)})
        assert done.returncode == 0, done.stderr


def test_readme_is_short():
    assert len(README.splitlines()) <= 250


def test_every_command_in_the_cli_page_table_exists():
    text = (ROOT / "docs" / "cli.md").read_text()
    documented = set(re.findall(r"^\| `hybridfit ([a-z-]+)", text, re.M))
    commands = set(build_parser()._subparsers._group_actions[0].choices)
    assert documented and documented <= commands, documented - commands


# README's Python and command-line examples run, and print what README shows: tests/test_doc_examples.py
