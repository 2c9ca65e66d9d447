"""The study database and the study folder: an old, foreign or linked database is refused
before anything is written to it; a folder that is not a study's is refused."""

from __future__ import annotations

import hashlib
import os
import sqlite3

import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study.runner import LOCK_NAME, check_folder
from hybridfit.study.store import SCHEMA_VERSION, Store, check_database

from .conftest import old_database


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("stamped", [False, True])
def test_an_old_database_is_refused_before_it_is_written(tmp_path, stamped):
    path = tmp_path / "study.db"
    old_database(path, stamped=stamped)
    before = sha(path)
    with pytest.raises(HybridfitError, match="before schema versioning") as err:
        Store(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
    assert sha(path) == before and sorted(os.listdir(tmp_path)) == ["study.db"]


def test_a_new_database_is_stamped_and_reopened(tmp_path):
    path = tmp_path / "study.db"
    Store(path).close()
    assert check_database(path) == SCHEMA_VERSION
    store = Store(path)
    assert store.get_meta("schema_version") == SCHEMA_VERSION
    store.close()


@pytest.mark.parametrize("content, match", [
    (b"garbage " * 200, "not a readable study database"),
    (None, "not a hybridfit study database"),  # a SQLite file of something else
], ids=["garbage", "foreign-sqlite"])
def test_a_foreign_file_is_refused_untouched(tmp_path, content, match):
    path = tmp_path / "study.db"
    if content is None:
        db = sqlite3.connect(path)
        db.execute("CREATE TABLE photos (name TEXT)")
        db.commit()
        db.close()
    else:
        path.write_bytes(content)
    before = sha(path)
    with pytest.raises(HybridfitError, match=match):
        Store(path)
    assert sha(path) == before and sorted(os.listdir(tmp_path)) == ["study.db"]


def test_a_database_is_never_opened_through_a_link(tmp_path):
    Store(tmp_path / "real.db").close()
    out = tmp_path / "out"
    out.mkdir()
    (out / "study.db").symlink_to(tmp_path / "real.db")
    with pytest.raises(HybridfitError, match="symbolic link"):
        Store(out / "study.db")
    victim = tmp_path / "victim"
    victim.write_text("precious")
    (out / "study.db").unlink()
    Store(out / "study.db").close()
    (out / "study.db-wal").symlink_to(victim)
    with pytest.raises(HybridfitError, match="study.db-wal: is a symbolic link"):
        Store(out / "study.db")
    assert victim.read_text() == "precious"


def test_which_folders_are_a_studys(tmp_path):
    check_folder(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    check_folder(tmp_path / "empty")
    started = tmp_path / "started"  # a run killed right after taking its lock
    started.mkdir()
    (started / LOCK_NAME).write_text("99999999 host\n")
    check_folder(started)
    study = tmp_path / "study"
    Store(study / "study.db").close()
    (study / "report.md").write_text("ours")
    check_folder(study)
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(HybridfitError, match=r"mine: not a study's folder \(it holds notes.txt"):
        check_folder(mine)
    sqlite3.connect(mine / "study.db").close()  # an empty database beside the user's files
    with pytest.raises(HybridfitError, match="not a study's folder"):
        check_folder(mine)
    (tmp_path / "file").write_text("x")
    with pytest.raises(HybridfitError, match="is a file"):
        check_folder(tmp_path / "file")
