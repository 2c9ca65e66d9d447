"""A Griffe extension: reST roles in docstrings (``:func:`x```, ``:class:`~a.B```) as links.

The package's docstrings use Sphinx's roles, which mkdocstrings shows raw. Each role becomes
an autorefs cross-reference to its target (a leading ``~`` shows the last name only; a
leading ``.`` is relative to the docstring's module; ``text <target>`` gives the text): a
link where the target is on the site, its name in code where it is not (an ``optional``
reference: private helpers are not documented, and that is no broken link).
"""

from __future__ import annotations

import html
import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|attr|data|exc|obj|const):`(?P<body>[^`]+)`")


def target_of(body: str, module: str, package: bool = False) -> tuple[str, str]:
    """(identifier, shown text) of a role's body in the docstring of ``module`` (``package``:
    an ``__init__``, which is its own package for relative names, as in Python)."""
    text, _, bracketed = body.partition(" <")
    if bracketed.endswith(">"):
        target, shown = bracketed[:-1], text
    else:
        target, shown = body, None
    short = target.startswith("~")
    target = written = target.lstrip("~")
    if target.startswith("."):
        up = len(target) - len(target.lstrip("."))
        base = module.split(".")
        target = ".".join(base[: len(base) - up + package] + [target.lstrip(".")])
    elif "." not in target:  # a name of the docstring's own module
        target = f"{module}.{target}"
    if shown is None:
        shown = target.rsplit(".", 1)[-1] if short else written.lstrip(".")
    return target, shown


def roles_to_links(text: str, module: str, package: bool = False) -> str:
    """``text`` with every reST role as an optional autorefs reference."""
    def link(m: re.Match) -> str:
        target, shown = target_of(m["body"], module, package)
        return (f'<autoref identifier="{html.escape(target)}" optional><code>{html.escape(shown)}</code>'
                f"</autoref>")

    return ROLE.sub(link, text)


class RestRoles(griffe.Extension):
    """Rewrites the roles of every loaded object's docstring (see the module docstring)."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            module = obj.module
            obj.docstring.value = roles_to_links(obj.docstring.value, module.path, module.is_package)
