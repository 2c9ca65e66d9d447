"""Names from users and plugins, made safe for every writer.

Names (joint, parameter, variant and study names, grid values, file names) come from files
and plugins hybridfit does not control. Every writer passes them through one of these:

- :func:`check_name` refuses control characters (NUL, newlines, tabs, escapes), which break
  tables, CSV rows and terminals, with one line naming where the name came from;
- :func:`markdown` escapes a name for a Markdown table cell or heading: HTML is inert
  (``<``, ``>``, ``&`` as entities), Markdown's own markup is escaped, so a name is shown
  as written and never becomes a link, an image or a tag;
- :func:`csv_cell` neutralises a spreadsheet formula (a cell starting with ``=``, ``+``,
  ``-``, ``@``, a tab or a carriage return gets a leading ``'``, OWASP's rule), numbers
  that merely start with a sign excepted;
- :func:`plain` makes a name safe for matplotlib text (``$`` is mathtext there, so it is
  escaped) and for a terminal that cannot print it (unencodable characters as escapes).
"""

from __future__ import annotations

import re
import unicodedata

from .errors import HybridfitError

__all__ = ["check_name", "control_characters", "csv_cell", "markdown", "plain"]


def control_characters(name: str) -> list[str]:
    """The control and format characters (Unicode categories Cc, Cf, Cs) in ``name``, as escapes."""
    return sorted({repr(ch)[1:-1] for ch in name if unicodedata.category(ch) in ("Cc", "Cf", "Cs")})


def check_name(name, where: str) -> str:
    """``name`` as a ``str`` if it holds no control character; otherwise a one-line
    :class:`~hybridfit.errors.HybridfitError` naming ``where`` (a file and field, say)."""
    name = str(name)
    bad = control_characters(name)
    if bad:
        raise HybridfitError(f"{where}: name {name!r} holds control characters ({', '.join(bad)}); "
                             "names must be printable")
    return name


_MARKDOWN = re.compile(r"([\\`*_\[\]#!|~])")


def markdown(value) -> str:
    """``value`` as inert text in a Markdown table cell or heading (one line, no HTML, no
    markup: ``<script>`` is shown, not run; ``[a](javascript:...)`` is shown, not linked)."""
    text = str(value)
    text = "".join(" " if unicodedata.category(ch) in ("Cc", "Cf", "Cs") else ch for ch in text)
    text = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")
    return _MARKDOWN.sub(r"\\\1", text)


_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$|^[+-]?(inf|nan)$", re.IGNORECASE)


def csv_cell(value) -> str:
    """``value`` as a CSV cell a spreadsheet shows as text: a leading ``= + - @``, tab or
    carriage return (a formula) gets a ``'`` in front; a plain number is kept as it is."""
    text = str(value)
    if text and text[0] in "=+-@\t\r" and not _NUMBER.match(text):
        return "'" + text
    return text


def plain(value, encoding: str | None = None) -> str:
    """``value`` as literal matplotlib text (``$`` escaped, so no mathtext is parsed) and, if
    ``encoding`` is given, with the characters it cannot encode as ``\\x..`` escapes."""
    text = str(value).replace("$", r"\$")
    if encoding:
        text = text.encode(encoding, errors="backslashreplace").decode(encoding)
    return text
