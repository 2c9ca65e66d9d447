"""The base of every plugin: a plain object configured by typed pydantic settings.

Like a scikit-learn estimator, a plugin takes its parameters as keywords, validates them
into ``self.settings`` (an instance of the class attribute ``Settings``) and keeps no
other hidden state. ``type(p)(**p.get_params())`` rebuilds an equal plugin. A plugin that
needs an optional library declares it in ``requires`` (see :mod:`hybridfit.optional`).
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

from pydantic import BaseModel, ConfigDict, ValidationError

from .errors import HybridfitError
from .optional import require


class Settings(BaseModel):
    """Base class of plugin settings: unknown keys are refused, values are validated."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class _RegisteredName:
    """``cls.name``: the entry-point name the class itself is registered under ('' if none),
    asked of the registry, which writes nothing onto classes. A class may set its own."""

    def __get__(self, obj, cls) -> str:
        from .registry import name_of

        return name_of(cls)


class Plugin:
    """A configurable plugin. Subclasses set ``Settings``."""

    Settings: ClassVar[type[Settings]] = Settings
    #: the entry-point name the plugin class is registered under ('' for an unregistered class)
    name: ClassVar[str] = _RegisteredName()  # type: ignore[assignment]
    #: optional libraries the plugin imports, {import name: pip requirement that installs it},
    #: e.g. {"nlopt": "hybridfit[nlopt]"}; creating the plugin without one raises MissingLibrary
    requires: ClassVar[Mapping[str, str]] = {}

    def __init__(self, **params: Any) -> None:
        require(f"plugin {type(self).name or type(self).__name__!r}", self.requires)
        too_deep = nested_too_deep(params)
        if too_deep is not None:
            raise HybridfitError(f"{type(self).__name__} settings: {too_deep}: nested more than {MAX_NESTING} levels "
                                 "deep")
        try:
            self.settings = self.Settings(**params)
        except ValidationError as err:
            raise HybridfitError(f"{type(self).__name__} settings: {format_validation_error(err, self.Settings)}") from None

    def get_params(self) -> dict[str, Any]:
        """The settings as a plain dict (JSON/TOML friendly)."""
        return self.settings.model_dump(mode="json")

    def with_params(self, **changes: Any):
        """A new plugin of the same type with some settings changed."""
        return type(self)(**{**self.get_params(), **changes})

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and self.settings == other.settings

    def __hash__(self) -> int:
        return hash((type(self), self.settings))

    def __repr__(self) -> str:
        defaults = self.Settings().model_dump(mode="json") if _has_defaults(self.Settings) else {}
        changed = {k: v for k, v in self.get_params().items() if defaults.get(k, object()) != v}
        args = ", ".join(f"{k}={v!r}" for k, v in changed.items())
        return f"{type(self).__name__}({args})"


def declare_offers(cls: type, forms: tuple[str, ...], supersedes: Mapping[str, tuple[str, ...]]) -> None:
    """Set ``cls.offers``, what a plugin class offers the core (a frozenset of the ``forms``),
    from the methods the class defines itself, at the class's creation (``__init_subclass__``):
    its parent's offers, less those that a method it defines supersedes (``supersedes``: form ->
    the forms it replaces), plus the forms it defines. A class that sets ``offers`` in its own
    body declares it outright. The core reads only ``offers``: a subclass's override is honoured
    by construction, never found by searching the class hierarchy."""
    if "offers" in vars(cls):
        cls.offers = frozenset(cls.offers)
        unknown = sorted(cls.offers - set(forms))
        if unknown:
            raise TypeError(f"{cls.__name__}.offers: unknown {unknown}; the forms are {forms}")
        return
    own = {form for form in forms if form in vars(cls)}
    inherited = set(getattr(cls, "offers", frozenset()))
    for form in own:
        inherited -= set(supersedes.get(form, ()))
    cls.offers = frozenset(inherited | own)


#: how deep settings may nest (tables and lists within one another): deeper ones cannot be
#: pickled for worker processes, printed or written as JSON
MAX_NESTING = 32


def nested_too_deep(params: Mapping[str, Any], limit: int = MAX_NESTING) -> str | None:
    """The setting (its name) whose value nests tables or lists more than ``limit`` levels
    deep, or None; walked without recursion, so any depth is safe to ask about."""
    for name, value in params.items():
        level = [value]
        for _ in range(limit):
            level = [v for x in level if isinstance(x, (dict, list, tuple, set, frozenset))
                     for v in (x.values() if isinstance(x, dict) else x)]
            if not level:
                break
        else:
            if any(isinstance(x, (dict, list, tuple, set, frozenset)) for x in level):
                return str(name)
    return None


def _has_defaults(settings: type[Settings]) -> bool:
    return all(not f.is_required() for f in settings.model_fields.values())


def format_validation_error(err: ValidationError, cls: type[BaseModel] | None = None) -> str:
    """One line naming each offending field path and what is wrong with it; with the settings
    class ``cls``, an unknown setting gets the closest valid one (``did you mean 'x'?``)."""
    parts = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(settings)"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown setting" + closest_key(cls, e["loc"])
        parts.append(f"{loc}: {msg}")
    return "; ".join(parts)


def closest_key(cls: type[BaseModel] | None, loc) -> str:
    """`` (did you mean 'key'?)`` for the unknown key at ``loc`` of settings class ``cls`` (its
    nested tables followed), or ''."""
    import difflib
    import typing

    for part in loc[:-1] if cls is not None else ():
        field = getattr(cls, "model_fields", {}).get(str(part))
        inner = [] if field is None else [a for a in (field.annotation, *typing.get_args(field.annotation))
                                          if isinstance(a, type) and issubclass(a, BaseModel)]
        if not inner:
            return ""
        cls = inner[0]
    names = [f.alias or n for n, f in getattr(cls, "model_fields", {}).items()]
    close = difflib.get_close_matches(str(loc[-1]), names, n=1) if loc and names else []
    return f" (did you mean {close[0]!r}?)" if close else ""
