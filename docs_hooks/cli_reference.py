"""MkDocs hook: replaces ``<!-- cli-reference -->`` with every ``hybridfit`` command's help.

The reference is generated from the parser the command line itself uses, so every command,
subcommand and option is documented and none can go stale.
"""

from __future__ import annotations

import argparse
import os

MARKER = "<!-- cli-reference -->"


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _sections(parser: argparse.ArgumentParser, name: str, level: int) -> list[str]:
    children = _subcommands(parser)
    out = [f"{'#' * level} `{name}`", ""]
    if parser.description and level > 2:
        out += [parser.description, ""]
    out += ["```text", parser.format_help().rstrip(), "```", ""]
    for child, sub in children.items():
        out += _sections(sub, f"{name} {child}", level + 1)
    return out


def cli_reference() -> str:
    """Markdown: one section per command and subcommand, in the parser's order."""
    from hybridfit.cli import build_parser

    os.environ["COLUMNS"] = "90"  # argparse wraps at the terminal's width: fix it
    root = build_parser()
    lines: list[str] = []
    for name, sub in _subcommands(root).items():
        lines += _sections(sub, f"hybridfit {name}", 3)
    return "\n".join(lines)


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARKER not in markdown:
        return markdown
    return markdown.replace(MARKER, cli_reference())
