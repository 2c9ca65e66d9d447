"""Plugin discovery through Python entry points.

Three entry-point groups: ``hybridfit.models``, ``hybridfit.objectives`` and
``hybridfit.optimizers``. The core never imports a plugin by name: every plugin, the
reference ones included, is found here. A plugin whose import fails (its module raises, or
its entry point names an attribute the module lacks) is a bug of that plugin: listing
plugins warns, naming the entry point and its error, and every other plugin keeps working;
asking for it (:func:`get`) raises a :class:`~hybridfit.errors.PluginError` naming the plugin
and its entry point. A plugin whose optional library is missing (``Plugin.requires``) is
listed as unavailable, with the ``pip install`` line that fixes it, and creating it raises
:class:`~hybridfit.optional.MissingLibrary` (a user error), as does a plugin module that
imports its library through :func:`~hybridfit.optional.import_library`.
"""

from __future__ import annotations

import difflib
import functools
import importlib.metadata as metadata
import sys
import warnings
from dataclasses import dataclass
from typing import Any, Mapping

from . import optional
from .errors import HybridfitError, PluginError, UnknownPluginError

GROUPS = {
    "model": "hybridfit.models",
    "objective": "hybridfit.objectives",
    "optimizer": "hybridfit.optimizers",
}


@dataclass(frozen=True)
class PluginInfo:
    """One registered plugin: its name, distribution, one-line doc, load error (if any) and,
    when an optional library it needs is missing, the line saying which and how to install it."""

    kind: str
    name: str
    value: str
    distribution: str
    doc: str
    error: str | None
    unavailable: str | None = None


def _group(kind: str) -> str:
    try:
        return GROUPS[kind]
    except KeyError:
        raise HybridfitError(f"unknown plugin kind {kind!r}; choose from {sorted(GROUPS)}") from None


@functools.cache
def _entry_points(kind: str) -> dict[str, metadata.EntryPoint]:
    """The group's entry points by name (read once per process; see :func:`refresh`)."""
    found: dict[str, metadata.EntryPoint] = {}
    for ep in metadata.entry_points(group=_group(kind)):
        other = found.get(ep.name)
        if other is not None and other.value != ep.value:
            warnings.warn(
                f"hybridfit: {_group(kind)} entry point {ep.name!r} is registered twice "
                f"({other.value} and {ep.value}); using the first",
                stacklevel=3,
            )
            continue
        found[ep.name] = ep
    return found


def refresh() -> None:
    """Forget the entry points read so far (after installing a plugin package at run time)."""
    _entry_points.cache_clear()
    _NAMES.clear()


def names(kind: str) -> list[str]:
    """Registered plugin names of a kind ('model', 'objective' or 'optimizer')."""
    return sorted(_entry_points(kind))


def _load(kind: str, ep: metadata.EntryPoint) -> type:
    return ep.load()


#: classes found registered, by class: their entry-point name (see name_of)
_NAMES: dict[type, str] = {}


def name_of(cls: type) -> str:
    """The name ``cls`` itself is registered under, '' if it is not (a subclass of a
    registered plugin is not registered by inheritance). Writes nothing onto the class and
    imports nothing: only entry points whose module is already imported can name it."""
    name = _NAMES.get(cls)
    if name is not None:
        return name
    for kind in GROUPS:
        for ep in _entry_points(kind).values():
            module = sys.modules.get(ep.module)
            if module is None:
                continue
            obj = module
            for part in (ep.attr or "").split("."):
                obj = getattr(obj, part, None)
            if obj is cls:
                _NAMES[cls] = ep.name
                return ep.name
    return ""


def get(kind: str, name: str) -> type:
    """The plugin class registered under ``name``.

    Raises UnknownPluginError listing the registered names and the closest match;
    :class:`~hybridfit.optional.MissingLibrary` when the plugin's module needs an optional
    library that is not installed; PluginError naming the plugin and its entry point when
    its import fails otherwise.
    """
    eps = _entry_points(kind)
    if name not in eps:
        known = sorted(eps)
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise UnknownPluginError(
            f"unknown {kind} {name!r}{hint} (registered {kind}s: {', '.join(known) or 'none'})"
        )
    try:
        return _load(kind, eps[name])
    except optional.MissingLibrary:  # the user's to install: one line with the pip command
        raise
    except Exception as err:  # a broken plugin: its bug, named, never a user error or ours
        raise PluginError(
            f"{kind} plugin {name!r} ({_group(kind)} = {eps[name].value}) failed to import: "
            f"{type(err).__name__}: {err}"
        ) from err


def create(kind: str, spec: Any, config: Mapping[str, Any] | None = None):
    """A configured plugin from a name (plus settings) or an existing plugin instance."""
    if isinstance(spec, str):
        return get(kind, spec)(**dict(config or {}))
    if config:
        return spec.with_params(**config)
    return spec


def available(kind: str) -> list[PluginInfo]:
    """Every registered plugin of a kind; import failures are warned about and kept, a module
    that needs a missing optional library is listed as unavailable."""
    infos = []
    for name, ep in sorted(_entry_points(kind).items()):
        dist = ep.dist.name if ep.dist is not None else "?"
        try:
            cls = _load(kind, ep)
            doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
            error = None
            unavailable = optional.unavailable(f"plugin {name!r}", getattr(cls, "requires", {}))
        except optional.MissingLibrary as err:
            doc, error, unavailable = "", None, str(err)
        except Exception as err:
            doc, error, unavailable = "", f"{type(err).__name__}: {err}", None
            warnings.warn(
                f"hybridfit: plugin {name!r} ({_group(kind)} = {ep.value}) failed to import: {error}",
                stacklevel=2,
            )
        infos.append(PluginInfo(kind, name, ep.value, dist, doc, error, unavailable))
    return infos
