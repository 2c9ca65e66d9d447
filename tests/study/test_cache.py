"""The shared-step cache: built once, atomically."""

from __future__ import annotations

import json

import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study.cache import MARKER, Cache


def test_entry_is_built_once_and_found_by_a_new_cache(tmp_path):
    calls = []

    def make(tmp):
        calls.append(tmp)
        tmp.write_text("x")

    key, path = Cache(tmp_path).get("thing", {"a": 1}, make, ".txt")
    assert path.read_text() == "x" and len(calls) == 1
    again = Cache(tmp_path)
    assert again.get("thing", {"a": 1}, make, ".txt") == (key, path) and len(calls) == 1 and again.made == []
    assert Cache(tmp_path).get("thing", {"a": 2}, make, ".txt")[0] != key and len(calls) == 2


def test_a_failed_build_leaves_nothing(tmp_path):
    def make(tmp):
        (tmp).mkdir()
        (tmp / "half").write_text("half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        Cache(tmp_path).get("folder", {"a": 1}, make)
    assert list((tmp_path / "folder").iterdir()) == []


def test_an_entry_is_built_in_a_private_folder_and_no_link_is_followed(tmp_path):
    victim = tmp_path / "victim"
    tmp_path = tmp_path / "cache"
    Cache(tmp_path)
    kind = tmp_path / "thing"
    kind.mkdir()
    victim.write_text("precious")
    seen = []

    def make(tmp):
        seen.append(tmp)
        tmp.write_text("x")

    key, path = Cache(tmp_path).path("thing", {"a": 1}, ".txt")
    (kind / f"{key}.payload.json.tmp").symlink_to(victim)  # a link at a guessable temporary name
    assert Cache(tmp_path).get("thing", {"a": 1}, make, ".txt") == (key, path)
    folder = seen[0].parent
    assert folder.parent == kind and ".hybridfit-scratch-" in folder.name and not folder.exists()
    assert victim.read_text() == "precious" and path.read_text() == "x"
    assert json.loads((kind / f"{key}.payload.json").read_text()) == {"a": 1}


def test_a_killed_runs_scratch_is_removed_and_nothing_named_like_one(tmp_path):
    from tests.test_scratch import dead_pid, left_by

    Cache(tmp_path)
    kind = tmp_path / "train-data"
    kind.mkdir()
    dead = dead_pid()
    stale = left_by(dead, kind, "tmp")
    users = [kind / n for n in (".a.old-2024", f".tmp-{dead}-x", f"..tmp-{dead}-KEY.partial-{dead}")]
    for p in users:
        p.mkdir()
        (p / "k").write_text("x")
    cache = Cache(tmp_path)
    assert cache.removed == 1 and not stale.exists() and all((p / "k").exists() for p in users)


def test_a_users_folder_is_refused_as_a_cache_and_left_as_it_was(tmp_path):
    """The issue's repro: ``--cache c`` where c/s/.a.old-2024 is the user's."""
    hidden = tmp_path / "c" / "s" / ".a.old-2024"
    hidden.mkdir(parents=True)
    (hidden / "k").write_text("x")
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("mine")
    for root in (tmp_path / "c", tmp_path / "notes"):
        before = sorted(p.relative_to(root) for p in root.rglob("*"))
        with pytest.raises(HybridfitError, match=rf"{root}: not a hybridfit cache .* give a new or empty folder"):
            Cache(root)
        assert sorted(p.relative_to(root) for p in root.rglob("*")) == before
    assert (hidden / "k").read_text() == "x"
    with pytest.raises(HybridfitError, match="must be a folder"):
        Cache(tmp_path / "notes" / "todo.txt")


def test_an_earlier_versions_cache_is_adopted(tmp_path):
    kind = tmp_path / "proposals"
    kind.mkdir()
    (kind / ("ab" * 16 + ".npz")).write_bytes(b"x")
    (kind / ("ab" * 16 + ".payload.json")).write_text("{}")
    assert Cache(tmp_path).removed == 0 and (tmp_path / MARKER).is_file()
    Cache(tmp_path / "new" / "cache")  # a new folder, and an empty one, become caches
    (tmp_path / "empty").mkdir()
    Cache(tmp_path / "empty")
    assert (tmp_path / "empty" / MARKER).is_file()


def test_a_study_refuses_a_users_folder_as_its_cache(tmp_path, tiny_file):
    from hybridfit.cli import main

    hidden = tmp_path / "c" / "s" / ".a.old-2024"
    hidden.mkdir(parents=True)
    (hidden / "k").write_text("x")
    assert main(["study", str(tiny_file), "--quick", "--out", str(tmp_path / "o"), "--cache", str(tmp_path / "c")]) == 2
    assert (hidden / "k").read_text() == "x" and sorted(p.name for p in (tmp_path / "c").rglob("*")) == [".a.old-2024", "k", "s"]

