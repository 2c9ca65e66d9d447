"""A content-addressed cache of expensive shared steps (data, forests, proposals, calibrations).

An entry is ``ROOT/KIND/KEY[SUFFIX]``, KEY a hash of everything that determines it, the
versions of hybridfit and of every plugin distribution and a hash of their Python sources
included (``code_versions``), so an upgrade, or an edit of an installed checkout,
recomputes instead of reusing what other code made. It is built in a private temporary
folder made exclusively (``tempfile.mkdtemp``: a random name holding the builder's PID,
``.tmp-PID-...``, mode 0700) beside it and renamed into place, so no link planted in the
cache is followed and a killed run leaves no half-written entry, and the temporary files and folders of runs
that are gone are removed when a cache is opened; two runs building the same entry at once
both succeed (the second rename finds it in place and discards its own copy).
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import re
import shutil
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any, Callable

from ..io import atomic_open, process_alive  # noqa: F401  (the study lock uses process_alive too)
from .expand import digest


class Cache:
    """Cache entries under ``root``; ``made`` lists the (kind, key) built by this object."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.made: list[tuple[str, str]] = []
        self.removed = remove_stale(self.root)

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
        scratch = Path(tempfile.mkdtemp(prefix=f".tmp-{os.getpid()}-", dir=path.parent))
        tmp = scratch / path.name
        try:
            make(tmp)
            _write_json(path.parent / f"{key}.payload.json", payload)
            try:
                if not path.exists():
                    os.replace(tmp, path)
            except OSError:  # a folder built meanwhile by another run: keep theirs
                if not path.exists():
                    raise
        finally:
            _remove(scratch)
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


_TEMPORARY = re.compile(r"^\.?\.tmp-(\d+)-|\.(?:partial|old)-(\d+)(?:-|$)|^\.hybridfit-(\d+)-")


def remove_stale(root: Path) -> int:
    """Remove temporary entries (``.tmp-PID-*``, ``*.partial-PID[-*]``, ``.hybridfit-PID-*``)
    under ``root/KIND/`` whose process is gone (a killed run); returns how many."""
    removed = 0
    for entry in root.glob("*/.*") if root.is_dir() else []:
        m = _TEMPORARY.search(entry.name)
        if m and not process_alive(int(next(g for g in m.groups() if g))):
            _remove(entry)
            removed += 1
    return removed


def _write_json(path: Path, payload: Any) -> None:
    with atomic_open(path, "w") as fh:
        fh.write(json.dumps(payload, indent=1, sort_keys=True, default=str))


def _remove(path: Path) -> None:
    """Remove a file or a folder (a link itself, never what it points to)."""
    shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink(missing_ok=True)
