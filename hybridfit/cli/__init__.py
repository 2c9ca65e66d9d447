"""The ``hybridfit`` command line.

Each subcommand is one module of this package that defines ``register(subparsers)``; they
are found by listing the package, so adding a command never edits this file.

Exit codes (``hybridfit.errors``): 0 done; 2 a user error (bad input or option: one line on
stderr naming the file, key, field or frame; nothing written or overwritten); 3 the run
finished but some frames or trials failed (the rest is written, the failures listed); 130
interrupted (finished work is written); 141 the output pipe was closed (``| head``).
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
import warnings

from pydantic import ValidationError

from ..errors import EXIT_INTERRUPTED, EXIT_USER_ERROR, HybridfitError
from ..plugin import format_validation_error


EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a shell reports `cmd | head`


class _Parser(argparse.ArgumentParser):
    """Option errors as one line (no usage dump), exit code 2."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"hybridfit: error: {self.prog}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hybridfit",
        description="3D hand pose by fitting an anatomically valid hand model to joint proposals.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    warnings.formatwarning = lambda msg, cat, *a, **k: f"hybridfit: warning: {msg}\n"
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit:  # --help, or an option error already printed as one line
        return int(exit.code or 0)
    try:
        from ._common import check_declared

        check_declared(args)
        return int(args.func(args) or 0)
    except HybridfitError as err:
        print(f"hybridfit: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except ValidationError as err:
        print(f"hybridfit: error: {format_validation_error(err)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except (FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as err:
        print(f"hybridfit: error: {err.filename}: {err.strerror}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:
        _silence_stdout()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        print("hybridfit: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _one_line(err: Exception) -> str:
    return " ".join(str(err).split("\n"))


def _silence_stdout() -> None:
    """After the reader closed the pipe: send the rest of stdout (and Python's final flush)
    to /dev/null, so no second BrokenPipeError is printed at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout is not a real file (tests)
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
