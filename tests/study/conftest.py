"""Tiny study files shared by the study tests."""

from __future__ import annotations

import sqlite3

import pytest

TINY = """
name = "tiny"
seed = 7
seeds = 2

[data]
kind = "synthetic-proposals"
frames = 4
k = 3

[base]
budget = 400

[sweep.grid]
k = [1, 3]
"optimizer_config.schedule" = ["stepwise", "joint"]

[quick]
seeds = 1
data = { frames = 2 }
"""


@pytest.fixture
def tiny_file(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def write(tmp_path, text: str, name: str = "study.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def old_database(path, stamped: bool = False, meta: bool = True) -> None:
    """A study.db of hybridfit before schema versioning: trials without variant_index, no
    schema_version (``stamped``: as the old code left it, stamped version 1 all the same)."""
    db = sqlite3.connect(path)
    db.executescript(
        ("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);" if meta else "") +
        "CREATE TABLE trials (id INTEGER PRIMARY KEY, key TEXT NOT NULL UNIQUE, variant TEXT NOT NULL, "
        "method TEXT NOT NULL, settings TEXT NOT NULL, seed INTEGER NOT NULL, joint_names TEXT, state TEXT NOT NULL, "
        "error TEXT, started REAL, finished REAL);"
        "CREATE TABLE frames (trial_id INTEGER NOT NULL, frame INTEGER NOT NULL, joint_errors TEXT NOT NULL, "
        "mean_error REAL, max_error REAL, objective REAL, evaluations INTEGER, time_s REAL, failed INTEGER NOT NULL, "
        "error TEXT, PRIMARY KEY (trial_id, frame));"
        "INSERT INTO trials VALUES (1, 'abc', 'old variant', 'fit', '{}', 0, '[]', 'complete', NULL, 0, 1);"
        + ("INSERT INTO meta VALUES ('study', '{\"name\": \"old\"}');" if meta else "")
        + ("INSERT INTO meta VALUES ('schema_version', '1');" if stamped else ""))
    db.commit()
    db.close()
