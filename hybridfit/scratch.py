"""Scratch folders that only their maker cleans up.

A writer that builds something beside its destination (a data set, a cache entry) builds
it in a scratch folder ``.LABEL.hybridfit-scratch-TOKEN`` made by :func:`make`: ``TOKEN``
is 32 random hex digits, and the folder's manifest ``.hybridfit-scratch.json`` records the
token and the process that made it (host, boot, PID namespace, PID and start time). A run
that is killed leaves its scratch folder; :func:`sweep` removes exactly those whose manifest
holds the token of their name and whose process is certainly gone. Nothing is ever removed
because its name looks like a temporary one: a user's ``.a.old-2024`` or ``.x.partial-12``
is never touched, and neither is a scratch folder of a live process, of another machine or
container, or one whose manifest is missing or altered.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import socket
from pathlib import Path

__all__ = ["MANIFEST", "gone", "identity", "make", "release", "sweep"]

#: the manifest inside every scratch folder
MANIFEST = ".hybridfit-scratch.json"
_NAME = re.compile(r"^\.(?P<label>.*)\.hybridfit-scratch-(?P<token>[0-9a-f]{32})$", re.DOTALL)


def _read(path: str) -> str:
    try:
        with open(path) as fh:
            return fh.read().strip()
    except OSError:
        return ""


def _start(pid: int) -> str:
    """When process ``pid`` started (clock ticks since boot, Linux), or '' (unknown or gone)."""
    try:
        return _read(f"/proc/{pid}/stat").rsplit(")", 1)[1].split()[19]
    except IndexError:
        return ""


def _pid_namespace() -> str:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return ""


def identity(pid: int | None = None) -> dict[str, str | int]:
    """Who process ``pid`` (default: this one) is: host, boot, PID namespace, PID, start time."""
    pid = os.getpid() if pid is None else pid
    return {"host": socket.gethostname(), "boot": _read("/proc/sys/kernel/random/boot_id"),
            "pidns": _pid_namespace(), "pid": pid, "start": _start(pid)}


def gone(who: dict) -> bool:
    """Whether the process recorded as ``who`` (an :func:`identity`) has certainly ended: it
    ran on this host, in this PID namespace, and this machine has booted since, or its PID is
    free or reused (another start time). Anything that cannot be checked counts as alive."""
    me = identity()
    if who.get("host") != me["host"] or (who.get("pidns") or "") != me["pidns"]:
        return False
    if who.get("boot") and me["boot"] and who["boot"] != me["boot"]:
        return True
    pid = who.get("pid")
    if not isinstance(pid, int) or pid <= 0 or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except (PermissionError, OverflowError):
        pass
    start = _start(pid)
    return bool(who.get("start") and start and start != who["start"])


def make(parent: str | os.PathLike, label: str) -> Path:
    """A new, private (mode 0700) scratch folder in ``parent``, with its manifest; ``label``
    (the destination's name, say) only makes it recognisable."""
    parent = Path(parent)
    token = secrets.token_hex(16)
    path = parent / f".{label[:80]}.hybridfit-scratch-{token}"
    os.mkdir(path, 0o700)  # exclusive: a random new name, never an existing folder or link
    with open(path / MANIFEST, "x") as fh:
        json.dump({"token": token, **identity()}, fh)
    return path


def release(path: str | os.PathLike) -> None:
    """Drop the manifest of scratch folder ``path`` before it is renamed into place (what
    is renamed is then the built thing alone)."""
    Path(path, MANIFEST).unlink(missing_ok=True)


def sweep(parent: str | os.PathLike) -> int:
    """Remove the scratch folders in ``parent`` left by processes that are gone (see the
    module docstring); returns how many."""
    parent = Path(parent)
    try:
        entries = list(parent.iterdir())
    except OSError:
        return 0
    removed = 0
    for entry in entries:
        m = _NAME.match(entry.name)
        if m is None or entry.is_symlink() or not entry.is_dir():
            continue
        try:
            with open(entry / MANIFEST) as fh:
                who = json.load(fh)
        except (OSError, ValueError):
            continue
        if isinstance(who, dict) and who.get("token") == m["token"] and gone(who):
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed
