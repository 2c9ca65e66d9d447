"""The ``hybridfit`` command line.

Each subcommand is one module of this package that defines ``register(subparsers)``; they
are found by listing the package, so adding a command never edits this file. User errors
print one line and exit with code 2; an interrupt exits with 130 after saving finished work.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import warnings

from pydantic import ValidationError

from ..errors import HybridfitError
from ..plugin import format_validation_error


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except HybridfitError as err:
        print(f"hybridfit: error: {err}", file=sys.stderr)
        return 2
    except ValidationError as err:
        print(f"hybridfit: error: {format_validation_error(err)}", file=sys.stderr)
        return 2
    except (FileNotFoundError, IsADirectoryError, PermissionError) as err:
        print(f"hybridfit: error: {err.filename}: {err.strerror}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("hybridfit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
