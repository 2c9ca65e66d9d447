"""Helpers shared by the CLI commands: TOML settings files and plugin options."""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path
from typing import Any

from ..errors import HybridfitError


def load_toml(path: str | None) -> dict[str, Any]:
    """A TOML file as a dict ({} for None), with errors naming the file and line."""
    if path is None:
        return {}
    p = Path(path)
    if not p.is_file():
        raise HybridfitError(f"{p}: no such file")
    try:
        return tomllib.loads(p.read_text())
    except tomllib.TOMLDecodeError as err:
        raise HybridfitError(f"{p}: invalid TOML: {err}") from None


def add_plugin_options(parser: argparse.ArgumentParser) -> None:
    """--model/--objective/--optimizer with their --*-config TOML settings files."""
    g = parser.add_argument_group("plugins")
    g.add_argument("--model", default="hand26", help="hand model plugin (default: hand26)")
    g.add_argument("--model-config", metavar="TOML", help="hand model settings file")
    g.add_argument("--objective", default="clamped-confidence", help="objective plugin (default: clamped-confidence)")
    g.add_argument("--objective-config", metavar="TOML", help="objective settings file")
    g.add_argument("--optimizer", default="stepwise-pso", help="optimizer plugin (default: stepwise-pso)")
    g.add_argument("--optimizer-config", metavar="TOML", help="optimizer settings file")


def add_fit_options(parser: argparse.ArgumentParser) -> None:
    """--budget/--seed/--jobs/--search-radius: how every frame is fitted."""
    parser.add_argument("--budget", type=positive_int, default=3400, help="objective evaluations per frame (default 3400)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--jobs", type=positive_int, default=1, help="parallel fitting processes (results do not depend on it)")
    parser.add_argument("--search-radius", type=float, default=60.0,
                        help="position search radius around the initial guess, mm")


def plugin_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments for hybridfit.fit from the plugin options."""
    return {
        "model": args.model,
        "model_config": load_toml(args.model_config),
        "objective": args.objective,
        "objective_config": load_toml(args.objective_config),
        "optimizer": args.optimizer,
        "optimizer_config": load_toml(args.optimizer_config),
    }


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value
