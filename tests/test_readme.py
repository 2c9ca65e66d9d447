"""README.md's two set-up commands are exactly what CI runs, and its CLI table is real."""

from __future__ import annotations

import re
from pathlib import Path

from hybridfit.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_readme_starts_with_install_and_test_commands():
    install, test = readme_commands()
    assert install.startswith('pip install -e ".[test]"') and test == "python -m pytest"


def test_ci_runs_the_readme_commands_in_order():
    ci = [line for line in (ROOT / ".ci/run").read_text().splitlines() if line and not line.startswith(("#", "set ", "cd "))]
    assert ci == readme_commands()


def test_every_command_in_the_readme_table_exists():
    text = (ROOT / "README.md").read_text()
    documented = set(re.findall(r"^\| `hybridfit ([a-z-]+)", text, re.M))
    parser = build_parser()
    commands = set(parser._subparsers._group_actions[0].choices)
    assert documented and documented <= commands, documented - commands
