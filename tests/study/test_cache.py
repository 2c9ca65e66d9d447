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
