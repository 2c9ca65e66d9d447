"""The study database: SQLite in WAL mode with a versioned schema (Optuna-like).

``trials``: one row per trial (unique ``key`` = hash of data, settings and seed), its
variant, settings JSON, seed (0 to 2**64 - 1; those from 2**63 stored below 0, as SQLite's
integers are signed, and read back as given) and state (running, complete, failed) with the
error of a failed trial. ``frames``: one row per trial and frame (errors per joint as a JSON list,
mean and worst joint error, objective, evaluations, time, the frame's own error).
Only the study's main process writes; each finished trial is one transaction, so a run
killed at any moment keeps every finished trial and never a half-written one.

An existing database is inspected read-only before anything is written to it
(:func:`check_database`): one that is not a study database, one from before schema
versioning (no ``schema_version``, or tables lacking the current columns), or of another
version is refused with one line naming it, and left as it was. The database is never
opened through a symbolic link.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
import urllib.parse
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HybridfitError
from ..io import WriteError

#: the file name of a study's store inside its output folder
DB_NAME = "study.db"

SCHEMA_VERSION = 1
STATES = ("running", "complete", "failed")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS trials (
    id INTEGER PRIMARY KEY,
    key TEXT NOT NULL UNIQUE,
    variant TEXT NOT NULL,
    variant_index INTEGER NOT NULL,
    method TEXT NOT NULL,
    settings TEXT NOT NULL,
    seed INTEGER NOT NULL,
    joint_names TEXT,
    state TEXT NOT NULL CHECK (state IN ('running', 'complete', 'failed')),
    error TEXT,
    started REAL,
    finished REAL
);
CREATE TABLE IF NOT EXISTS frames (
    trial_id INTEGER NOT NULL REFERENCES trials(id) ON DELETE CASCADE,
    frame INTEGER NOT NULL,
    joint_errors TEXT NOT NULL,
    mean_error REAL,
    max_error REAL,
    objective REAL,
    evaluations INTEGER,
    time_s REAL,
    failed INTEGER NOT NULL,
    error TEXT,
    PRIMARY KEY (trial_id, frame)
);
"""


#: what SQLite says when the disk, not the program, is at fault
_ENVIRONMENT = ("disk is full", "readonly", "read-only", "unable to open", "disk i/o error", "out of memory")


#: how long a study waits for a database another program holds locked, seconds
BUSY_TIMEOUT_S = 30.0


def storage_error(path: Path, err: sqlite3.Error) -> HybridfitError | None:
    """A one-line error naming the database for SQLite's errors that are not a bug: a full
    disk or read-only folder (a WriteError), a database another program holds locked, a file
    that is damaged or no database; None for others (a bug)."""
    msg = str(err)
    low = msg.lower()
    if "locked" in low or "busy" in low:
        return HybridfitError(f"{path}: the study database stayed locked by another program for {BUSY_TIMEOUT_S:g} s "
                              "(an open sqlite3 shell or database viewer, a run on another machine sharing the "
                              "folder?); close it and run again")
    if any(m in low for m in ("malformed", "not a database", "file is encrypted", "disk image")):
        return HybridfitError(f"{path}: not a readable study database ({msg}); it was left as it was: use another "
                              "--out folder")
    if not any(m in low for m in _ENVIRONMENT):
        return None
    return WriteError(28 if "full" in msg else 30, f"{path}: cannot write the study database: {msg}")


def _text(value) -> str:
    """``value`` as text SQLite can store (UTF-8): what UTF-8 cannot hold (a lone surrogate, from
    a file name that is not UTF-8, say) as ``\\udcff``-style escapes."""
    return str(value).encode("utf-8", "backslashreplace").decode("utf-8")


def _json(text, path: Path, what: str):
    """``json.loads(text)``, or a one-line HybridfitError naming the database and ``what``."""
    try:
        return json.loads(text)
    except (TypeError, ValueError, RecursionError) as err:
        raise HybridfitError(f"{path}: {what} is not JSON ({type(err).__name__}: {' '.join(str(err).split())}): a "
                             "damaged study database; run the study into a new --out folder") from None


def _columns(schema: str) -> dict[str, set[str]]:
    """{table: its columns} of a CREATE TABLE script such as ``_SCHEMA``."""
    db = sqlite3.connect(":memory:")
    try:
        db.executescript(schema)
        return {t: {row[1] for row in db.execute(f"PRAGMA table_info({t})")}
                for (t,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    finally:
        db.close()


#: the tables of the current schema and their columns
COLUMNS = _columns(_SCHEMA)
#: the files SQLite keeps beside a database
COMPANIONS = ("-wal", "-shm", "-journal")


def _refuse_links(path: Path) -> None:
    for p in (path, *(path.with_name(path.name + c) for c in COMPANIONS)):
        if p.is_symlink():
            raise HybridfitError(f"{p}: is a symbolic link; hybridfit never opens a study database through a link "
                                 "(it would write where the link points): remove it or use another --out folder")


def check_writable(folder: str | Path) -> None:
    """Refuse an existing study folder this process cannot write (read-only): a study writes
    its database and its report there, and SQLite cannot even read a WAL database from it."""
    folder = Path(folder)
    if folder.is_dir() and not os.access(folder, os.W_OK | os.X_OK):
        raise HybridfitError(f"{folder}: a read-only folder; a study writes its database and its report "
                             "(report.md, results.csv, the plots) there: copy the folder somewhere writable "
                             f"(cp -r {folder} NEW) and give that as --out")


def check_database(path: str | Path) -> int | None:
    """The schema version of the existing study database at ``path``, read without writing
    anything to it; None when it holds no tables yet (a new, empty file). A file that is not
    a study database, one from before schema versioning (no ``schema_version``, or tables
    without the current columns: older hybridfit stamped version 1 on such files) or of
    another version is a HybridfitError naming it (one line)."""
    path = Path(path)
    _refuse_links(path)
    uri = f"file:{urllib.parse.quote(str(path.absolute()))}?mode=ro"
    try:
        db = sqlite3.connect(uri, uri=True, timeout=5)
    except sqlite3.Error as err:
        raise HybridfitError(f"{path}: cannot open the study database ({err})") from None
    try:
        tables = {t: {row[1] for row in db.execute(f"PRAGMA table_info({t})")}
                  for (t,) in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()}
        raw = None
        if "meta" in tables and "key" in tables["meta"] and "value" in tables["meta"]:
            row = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
            raw = None if row is None else row[0]
    except sqlite3.DatabaseError as err:
        if "locked" in str(err) or "busy" in str(err):
            raise storage_error(path, err) from None
        raise HybridfitError(f"{path}: not a readable study database ({err})") from None
    finally:
        db.close()
    if not tables:
        return None
    if raw is None:
        if "trials" not in tables:
            raise HybridfitError(f"{path}: not a hybridfit study database (tables: {', '.join(sorted(tables))}); "
                                 "use another --out folder")
        raise HybridfitError(f"{path}: a study database from before schema versioning (no schema_version), which "
                             f"this hybridfit cannot read; it was left as it was: use another --out folder")
    try:
        version = int(json.loads(raw))
    except (ValueError, TypeError, OverflowError):
        raise HybridfitError(f"{path}: not a hybridfit study database (schema_version {raw!r}); "
                             "use another --out folder") from None
    if version != SCHEMA_VERSION:
        raise HybridfitError(f"{path}: study database schema version {version}, this hybridfit "
                             f"reads version {SCHEMA_VERSION}; use another --out folder")
    missing = [f"{t}.{c}" for t, cols in COLUMNS.items() for c in sorted(cols - tables.get(t, set()))]
    if missing:
        raise HybridfitError(f"{path}: a study database from before schema versioning (no column "
                             f"{', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}; an older hybridfit "
                             f"stamped version {version} on it), which this hybridfit cannot read; it was left as it "
                             "was: use another --out folder")
    return version


class Store:
    """The SQLite study database at ``path`` (created with the current schema if new; an
    existing one is checked by :func:`check_database` before anything is written to it).
    ``created``: whether this object created the file; ``written``: how many trial rows it wrote."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        check_writable(self.path.parent)
        existed = self.path.exists() or self.path.is_symlink()
        found = check_database(self.path) if existed else None
        _refuse_links(self.path)
        self.created, self.written = not existed, 0
        self.db = None
        try:
            self.db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
            self.db.execute("PRAGMA journal_mode=WAL")
            self.db.execute("PRAGMA synchronous=NORMAL")
            self.db.execute("PRAGMA foreign_keys=ON")
            if found is None:  # a new database
                for stmt in filter(str.strip, _SCHEMA.split(";")):
                    self.db.execute(stmt)
                self.set_meta("schema_version", SCHEMA_VERSION)
        except sqlite3.Error as err:
            if self.db is not None:
                self.db.close()
            failure = storage_error(self.path, err)
            if failure is None:
                raise
            raise failure from None

    def close(self) -> None:
        self.db.close()

    # ------------------------------------------------------------------ meta

    def get_meta(self, key: str, kind: type | tuple[type, ...] | None = None) -> Any:
        """The meta row ``key`` (None if missing); ``kind``: the type it must have (a damaged
        database is a one-line HybridfitError naming the row)."""
        row = self.db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        value = None if row is None else _json(row[0], self.path, f"the meta row {key!r}")
        if kind is not None and value is not None and not isinstance(value, kind):
            raise HybridfitError(f"{self.path}: the meta row {key!r} is a {type(value).__name__}, not what a study "
                                 "writes: a damaged study database; run the study into a new --out folder")
        return value

    def set_meta(self, key: str, value: Any) -> None:
        self.db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, json.dumps(value)))

    # ------------------------------------------------------------------ trials

    def states(self) -> dict[str, str]:
        """{trial key: state} of every trial in the database."""
        return dict(self.db.execute("SELECT key, state FROM trials"))

    def start(self, key: str, variant: str, variant_index: int, method: str, settings: dict, seed: int) -> None:
        """Record a trial as running (a re-run of an unfinished trial replaces its row's state)."""
        self.written += 1
        self.db.execute(
            "INSERT INTO trials (key, variant, variant_index, method, settings, seed, state, started) "
            "VALUES (?, ?, ?, ?, ?, ?, 'running', ?) ON CONFLICT(key) DO UPDATE SET state = 'running', "
            "error = NULL, started = excluded.started, finished = NULL, variant = excluded.variant, "
            "variant_index = excluded.variant_index",
            (key, _text(variant), variant_index, method, json.dumps(settings, sort_keys=True), _seed_in(seed),
             time.time()))

    def complete(self, key: str, result: dict) -> None:
        """Store a finished trial's frames and mark it complete, in one transaction.

        result: ``errors`` (F, J) mm, ``objective`` (F,), ``evaluations`` (F,), ``failed`` (F,),
        ``messages`` {frame: error}, ``time_per_frame`` s, ``joint_names`` (J,)."""
        errors = np.asarray(result["errors"], float)
        rows = []
        for f in range(len(errors)):
            e = errors[f]
            ok = np.isfinite(e).all()
            rows.append((f, json.dumps([None if not np.isfinite(x) else round(float(x), 4) for x in e]),
                         float(e.mean()) if ok else None, float(e.max()) if ok else None,
                         _num(result["objective"][f]), int(result["evaluations"][f]), _num(result["time_per_frame"]),
                         int(bool(result["failed"][f])), result["messages"].get(f)))
        with self.db:
            self.db.execute("BEGIN IMMEDIATE")
            (tid,) = self.db.execute("SELECT id FROM trials WHERE key = ?", (key,)).fetchone()
            self.db.execute("DELETE FROM frames WHERE trial_id = ?", (tid,))
            self.db.executemany("INSERT INTO frames VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", [(tid, *r) for r in rows])
            self.db.execute("UPDATE trials SET state = 'complete', error = NULL, finished = ?, joint_names = ? "
                            "WHERE id = ?", (time.time(), json.dumps(list(result["joint_names"])), tid))

    def fail(self, key: str, error: str) -> None:
        """Mark a trial failed with its error."""
        self.db.execute("UPDATE trials SET state = 'failed', error = ?, finished = ? WHERE key = ?",
                        (_text(error), time.time(), key))

    def mark_interrupted(self) -> int:
        """Trials left 'running' by a run that died: failed ("interrupted"); returns how many."""
        cur = self.db.execute("UPDATE trials SET state = 'failed', error = 'interrupted' WHERE state = 'running'")
        return cur.rowcount

    # ------------------------------------------------------------------ reading

    def trials(self, state: str | None = None) -> list[dict]:
        """Trial rows as dicts (settings and joint_names decoded), by variant and seed."""
        sql = ("SELECT * FROM trials" + (" WHERE state = ?" if state else "") +
               " ORDER BY variant_index, seed < 0, seed, id")  # seeds from 2**63 are stored below 0
        cur = self.db.execute(sql, (state,) if state else ())
        cols = [c[0] for c in cur.description]
        out = []
        for row in cur:
            d = dict(zip(cols, row))
            d["seed"] = _seed_out(d["seed"])
            d["settings"] = _json(d["settings"], self.path, f"the settings of trial {d.get('id')}")
            d["joint_names"] = (_json(d["joint_names"], self.path, f"the joint names of trial {d.get('id')}")
                                if d["joint_names"] else None)
            out.append(d)
        return out

    def frames(self, trial_id: int) -> dict[str, np.ndarray]:
        """A trial's frames as arrays: errors (F, J) mm (NaN where failed), objective, evaluations, time_s, failed."""
        rows = self.db.execute("SELECT joint_errors, objective, evaluations, time_s, failed FROM frames "
                               "WHERE trial_id = ? ORDER BY frame", (trial_id,)).fetchall()
        try:
            errors = np.array([[np.nan if x is None else x for x in _json(r[0], self.path, f"a frame of trial {trial_id}")]
                               for r in rows], float)
        except (TypeError, ValueError):
            raise HybridfitError(f"{self.path}: the joint errors of trial {trial_id} are not lists of numbers: a "
                                 "damaged study database; run the study into a new --out folder") from None
        return {"errors": errors.reshape(len(rows), -1),
                "objective": np.array([np.nan if r[1] is None else r[1] for r in rows], float),
                "evaluations": np.array([r[2] for r in rows], float),
                "time_s": np.array([r[3] for r in rows], float),
                "failed": np.array([bool(r[4]) for r in rows])}


def _seed_in(seed: int) -> int:
    """A seed (0 to 2**64 - 1) as SQLite's signed 64-bit INTEGER: seeds from 2**63 wrap below 0
    (two's complement), which no seed is, so :func:`_seed_out` reads every seed back as given."""
    seed = int(seed)
    return seed - 2**64 if seed >= 2**63 else seed


def _seed_out(stored: int) -> int:
    return stored + 2**64 if isinstance(stored, int) and stored < 0 else stored


def _num(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None
