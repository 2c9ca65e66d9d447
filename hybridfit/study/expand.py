"""A study's deterministic expansion into variants and trials.

Variants (in file order, default one empty variant) x grid (keys in file order, values in
list order) gives the variants; each runs with every seed. ``seeds = n`` derives n seeds
from the study ``seed`` (numpy SeedSequence), the same for every variant, so variants are
compared on common random numbers. The trial key hashes the data, settings and seed.

Two variants with the same settings would be the same trials (one key each seed, the same
result), so such a sweep is refused, naming both; a variant's name holding control
characters is refused too (:func:`hybridfit.text.check_name`). The study's size is counted
from the axis lengths (:func:`count_trials`), without expanding it.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import itertools
import json
from dataclasses import dataclass
from typing import Any

from pydantic import ValidationError

from ..errors import HybridfitError
from ..text import check_name
from .spec import SETTING_KEYS, Study, SyntheticProposalsData, TrialSettings, validation_error

@dataclass(frozen=True)
class Variant:
    """One point of the sweep: its name, the overrides it makes and the resolved settings."""

    index: int
    name: str
    overrides: dict[str, Any]
    settings: TrialSettings


@dataclass(frozen=True)
class Trial:
    """One variant x one seed; ``key`` is unique for (data, settings, seed)."""

    key: str
    variant: Variant
    seed: int


def digest(payload: Any) -> str:
    """A short content hash of JSON-able data (sorted keys)."""
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def deep_merge(base: dict, over: dict) -> dict:
    """base with over merged in (tables merge recursively, other values replace)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else copy.deepcopy(v)
    return out


def _nest(path: str, value: Any) -> dict:
    out: Any = value
    for part in reversed(path.split(".")):
        out = {part: out}
    return out


def _variant_name(overrides: dict[str, Any]) -> str:
    def flat(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict) and v:
                yield from flat(v, f"{prefix}{k}.")
            else:
                yield f"{prefix}{k}", v

    return ", ".join(f"{k}={json.dumps(v) if not isinstance(v, str) else v}" for k, v in flat(overrides)) or "base"


#: a study of more trials than this runs only when asked (``allow_large``): its database grows by
#: hundreds of MB, and a grid that large is usually a mistake (a list where a range was meant)
MAX_TRIALS = 10_000


def count_variants(study: Study) -> int:
    """The number of variants the study's sweep expands into (listed variants x grid points)."""
    variants = max(1, len(study.sweep.variants or []))
    for values in study.sweep.grid.values():
        variants *= max(1, len(values))
    return variants


def count_trials(study: Study) -> int:
    """The number of trials (variants x seeds) the study plans, computed without expanding it."""
    return count_variants(study) * (len(study.seeds) if isinstance(study.seeds, list) else int(study.seeds))


def check_size(study: Study, allow_large: bool, where: str = "study") -> None:
    """Refuse a study above MAX_TRIALS trials unless ``allow_large``."""
    n = count_trials(study)
    if n > MAX_TRIALS and not allow_large:
        raise HybridfitError(f"{where}: {n:,} trials planned (variants x seeds), more than {MAX_TRIALS:,}: check the "
                             "sweep, or pass --allow-large to run them all")


def expand(study: Study, where: str = "study") -> list[Variant]:
    """The study's variants in a deterministic order (see the module docstring)."""
    for key in study.sweep.grid:
        check_name(key, f"{where}: sweep.grid")
        if key.split(".")[0] not in SETTING_KEYS:
            raise HybridfitError(f"{where}: sweep.grid.{key}: unknown setting{_closest(key, SETTING_KEYS)}; allowed: "
                                 f"{', '.join(sorted(SETTING_KEYS))}")
        if not study.sweep.grid[key]:
            raise HybridfitError(f"{where}: sweep.grid.{key}: needs at least one value")
    listed = study.sweep.variants or [{}]
    keys = list(study.sweep.grid)
    base = study.base.as_dict()
    out: list[Variant] = []
    names: set[str] = set()
    same: dict[str, tuple[str, str]] = {}  # settings -> (the first variant with them, where it is)
    for i, entry in enumerate(listed):
        entry = dict(entry)
        name = entry.pop("name", None)
        if name is not None:
            check_name(name, f"{where}: sweep.variants.{i}.name")
        for k in entry:
            check_name(k, f"{where}: sweep.variants.{i}")
        over: dict[str, Any] = {}
        for k, v in entry.items():  # dotted keys in variant tables too
            over = deep_merge(over, _nest(k, v))
        for combo in itertools.product(*(study.sweep.grid[k] for k in keys)):
            o = over
            for k, v in zip(keys, combo):
                o = deep_merge(o, _nest(k, v))
            loc = f"sweep.variants.{i}" if study.sweep.variants else "sweep.grid"
            grid_label = _variant_name(dict(zip(keys, combo))) if keys else ""
            label = ", ".join(p for p in (name or (_variant_name(over) if over else ""), grid_label) if p) or "base"
            check_name(label, f"{where}: {loc}")  # (before the label is part of a message)
            if keys:
                loc += f" ({_variant_name(dict(zip(keys, combo)))})"
            unknown = [k for k in o if k not in SETTING_KEYS]
            if unknown:
                raise HybridfitError(f"{where}: {loc}.{unknown[0]}: unknown setting{_closest(unknown[0], SETTING_KEYS)}; "
                                     f"allowed: {', '.join(sorted(SETTING_KEYS))}")
            try:
                settings = TrialSettings.model_validate(deep_merge(base, o))
            except ValidationError as err:  # named where the key was set: this variant, or [base]
                raise validation_error(where, err, loc if _sets(o, err) else "base") from None
            if label in names:
                raise HybridfitError(f"{where}: {loc}: duplicate variant name {label!r}")
            names.add(label)
            first = same.setdefault(digest(settings.as_dict()), (label, loc))
            if first != (label, loc):
                raise HybridfitError(f"{where}: {loc}: variant {label!r} has the same settings as variant {first[0]!r} "
                                     f"({first[1]}), so it would run the same trials: change or remove one")
            _check_k(study, settings, where, loc if "k" in o else "base")
            out.append(Variant(len(out), label, o, settings))
    return out


def _closest(key: str, names) -> str:
    """`` (did you mean 'x'?)`` for a misspelt dotted setting path (its first part, or the whole)."""
    first = key.split(".")[0]
    close = difflib.get_close_matches(first, sorted(names), n=1)
    if not close:
        return ""
    return f" (did you mean {'.'.join([close[0], *key.split('.')[1:]])!r}?)"


def _sets(overrides: dict, err: ValidationError) -> bool:
    """Whether the overrides of a variant set the first key ``err`` is about (else [base] does)."""
    errors = err.errors()
    if not errors:
        return True
    loc = errors[0]["loc"]
    if loc:
        return str(loc[0]) in overrides
    # a check of the whole trial (a plugin's settings): "KIND_config: ..."; the plugin or its settings
    key = errors[0]["msg"].removeprefix("Value error, ").split(":")[0]
    return key in overrides or key.removesuffix("_config") in overrides or not key.endswith("_config")


def _check_k(study: Study, settings: TrialSettings, where: str, loc: str) -> None:
    if isinstance(study.data, SyntheticProposalsData) and settings.k > study.data.k:
        raise HybridfitError(f"{where}: {loc}.k: {settings.k} exceeds data.k = {study.data.k} (proposals generated)")


def trials(study: Study, variants: list[Variant], data_key: str) -> list[Trial]:
    """Every variant x seed, variant-major, with its unique key."""
    return [Trial(digest({"data": data_key, "settings": v.settings.as_dict(), "seed": s}), v, s)
            for v in variants for s in study.seed_list()]
