"""Docs that cannot go stale (issue 32, item 2): the commands of docs/getting-started.md and
README.md's examples run, and what they print is what the page shows.

A page shows a session as a ```` ```console ```` block: ``$ hybridfit ...`` lines, each followed
by the lines it prints (stdout and stderr, as a terminal shows them; a ``#`` starts a comment).
A line ``...`` stands for any number of lines, and ``...`` within a line for any text (a time
in seconds). The console blocks of a page run in order in one new folder, each command must
exit 0 (a page whose commands begin with another page's whole session goes on from that
session's folder and output; a first run's note that numba compiles is left out). A ```` ```python ```` block followed by a ```` ```text title="prints" ```` block runs
(in a new folder) and must print exactly that. The only other block of these pages with
``hybridfit`` commands is the install-and-test pair that tests/test_readme.py checks against
CI, so every other command on them is run here.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = ("README.md", "docs/getting-started.md")
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```\s*$", re.S | re.M)
#: the note of a first run (numba's cache empty), printed once: the pages show later runs
FIRST_RUN = "hybridfit: note: a first run: "
#: the one bash block of each page: the install-and-test commands (tests/test_readme.py)
SETUP = ['pip install -e ".[all,test,docs]" && hybridfit study studies/stepwise_vs_joint.toml --quick --out '
         'runs/stepwise_vs_joint', "python -m pytest"]


def blocks(page: str) -> list[tuple[str, str, str]]:
    """The page's fenced blocks: (language, the rest of the fence line, text)."""
    return [(m[1], m[2].strip(), m[3]) for m in FENCE.finditer((ROOT / page).read_text())]


def sessions(page: str) -> list[tuple[str, list[str]]]:
    """Every console block's commands with the lines each prints."""
    out: list[tuple[str, list[str]]] = []
    for language, _, text in blocks(page):
        if language != "console":
            continue
        for line in text.splitlines():
            if line.startswith("$ "):
                out.append((line[2:], []))
            else:
                assert out, f"{page}: a console block must start with a command: {line!r}"
                out[-1][1].append(line)
    return out


def printed_by_python(page: str) -> list[tuple[str, list[str]]]:
    """(code, the lines it prints) of each Python block followed by a ``title="prints"`` block."""
    found = blocks(page)
    return [(code, after[2].splitlines()) for (language, _, code), after in zip(found, found[1:])
            if language == "python" and after[:2] == ("text", 'title="prints"')]


def matches(expected: list[str], actual: list[str]) -> bool:
    """``actual`` as ``expected`` shows it: ``...`` lines stand for any lines, ``...`` in a line for any text."""
    pattern = "".join("(?:.*\n)*?" if line == "..." else ".*".join(map(re.escape, line.split("..."))) + "\n"
                      for line in expected)
    return re.fullmatch(pattern, "".join(f"{line}\n" for line in actual)) is not None


def run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "100"}  # stdout and stderr in the order printed
    return subprocess.run(argv, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=600)


#: the pages whose sessions ran: their commands, what each printed and the folder they left
_RAN: dict[str, tuple[list[list[str]], list[list[str]], Path]] = {}


@pytest.mark.parametrize("page", PAGES)
def test_the_pages_commands_print_what_the_page_shows(page, tmp_path):
    steps = sessions(page)
    assert steps, f"{page} shows no command session"
    commands = [shlex.split(command, comments=True) for command, _ in steps]
    assert all(argv[0] == "hybridfit" for argv in commands), f"{page}: only hybridfit commands are run"
    # a page whose commands begin with another page's whole session (README's three are getting-started's
    # first three) starts from that session's folder and printed lines instead of running them again
    reused = max((r for r in _RAN.values() if commands[:len(r[0])] == r[0]), key=lambda r: len(r[0]),
                 default=([], [], None))
    if reused[2] is not None:
        shutil.copytree(reused[2], tmp_path, dirs_exist_ok=True)
    printed = list(reused[1])
    for argv in commands[len(printed):]:
        done = run([sys.executable, "-m", "hybridfit", *argv[1:]], tmp_path)
        assert done.returncode == 0, f"{page}: $ {shlex.join(argv)}\n{done.stdout}"
        printed.append([line for line in done.stdout.splitlines() if not line.startswith(FIRST_RUN)])
    _RAN[page] = (commands, printed, tmp_path)
    for (command, expected), actual in zip(steps, printed):
        assert matches(expected, actual), (f"{page}: $ {command} printed\n" + "\n".join(actual)
                                           + "\n\nwhile the page shows\n" + "\n".join(expected))


@pytest.mark.parametrize("page", PAGES)
def test_the_pages_python_prints_what_the_page_shows(page, tmp_path):
    for code, expected in printed_by_python(page):
        done = run([sys.executable, "-c", code], tmp_path)
        assert done.returncode == 0, done.stdout
        assert matches(expected, done.stdout.splitlines()), (f"{page}: the Python example printed\n{done.stdout}\n"
                                                             "while the page shows\n" + "\n".join(expected))


def test_readmes_python_example_is_checked():
    (code, expected), = printed_by_python("README.md")
    assert "hybridfit.fit(" in code and expected


@pytest.mark.parametrize("page", PAGES)
def test_every_other_hybridfit_command_on_the_page_is_in_a_console_block(page):
    bash = [[line for line in text.splitlines() if line.strip()] for language, _, text in blocks(page)
            if language in ("bash", "sh", "shell", "text")]
    other = [b for b in bash if b != SETUP and any(re.match(r"\s*(\$ )?hybridfit ", line) for line in b)]
    assert SETUP in bash and not other, f"{page}: hybridfit commands outside a console block are not run: {other}"


def test_the_matching_rules():
    assert matches(["a", "...", "d"], ["a", "b", "c", "d"]) and matches(["a", "...", "b"], ["a", "b"])
    assert matches(["took ... s -> x"], ["took 5.4 s -> x"]) and not matches(["took ... s -> x"], ["took 5.4 s -> y"])
    assert not matches(["a"], ["a", "b"]) and not matches(["a", "b"], ["a"]) and not matches(["7.62 mm"], ["7.63 mm"])
