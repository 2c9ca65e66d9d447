"""A content-addressed cache of expensive shared steps (data, forests, proposals, calibrations).

An entry is ``ROOT/KIND/KEY[SUFFIX]``, KEY a hash of everything that determines it. It is
built under a temporary name in the same folder and renamed into place, so a killed run
leaves no half-written entry; two runs building the same entry at once both succeed
(the second rename finds it in place and discards its own copy).
"""

from __future__ import annotations

import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any, Callable

from .spec import digest


class Cache:
    """Cache entries under ``root``; ``made`` lists the (kind, key) built by this object."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.made: list[tuple[str, str]] = []

    def path(self, kind: str, payload: Any, suffix: str = "") -> tuple[str, Path]:
        """(key, path) of the entry for ``payload``."""
        key = digest(payload)
        return key, self.root / kind / f"{key}{suffix}"

    def get(self, kind: str, payload: Any, make: Callable[[Path], None], suffix: str = "") -> tuple[str, Path]:
        """(key, path) of the entry, calling ``make(tmp_path)`` to build it when missing."""
        key, path = self.path(kind, payload, suffix)
        if path.exists():
            return key, path
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".tmp-{uuid.uuid4().hex[:8]}-{path.name}")
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
            if tmp.exists():
                _remove(tmp)
        self.made.append((kind, key))
        return key, path


def _write_json(path: Path, payload: Any) -> None:
    tmp = path.with_name(f".tmp-{uuid.uuid4().hex[:8]}-{path.name}")
    tmp.write_text(json.dumps(payload, indent=1, sort_keys=True, default=str))
    os.replace(tmp, path)


def _remove(path: Path) -> None:
    shutil.rmtree(path) if path.is_dir() else path.unlink(missing_ok=True)
