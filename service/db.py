"""The service's SQLite database: one file under the data directory, opened per use.

WAL mode lets the API read while a worker process writes progress; ``BEGIN IMMEDIATE`` makes a
job claim atomic across processes.
"""

from __future__ import annotations

import errno
import logging
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger("wandcal.service")

BUSY_TIMEOUT_S = 30.0  # a writer holds the lock for milliseconds; 30 s only trips on a wedged disk

SCHEMA = """
CREATE TABLE IF NOT EXISTS captures (
    id TEXT PRIMARY KEY,
    created REAL NOT NULL,
    source TEXT NOT NULL,
    name TEXT NOT NULL,
    cameras TEXT NOT NULL,          -- JSON list of camera ids, rig order
    counts TEXT NOT NULL,           -- JSON {camera id: {"blobs": n, "pairs": n}}
    frames INTEGER NOT NULL,        -- distinct frame indices with wand blobs
    framesets INTEGER NOT NULL DEFAULT 0,
    has_static INTEGER NOT NULL DEFAULT 0,
    static_solution TEXT            -- JSON, last POST /captures/{id}/static
);
CREATE TABLE IF NOT EXISTS framesets (
    capture_id TEXT NOT NULL REFERENCES captures(id),
    frame INTEGER NOT NULL,
    trigger_count INTEGER,
    received REAL NOT NULL,
    blobs TEXT NOT NULL,            -- JSON {camera id: blobs detected}
    PRIMARY KEY (capture_id, frame)
);
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY,
    capture_id TEXT NOT NULL REFERENCES captures(id),
    method TEXT NOT NULL,
    options TEXT NOT NULL,
    state TEXT NOT NULL,
    attempts INTEGER NOT NULL DEFAULT 0,
    created REAL NOT NULL,
    started REAL,
    finished REAL,
    progress TEXT,
    result TEXT,
    error TEXT,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    run_token TEXT,                 -- the claim that may write this job's outcome
    worker_pid INTEGER,
    solve_seconds REAL
);
CREATE INDEX IF NOT EXISTS jobs_state ON jobs(state, created);
"""


def init_db(path: Path) -> Path | None:
    """Create the database file and its tables if missing (idempotent).

    A database that SQLite finds corrupt (not a database, or failing ``PRAGMA quick_check``) is
    moved aside, never deleted, and a new one is made: returns the moved file's path (the caller
    re-registers the captures from their folders), else None.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    moved = None
    try:
        _check(path)
    except sqlite3.DatabaseError as exc:
        if isinstance(exc, sqlite3.OperationalError) and not _corrupt_error(exc):
            raise  # locked, or the disk: not the file's fault, so it stays where it is
        moved = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%d-%H%M%S')}")
        for suffix in ("", "-wal", "-shm"):
            side = path.with_name(path.name + suffix)
            if side.exists():
                side.rename(moved.with_name(moved.name + suffix))
        log.warning("%s is corrupt (%s); moved it to %s and started a new database: the captures are "
                    "re-registered from their folders, the job records stay in the moved file "
                    "(sqlite3 %s .recover)", path, exc, moved, moved)
    with connect(path) as conn:
        conn.execute("PRAGMA journal_mode=WAL")
        conn.executescript(SCHEMA)
    return moved


def _check(path: Path) -> None:
    """Raise sqlite3.DatabaseError if the database at ``path`` is damaged."""
    if not path.exists():
        return
    with connect(path) as conn:
        rows = [r[0] for r in conn.execute("PRAGMA quick_check").fetchall()]
    if rows != ["ok"]:
        raise sqlite3.DatabaseError(f"quick_check: {'; '.join(map(str, rows[:3]))}")


def _corrupt_error(exc: sqlite3.OperationalError) -> bool:
    return getattr(exc, "sqlite_errorcode", None) in (sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB)


def disk_full(exc: BaseException) -> bool:
    """True for the errors of a full disk (or quota): OSError ENOSPC/EDQUOT, SQLite's SQLITE_FULL."""
    if isinstance(exc, sqlite3.OperationalError):
        return getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL or "disk is full" in str(exc)
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


@contextmanager
def connect(path: Path) -> Iterator[sqlite3.Connection]:
    """A connection in autocommit mode; use :func:`transaction` for multi-statement writes."""
    conn = sqlite3.connect(path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
    conn.row_factory = sqlite3.Row
    conn.execute("PRAGMA foreign_keys=ON")
    try:
        yield conn
    finally:
        conn.close()


@contextmanager
def transaction(path: Path) -> Iterator[sqlite3.Connection]:
    """An immediate (write-locked) transaction: committed on success, rolled back on error."""
    with connect(path) as conn:
        conn.execute("BEGIN IMMEDIATE")
        try:
            yield conn
        except BaseException:
            conn.execute("ROLLBACK")
            raise
        conn.execute("COMMIT")
