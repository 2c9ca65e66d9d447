"""A content-addressed cache of expensive shared steps (data, forests, proposals, calibrations).

An entry is ``ROOT/KIND/KEY[SUFFIX]``, KEY a hash of everything that determines it, the
versions of hybridfit and of every plugin distribution and a hash of their Python sources
included (``code_versions``), so an upgrade, or an edit of an installed checkout,
recomputes instead of reusing what other code made. It is built in a private scratch
folder beside it (:mod:`hybridfit.scratch`: a random name, mode 0700, a manifest naming
the process) and renamed into place, so no link planted in the cache is followed and a
killed run leaves no half-written entry; the scratch folders of runs that are gone are
removed when a cache is opened, and nothing else ever is. Two runs building the same entry
at once both succeed (the second rename finds it in place and discards its own copy).

``ROOT`` holds the marker ``.hybridfit-cache.json``; a folder that holds anything else and
no marker (a user's folder given as ``--cache`` by mistake) is refused, never written to.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import re
import shutil
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

from .. import scratch
from ..errors import HybridfitError
from ..io import atomic_open, process_alive  # noqa: F401  (the study lock uses process_alive too)
from .expand import digest


class Cache:
    """Cache entries under ``root``; ``made`` lists the (kind, key) built by this object."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.made: list[tuple[str, str]] = []
        claim(self.root)
        self.removed = sum(scratch.sweep(kind) for kind in self.root.iterdir() if kind.is_dir() and not kind.is_symlink())

    def path(self, kind: str, payload: Any, suffix: str = "") -> tuple[str, Path]:
        """(key, path) of the entry for ``payload`` (made by this code: versions included)."""
        key = digest({"payload": payload, "code": code_versions()})
        return key, self.root / kind / f"{key}{suffix}"

    def get(self, kind: str, payload: Any, make: Callable[[Path], None], suffix: str = "") -> tuple[str, Path]:
        """(key, path) of the entry, calling ``make(tmp_path)`` to build it when missing."""
        key, path = self.path(kind, payload, suffix)
        if path.exists():
            return key, path
        path.parent.mkdir(parents=True, exist_ok=True)
        folder = scratch.make(path.parent, "tmp")
        tmp = folder / path.name
        try:
            make(tmp)
            record = folder / f"{key}.payload.json"
            record.write_text(json.dumps(payload, indent=1, sort_keys=True, default=str))
            os.replace(record, path.parent / record.name)
            try:
                if not path.exists():
                    os.replace(tmp, path)
            except OSError:  # a folder built meanwhile by another run: keep theirs
                if not path.exists():
                    raise
        finally:
            _remove(folder)
        self.made.append((kind, key))
        return key, path


@functools.cache
def code_versions() -> dict[str, str]:
    """{distribution: "VERSION+src.HASH"} of hybridfit and of every distribution providing a
    plugin; HASH covers the Python sources of the packages it provides plugins from (and
    ``hybridfit`` itself), so an edited editable install counts as other code."""
    from .. import registry

    packages: dict[str, set[str]] = {"hybridfit": {"hybridfit"}}
    for kind in ("model", "objective", "optimizer"):
        for ep in registry.entry_points(kind).values():  # read from the metadata: no plugin is imported
            dist = registry.distribution(ep)
            if dist != "?":
                packages.setdefault(dist, set()).add(ep.value.split(":")[0].split(".")[0].strip())
    out = {}
    for name in sorted(packages):
        try:
            version = metadata.version(name)
        except metadata.PackageNotFoundError:
            version = "?"
        out[name] = f"{version}+src.{source_hash(sorted(packages[name]))}"
    return out


def source_hash(packages: list[str]) -> str:
    """A short hash of the ``.py`` files (paths and contents) of importable packages."""
    h = hashlib.sha256()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None:
            continue
        roots = [Path(p) for p in (spec.submodule_search_locations or [])] or [Path(spec.origin or name)]
        for root in roots:
            files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
            for path in files:
                if path.is_file():
                    h.update(f"{name}/{path.relative_to(root) if root.is_dir() else path.name}".encode())
                    h.update(path.read_bytes())
    return h.hexdigest()[:12]


MARKER = ".hybridfit-cache.json"
_KEYED = re.compile(r"^[0-9a-f]{16,}")


def claim(root: Path) -> None:
    """Make ``root`` a cache (created, or an empty folder, gets the marker) or check it is
    one: it has the marker, or it is a cache of an earlier version (only KIND folders of
    keyed entries with their ``KEY.payload.json``). Anything else is a
    :class:`~hybridfit.errors.HybridfitError`, before anything is written there."""
    marker = root / MARKER
    if marker.is_file() and not marker.is_symlink():
        return
    if root.exists() and not root.is_dir():
        raise HybridfitError(f"{root}: the cache must be a folder, not a file")
    try:
        entries = list(root.iterdir()) if root.exists() else []
    except OSError as err:
        raise HybridfitError(f"{root}: cannot use as a cache: {err.strerror or err}") from None
    if entries and not all(_an_earlier_caches_kind(e) for e in entries):
        other = sorted(e.name for e in entries if not _an_earlier_caches_kind(e))
        raise HybridfitError(f"{root}: not a hybridfit cache (it holds {len(other)} entries that are not, e.g. "
                             f"{other[0]!r}, and no {MARKER}); give a new or empty folder as the cache")
    root.mkdir(parents=True, exist_ok=True)
    _write_json(marker, {"format": "hybridfit-cache", "version": 1})


def _an_earlier_caches_kind(entry: Path) -> bool:
    """Whether ``entry`` is a KIND folder as earlier versions wrote them (without a marker)."""
    if entry.is_symlink() or not entry.is_dir():
        return False
    names = [e.name for e in entry.iterdir()]
    visible = [n for n in names if not n.startswith(".")]
    return any(n.endswith(".payload.json") for n in visible) and all(_KEYED.match(n) for n in visible)


def _write_json(path: Path, payload: Any) -> None:
    with atomic_open(path, "w") as fh:
        fh.write(json.dumps(payload, indent=1, sort_keys=True, default=str))


def _remove(path: Path) -> None:
    """Remove a file or a folder (a link itself, never what it points to)."""
    shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink(missing_ok=True)
