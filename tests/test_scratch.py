"""Scratch folders: only a gone process's own, token-verified folders are ever removed."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from hybridfit import scratch


def dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def left_by(pid: int, parent, label="set", **changes):
    """A scratch folder as a run ``pid`` that was killed leaves it."""
    path = scratch.make(parent, label)
    manifest = path / scratch.MANIFEST
    who = {**json.loads(manifest.read_text()), "pid": pid, "start": "1", **changes}
    manifest.write_text(json.dumps(who))
    (path / "labels.npz").write_bytes(b"half")
    return path


def test_a_gone_processs_scratch_is_removed_and_a_live_ones_kept(tmp_path):
    stale = left_by(dead_pid(), tmp_path)
    mine = scratch.make(tmp_path, "set")
    assert scratch.sweep(tmp_path) == 1
    assert not stale.exists() and mine.exists()


def test_a_reused_pid_counts_as_gone(tmp_path):
    reused = left_by(os.getppid(), tmp_path, start="1")  # a live PID, another start time
    assert scratch.sweep(tmp_path) == 1 and not reused.exists()


def test_nothing_is_removed_for_its_name(tmp_path):
    """Names that look temporary (earlier versions' patterns, a date for a PID) are the user's."""
    dead = dead_pid()
    users = [tmp_path / n for n in (".a.old-2024", f".set.partial-{dead}", f".tmp-{dead}-x", f".hybridfit-{dead}-y",
                                     ".set.hybridfit-scratch-" + "0" * 32)]
    for p in users:
        p.mkdir()
        (p / "k").write_text("x")
    forged = left_by(dead, tmp_path)
    manifest = forged / scratch.MANIFEST
    manifest.write_text(json.dumps({**json.loads(manifest.read_text()), "token": "f" * 32}))  # not its name's token
    elsewhere = left_by(dead, tmp_path, host="another-host")
    assert scratch.sweep(tmp_path) == 0
    assert all((p / "k").read_text() == "x" for p in users) and forged.exists() and elsewhere.exists()


def test_a_link_named_like_scratch_is_never_followed(tmp_path):
    target = tmp_path / "precious"
    target.mkdir()
    (target / "k").write_text("x")
    (tmp_path / (".set.hybridfit-scratch-" + "a" * 32)).symlink_to(target)
    assert scratch.sweep(tmp_path) == 0 and (target / "k").read_text() == "x"


def test_a_released_scratch_holds_only_what_was_built(tmp_path):
    path = scratch.make(tmp_path, "set")
    (path / "meta.json").write_text("{}")
    scratch.release(path)
    assert sorted(p.name for p in path.iterdir()) == ["meta.json"] and oct(path.stat().st_mode & 0o777) == "0o700"
