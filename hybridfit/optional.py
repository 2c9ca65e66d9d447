"""Optional libraries: what needs one says which, and a missing one is a user error that
names the ``pip install`` line installing it.

hybridfit's core needs only its declared dependencies. CasADi, NLopt, pymoo, cma and dask
are extras (``pip install "hybridfit[casadi]"``, ..., ``"hybridfit[all]"``). A plugin
declares the libraries it imports in ``Plugin.requires`` ({import name: pip requirement});
``hybridfit plugins`` lists it as unavailable while one is missing, and creating it raises
:class:`MissingLibrary`. Core modules that use one (``hybridfit.model.casadi``, the dask
study executor) import it through :func:`import_library`.
"""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType
from typing import Mapping

from .errors import HybridfitError


class MissingLibrary(HybridfitError):
    """An optional library is not installed; the message ends with the line that installs it."""


def install_line(requirements: list[str] | tuple[str, ...]) -> str:
    """The shell command that installs ``requirements`` (pip requirement strings)."""
    return "pip install " + " ".join(f'"{r}"' for r in requirements)


def missing(requires: Mapping[str, str]) -> dict[str, str]:
    """The entries of ``requires`` ({import name: pip requirement}) that cannot be imported.

    Looks for the libraries without importing them (a library that is present but fails to
    import fails later, when it is imported, with its own error)."""
    return {name: req for name, req in requires.items() if not _importable(name)}


def _importable(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a parent package missing, or sys.modules[name] is None
        return False


def unavailable(what: str, requires: Mapping[str, str]) -> str | None:
    """One line saying what ``what`` needs and how to install it, or None when nothing is missing."""
    absent = missing(requires)
    if not absent:
        return None
    libraries = ", ".join(absent)
    return f"{what} needs {libraries}, not installed: {install_line(sorted(set(absent.values())))}"


def require(what: str, requires: Mapping[str, str]) -> None:
    """Raise :class:`MissingLibrary` naming ``what`` and the install line when a library is missing."""
    message = unavailable(what, requires)
    if message is not None:
        raise MissingLibrary(message)


def import_library(name: str, requirement: str, what: str) -> ModuleType:
    """``import name``, or :class:`MissingLibrary` (naming ``what`` and ``pip install
    "requirement"``) when it is not installed."""
    require(what, {name.partition(".")[0]: requirement})
    return importlib.import_module(name)
