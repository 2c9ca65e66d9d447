"""Plugin discovery through Python entry points.

Three entry-point groups: ``hybridfit.models``, ``hybridfit.objectives`` and
``hybridfit.optimizers``. The core never imports a plugin by name: every plugin, the
reference ones included, is found here. Entry points are imported lazily, by name, when a
plugin is used (:func:`get`): listing names (:func:`names`, :func:`entry_points`) imports
nothing, so a slow or broken plugin costs nothing to a command that does not use it; only
:func:`available` (``hybridfit plugins``) imports them all, to report on them.

A plugin whose import fails (its module raises anything, ``SystemExit`` included, but a
``KeyboardInterrupt``; or its entry point names an attribute the module lacks) is a bug of
that plugin: listing plugins warns, naming the entry point and its error, and every other
plugin keeps working; asking for it (:func:`get`) raises a
:class:`~hybridfit.errors.PluginError` naming the plugin and its entry point. A plugin whose
optional library is missing (``Plugin.requires``) is listed as unavailable, with the ``pip
install`` line that fixes it, and creating it raises
:class:`~hybridfit.optional.MissingLibrary` (a user error), as does a plugin module that
imports its library through :func:`~hybridfit.optional.import_library`.

Names are unique. The built-in plugins (the entry points of the ``hybridfit`` distribution
itself) keep their names: another distribution registering one of them is ignored (never
imported), warned about when that name is used and listed as a conflict by
:func:`available`. A name that two other distributions both register is ambiguous: asking
for it is a :class:`~hybridfit.errors.HybridfitError` naming both (uninstall one).
"""

from __future__ import annotations

import difflib
import functools
import importlib
import importlib.metadata as metadata
import re
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
    when an optional library it needs is missing, the line saying which and how to install it.
    ``conflict``: why this entry point is not used (it takes a built-in's name, or another
    distribution registers the same name); such entries are listed, never imported."""

    kind: str
    name: str
    value: str
    distribution: str
    doc: str
    error: str | None
    unavailable: str | None = None
    conflict: str | None = None


def _group(kind: str) -> str:
    try:
        return GROUPS[kind]
    except KeyError:
        raise HybridfitError(f"unknown plugin kind {kind!r}; choose from {sorted(GROUPS)}") from None


#: the distribution whose entry points are the built-in plugins
BUILTIN = "hybridfit"


def distribution(ep: metadata.EntryPoint) -> str:
    """The name of the distribution that registers ``ep`` ('?' when unknown)."""
    dist = getattr(ep, "dist", None)
    return dist.name if dist is not None and dist.name else "?"


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _label(ep: metadata.EntryPoint) -> str:
    return f"{distribution(ep)} ({ep.value})"


@dataclass(frozen=True)
class _Scan:
    """A group's entry points: ``used`` (one per name), ``ignored`` (entry points that take a
    built-in's name) and ``ambiguous`` (names registered by several other distributions)."""

    used: dict[str, metadata.EntryPoint]
    ignored: dict[str, list[metadata.EntryPoint]]
    ambiguous: dict[str, list[metadata.EntryPoint]]


@functools.cache
def _scan(kind: str) -> _Scan:
    """Read the group's entry points once per process (see :func:`refresh`); imports nothing."""
    by_name: dict[str, list[metadata.EntryPoint]] = {}
    for ep in metadata.entry_points(group=_group(kind)):
        same = by_name.setdefault(ep.name, [])
        if not any(o.value == ep.value and _normal(distribution(o)) == _normal(distribution(ep)) for o in same):
            same.append(ep)  # (one distribution found twice on sys.path counts once)
    used, ignored, ambiguous = {}, {}, {}
    for name, eps in by_name.items():
        builtin = [ep for ep in eps if _normal(distribution(ep)) == BUILTIN]
        others = [ep for ep in eps if _normal(distribution(ep)) != BUILTIN]
        if builtin:
            used[name] = builtin[0]
            if others:
                ignored[name] = others
        elif len({_normal(distribution(ep)) for ep in others}) > 1:
            ambiguous[name] = others
        else:
            used[name] = others[0]
    return _Scan(used, ignored, ambiguous)


def _entry_points(kind: str) -> dict[str, metadata.EntryPoint]:
    return _scan(kind).used


def entry_points(kind: str) -> dict[str, metadata.EntryPoint]:
    """The entry points in use by name (conflicting ones left out), none of them imported."""
    return dict(_scan(kind).used)


#: (kind, name) of the built-ins whose taken name was warned about in this process
_WARNED: set[tuple[str, str]] = set()


def refresh() -> None:
    """Forget the entry points read so far (after installing a plugin package at run time)."""
    _scan.cache_clear()
    _NAMES.clear()
    _WARNED.clear()


def names(kind: str) -> list[str]:
    """Registered plugin names of a kind ('model', 'objective' or 'optimizer'); imports nothing."""
    scan = _scan(kind)
    return sorted({*scan.used, *scan.ambiguous})


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
    """The plugin class registered under ``name``; imports its module only (and only now). A
    ``module:qualname`` name is an unregistered class a fit recorded (:func:`unregistered`).

    Raises UnknownPluginError listing the registered names and the closest match;
    HybridfitError when two distributions other than hybridfit register the name;
    :class:`~hybridfit.optional.MissingLibrary` when the plugin's module needs an optional
    library that is not installed; PluginError naming the plugin and its entry point when
    its import fails otherwise (any exception, ``SystemExit`` included, but a
    KeyboardInterrupt). A third-party entry point taking a built-in's name is never used:
    the built-in is returned, with a warning naming the other.
    """
    if ":" in name:
        return unregistered(kind, name)
    scan = _scan(kind)
    if name in scan.ambiguous:
        eps = scan.ambiguous[name]
        raise HybridfitError(
            f"{kind} {name!r} is registered by {len(eps)} distributions ({', '.join(_label(ep) for ep in eps)}) "
            f"in {_group(kind)}; hybridfit cannot tell which is meant: uninstall all but one"
        )
    eps = scan.used
    if name not in eps:
        known = names(kind)
        close = difflib.get_close_matches(name, known, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise UnknownPluginError(
            f"unknown {kind} {name!r}{hint} (registered {kind}s: {', '.join(known) or 'none'})"
        )
    if name in scan.ignored and (kind, name) not in _WARNED:  # once per process
        _WARNED.add((kind, name))
        warnings.warn(
            f"{kind} {name!r} is also registered by {', '.join(_label(ep) for ep in scan.ignored[name])}; "
            f"the built-in is used and the other is ignored: a plugin may not take a built-in's name",
            stacklevel=2,
        )
    try:
        return _load(kind, eps[name])
    except optional.MissingLibrary:  # the user's to install: one line with the pip command
        raise
    except KeyboardInterrupt:  # Ctrl-C (or a stop signal) during the import: stop, as anywhere else
        raise
    except BaseException as err:  # a broken plugin (SystemExit too): its bug, named, never an exit or ours
        raise PluginError(
            f"{kind} plugin {name!r} ({_group(kind)} = {eps[name].value}) failed to import: "
            f"{type(err).__name__}: {err}"
        ) from err


#: the base class of each kind's plugins, by kind (``module:class``, imported when asked)
BASES = {"model": "hybridfit.model.base:HandModel", "objective": "hybridfit.objective:Objective",
         "optimizer": "hybridfit.optimizer:Optimizer"}


def _base(kind: str) -> type:
    module, _, cls = BASES[kind].partition(":")
    return getattr(importlib.import_module(module), cls)


def reference(cls: type) -> str:
    """``module:qualname`` of an unregistered plugin class, the name a fit records it by
    (:func:`get` finds it again while its module is imported)."""
    return f"{cls.__module__}:{cls.__qualname__}"


def unregistered(kind: str, name: str) -> type:
    """The unregistered plugin class ``module:qualname`` (:func:`reference`) of the kind, if its
    module is imported (nothing is imported here: a name read from a file runs no code);
    else an UnknownPluginError saying how to rebuild it."""
    module, _, qualname = name.partition(":")
    found = sys.modules.get(module)
    for part in qualname.split(".") if found is not None else ():
        found = getattr(found, part, None)
    register = f"register it in the entry-point group {_group(kind)} (docs/plugins.md, 'The entry point')"
    if found is None and ("<locals>" in qualname or module == "__main__"):
        where = "inside a function" if "<locals>" in qualname else "in a script (__main__)"
        raise UnknownPluginError(f"{kind} {name!r} is a class defined {where}, not registered as a plugin, which "
                                 f"nothing can find again: define it at the top level of an importable module, or "
                                 f"{register} and fit with its name")
    if found is None and module in sys.modules:
        raise UnknownPluginError(f"{kind} {name!r}: module {module} has no class {qualname} (renamed or removed since "
                                 f"the fit?); {register} and fit with its name")
    if found is None:
        raise UnknownPluginError(
            f"{kind} {name!r} is a class that is not registered as a plugin (a {kind} instance passed to hybridfit "
            f"without an entry point): import {module} first to rebuild it in Python, or {register} and fit with "
            f"its name")
    if not (isinstance(found, type) and issubclass(found, _base(kind))):
        raise UnknownPluginError(f"{kind} {name!r} names no {_base(kind).__name__} class")
    return found


def create(kind: str, spec: Any, config: Mapping[str, Any] | None = None):
    """A configured plugin from a name (plus settings) or an existing plugin instance. A
    ``config`` that is not a table of settings ``{name: value}`` (``{kind}_config``) and a
    ``spec`` that is neither a name nor a plugin of the kind are refused in one line."""
    _group(kind)
    if config is not None and not (isinstance(config, Mapping) and all(isinstance(k, str) for k in config)):
        got = (f"the setting name {next(k for k in config if not isinstance(k, str))!r}"
               if isinstance(config, Mapping) else f"a {type(config).__name__}")
        raise HybridfitError(f"{kind}_config must be a table of settings {{name: value}} with string names, got {got}")
    base = _base(kind)
    if isinstance(spec, str):
        return get(kind, spec)(**dict(config or {}))
    if not isinstance(spec, base):
        raise HybridfitError(f"{kind} must be a registered name or a{'n' if base.__name__[0] in 'AEIOU' else ''} "
                             f"{base.__name__} instance, got {type(spec).__name__} {_short(spec)}")
    if config:
        return spec.with_params(**config)
    return spec


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def available(kind: str) -> list[PluginInfo]:
    """Every registered plugin of a kind, each imported to report on it: import failures are
    warned about and kept, a module that needs a missing optional library is listed as
    unavailable. Entry points that conflict (a built-in's name taken by another distribution,
    or one name registered by several) are listed with ``conflict`` set, never imported."""
    scan = _scan(kind)
    infos = []
    for name, ep in sorted(scan.used.items()):
        try:
            cls = _load(kind, ep)
            doc = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
            error = None
            unavailable = optional.unavailable(f"plugin {name!r}", getattr(cls, "requires", {}))
        except optional.MissingLibrary as err:
            doc, error, unavailable = "", None, str(err)
        except KeyboardInterrupt:
            raise
        except BaseException as err:  # SystemExit too: listed as broken, never an exit
            doc, error, unavailable = "", f"{type(err).__name__}: {err}", None
            warnings.warn(
                f"plugin {name!r} ({_group(kind)} = {ep.value}) failed to import: {error}",
                stacklevel=2,
            )
        infos.append(PluginInfo(kind, name, ep.value, distribution(ep), doc, error, unavailable))
        for other in scan.ignored.get(name, []):
            infos.append(PluginInfo(kind, name, other.value, distribution(other), "", None, conflict=(
                f"takes the name of hybridfit's built-in {kind} {name!r}: ignored (the plugin must use another name)")))
    for name, eps in sorted(scan.ambiguous.items()):
        for ep in eps:
            rivals = ", ".join(distribution(o) for o in eps if o is not ep)
            infos.append(PluginInfo(kind, name, ep.value, distribution(ep), "", None, conflict=(
                f"{rivals} registers {name!r} too: neither is used (uninstall all but one)")))
    return infos
