"""The shared-step cache: built once, atomically."""

from __future__ import annotations

import pytest

from hybridfit.study.cache import Cache


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
    import os

    kind = tmp_path / "thing"
    kind.mkdir()
    victim = tmp_path / "victim"
    victim.write_text("precious")
    seen = []

    def make(tmp):
        seen.append(tmp)
        tmp.write_text("x")

    key, path = Cache(tmp_path).path("thing", {"a": 1}, ".txt")
    (kind / f"{key}.payload.json.tmp").symlink_to(victim)  # a link at a guessable temporary name
    assert Cache(tmp_path).get("thing", {"a": 1}, make, ".txt") == (key, path)
    scratch = seen[0].parent
    assert scratch.parent == kind and scratch.name.startswith(f".tmp-{os.getpid()}-") and not scratch.exists()
    assert victim.read_text() == "precious" and path.read_text() == "x"
    # a dead run's temporary link is removed itself, never what it points to
    dead = 2**22 + 12345
    (kind / f".tmp-{dead}-x").symlink_to(tmp_path)
    assert Cache(tmp_path).removed == 1 and victim.exists() and not (kind / f".tmp-{dead}-x").is_symlink()
