"""The service's SQLite database: one file under the data directory, opened per use.

WAL mode lets the API read while a worker process writes progress; ``BEGIN IMMEDIATE`` makes a
job claim atomic across processes.
"""

from __future__ import annotations

import errno
import logging
import os
import sqlite3
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from wandcal.calib.errors import CalibrationError

log = logging.getLogger("wandcal.service")
# the folders a server keeps in its data directory (captures, reports, spooled uploads, recordings
# kept after a failure); each must be a folder, or absent and then made
DATA_FOLDERS = ("captures", "reports", "tmp", "recovered")


class DataDirectoryError(CalibrationError):
    """A data directory the server cannot start on (a file where a folder belongs, a database
    path that is a folder, no permission); the message names the path and what to do."""


def check_data_dir(data_dir: Path, db_path: Path) -> None:
    """Refuse, naming the path, a data directory whose layout a start would trip over."""
    if data_dir.exists() and not data_dir.is_dir():
        raise DataDirectoryError(f"{data_dir}: the data directory is not a folder; give a folder (WANDCAL_DATA_DIR "
                                 "or --data-dir), or move this file away")
    for path in (db_path, *(data_dir / name for name in DATA_FOLDERS)):
        if path.is_symlink() and not path.exists():
            raise DataDirectoryError(f"{path}: a link to nothing ({os.readlink(path)}); remove the link and start again")
    for name in DATA_FOLDERS:
        folder = data_dir / name
        if folder.exists() and not folder.is_dir():
            raise DataDirectoryError(f"{folder}: must be a folder of the data directory, but is a file; move it away "
                                     "and start again")
    if db_path.exists() and not db_path.is_file():
        raise DataDirectoryError(f"{db_path}: the database path is a {'folder' if db_path.is_dir() else 'special file'}"
                                 ", not a file; move it away (the captures are registered again from their "
                                 "folders) and start again")

BUSY_TIMEOUT_S = 30.0  # a writer holds the lock for milliseconds; 30 s only trips on a wedged disk

# The tables of the first release: migration 1 below. A database made before versioning has these
# tables (they are unchanged since) and schema version 0; CREATE ... IF NOT EXISTS leaves them as they are.
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


@dataclass(frozen=True)
class Migration:
    """One step of the database's schema: ``sql`` takes a database at ``version - 1`` to ``version``."""

    version: int
    what: str
    sql: str


# Applied in order at start, each in its own transaction with its PRAGMA user_version. Append a step
# for every change of the tables; never edit one that has shipped (a released database has run it).
MIGRATIONS = (
    Migration(1, "the captures, framesets and jobs tables of the first release", SCHEMA),
)
SCHEMA_VERSION = MIGRATIONS[-1].version


class NewerDatabaseError(DataDirectoryError):
    """A database whose schema version is past :data:`SCHEMA_VERSION`: a newer wandcal wrote it."""


def init_db(path: Path) -> Path | None:
    """Create the database file and its tables if missing (idempotent).

    A database that SQLite finds corrupt (not a database, or failing ``PRAGMA quick_check``) is
    moved aside, never deleted, and a new one is made: returns the moved file's path (the caller
    re-registers the captures from their folders), else None.
    """
    check_data_dir(path.parent, path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataDirectoryError(f"{path.parent}: the data directory cannot be made ({exc.strerror or exc}); give "
                                 "a folder the server may write to") from None
    moved = None
    try:
        _check(path)
    except sqlite3.DatabaseError as exc:
        if isinstance(exc, sqlite3.OperationalError) and not _corrupt_error(exc):
            if getattr(exc, "sqlite_errorcode", None) in (sqlite3.SQLITE_CANTOPEN, sqlite3.SQLITE_PERM,
                                                          sqlite3.SQLITE_READONLY, sqlite3.SQLITE_IOERR):
                raise DataDirectoryError(f"{path}: the database cannot be opened ({exc}); check that the server may "
                                         "read and write it and its folder") from None
            raise  # locked, or the disk: not the file's fault, so it stays where it is
        moved = path.with_name(f"{path.name}.corrupt-{time.strftime('%Y%m%d-%H%M%S')}")
        for suffix in ("", "-wal", "-shm"):
            side = path.with_name(path.name + suffix)
            if side.exists():
                side.rename(moved.with_name(moved.name + suffix))
        log.warning("%s is corrupt (%s); moved it to %s and started a new database: the captures are "
                    "re-registered from their folders, the job records stay in the moved file "
                    "(sqlite3 %s .recover)", path, exc, moved, moved)
    try:
        with connect(path) as conn:
            refuse_newer(conn, path)  # before anything is written: a newer release's database stays as it was
            conn.execute("PRAGMA journal_mode=WAL")
            migrate(conn, path)
    except sqlite3.OperationalError as exc:
        if getattr(exc, "sqlite_errorcode", None) in (sqlite3.SQLITE_BUSY, sqlite3.SQLITE_LOCKED):
            raise
        raise DataDirectoryError(f"{path}: the database cannot be written ({exc}); check that the server may write "
                                 "it and its folder") from None
    return moved


def schema_version(conn: sqlite3.Connection) -> int:
    """The database's schema version (``PRAGMA user_version``; 0 before versioning or when new)."""
    return int(conn.execute("PRAGMA user_version").fetchone()[0])


def refuse_newer(conn: sqlite3.Connection, path: Path) -> int:
    """The database's schema version; :class:`NewerDatabaseError` naming it when past this release's."""
    found = schema_version(conn)
    if found > SCHEMA_VERSION:
        raise NewerDatabaseError(f"{path}: written by a newer wandcal: database schema version {found}; upgrade "
                                 f"wandcal (this release reads schema versions up to {SCHEMA_VERSION}), or give "
                                 "another data directory")
    return found


def migrate(conn: sqlite3.Connection, path: Path) -> list[Migration]:
    """Bring the database to :data:`SCHEMA_VERSION`, applying the missing :data:`MIGRATIONS` in order;
    returns those applied. A database from a newer wandcal is refused, naming its version, and left
    as it is (:class:`NewerDatabaseError`)."""
    found = refuse_newer(conn, path)
    applied = []
    existed = conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0] > 0
    for step in MIGRATIONS[found:]:
        # executescript commits what is open first, so the script carries its own transaction; a
        # failed step rolls back when the connection closes and the database stays at the last step
        conn.executescript(f"BEGIN IMMEDIATE;\n{step.sql}\nPRAGMA user_version = {step.version};\nCOMMIT;")
        applied.append(step)
        if existed:  # a new database is not news; an upgrade of a user's database is
            log.info("%s: database schema migrated to version %d (%s)", path, step.version, step.what)
    return applied


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
