"""What a start does after a crash (SIGKILL, power loss) so that nothing recorded is lost.

Only the data folder's owner runs it: ``create_app`` takes the folder's lock first
(:mod:`wandcal.service.datafolder.lock`), so a second server started on a folder in use refuses
before it gets here. Each action is logged with the id it concerns (INFO for what is only
deleted, WARNING for what is registered, moved or cut).

| left behind | what the start does |
|---|---|
| ``captures/.<id>.partial`` of an upload (points level only) | deleted: the upload was never answered 201, the client sends it again |
| ``captures/.<id>.partial`` of a live recording (``sync.csv``, ``frames/``, ``capture.json``) | its rows cut mid-line by the kill are dropped; registered as capture ``<id>`` when its points level reads, else moved to ``recovered/<id>`` (an image-level capture folder for ``wandcal detect``) |
| a capture folder without a database row (killed between the two) | registered |
| wand.csv rows of a streamed frame set killed before its commit | cut: the unanswered client sends the set again |
| spooled upload bodies in ``tmp/`` | deleted |
| ``reports/.<job id>.<random>.partial`` of a report being drawn | deleted: the next request draws it again |
| a corrupt database | moved aside by :func:`wandcal.service.db.init_db`; every capture folder is registered again |
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

from wandcal.capture.csv_tables import csv_records
from wandcal.capture.folder import read_capture
from wandcal.drivers.capture_files import (
    BLOBS_FILE,
    FRAMES_DIR,
    LOG_FILE,
    STATIC_DIR,
    STATIC_FILE,
    SYNC_FILE,
    WAND_FILE,
)
from wandcal.service.db import connect
from wandcal.service.report.store import REPORTS_DIR
from wandcal.service.storage import CAPTURE_ID, WAND_PAIR, CaptureStore

log = logging.getLogger("wandcal.service")

RECOVERED_DIR = "recovered"
SPOOL_DIR = "tmp"  # where ``wandcal serve`` spools large uploads (service/cli/serve.py)
RECORDING_MARKS = (SYNC_FILE, LOG_FILE, FRAMES_DIR, STATIC_DIR, BLOBS_FILE)  # written by a recording only
RECOVERED_SOURCE = "live (recovered after a crash)"


def recover(store: CaptureStore, data_dir: Path) -> list[str]:
    """Clean up after a crash (module docstring); returns one line per thing done, also logged."""
    store.root.mkdir(parents=True, exist_ok=True)
    done = []
    for staging in sorted(store.root.glob(".*.partial")):
        capture_id = staging.name[1 : -len(".partial")]
        if not any((staging / mark).exists() for mark in RECORDING_MARKS) or not CAPTURE_ID.match(capture_id):
            shutil.rmtree(staging, ignore_errors=True)
            log.info("deleted %s, an upload a crash cut short (it was never answered 201)", staging.name)
            continue
        done.append(_recover_recording(store, staging, capture_id))
    done += register_orphans(store)
    done += trim_uncommitted_rows(store)
    spool = Path(data_dir) / SPOOL_DIR
    if spool.is_dir():
        for leftover in spool.iterdir():
            if leftover.is_file():
                leftover.unlink(missing_ok=True)
                log.info("deleted %s/%s, an upload body spooled before a crash", SPOOL_DIR, leftover.name)
    # a report whose drawing a crash cut short: the next request draws it again (service/report/store.py)
    for half in (Path(data_dir) / REPORTS_DIR).glob(".*.partial"):
        shutil.rmtree(half, ignore_errors=True)
        log.info("deleted %s/%s, a report a crash cut short (the next request draws it again)", REPORTS_DIR, half.name)
    for line in done:
        log.warning("%s", line)
    return done


def _recover_recording(store: CaptureStore, staging: Path, capture_id: str) -> str:
    for name in (WAND_FILE, STATIC_FILE):
        drop_cut_last_line(staging / name)
    try:
        capture = read_capture(staging)
        store.adopt(staging, capture_id, capture, RECOVERED_SOURCE, f"recovered recording {capture_id[:8]}",
                    created=staging.stat().st_mtime)
        return (f"a live recording cut short by a crash is capture {capture_id} ({len(capture.wand)} wand rows); "
                "its images are beside it")
    except (ValueError, OSError) as exc:  # CaptureFormatError: no readable points level yet
        target = _move_to_recovered(store, staging, capture_id)
        return (f"a live recording cut short by a crash is kept in {target} ({exc}); run 'wandcal detect {target}' "
                "and upload its rig.json, wand.csv and static.csv, or copy it under the replay root")


def keep_failed_recording(store: CaptureStore, staging: Path, capture_id: str) -> Path | None:
    """A live recording that failed before it became a capture (its points level does not read,
    the disk filled, a device failed mid-set): its recorded sets are moved to ``recovered/<id>``,
    as a crash's are, and that folder is returned; a staging folder with no recorded set is
    deleted (None)."""
    sync = staging / SYNC_FILE
    try:
        recorded = sync.is_file() and len(csv_records(sync.read_bytes())) > 1  # a row below the header
    except OSError:
        recorded = False
    if not recorded:
        shutil.rmtree(staging, ignore_errors=True)
        return None
    target = _move_to_recovered(store, staging, capture_id)
    log.warning("a failed live recording is kept in %s", target)
    return target


def _move_to_recovered(store: CaptureStore, staging: Path, capture_id: str) -> Path:
    """Move a recording's staging folder to ``recovered/<id>`` beside the captures; its new path."""
    target = store.root.parent / RECOVERED_DIR / capture_id
    target.parent.mkdir(parents=True, exist_ok=True)
    staging.rename(target)
    return target


def trim_uncommitted_rows(store: CaptureStore) -> list[str]:
    """A kill between a streamed frame set's wand.csv append and its COMMIT leaves rows that no
    frame-set row owns, at the file's end (a capture's appends are serialised); its client, never
    answered, sends the set again. They are cut, so the retry does not double them: a stream
    capture's file holds its header and two rows per committed camera pair."""
    with connect(store.db_path) as conn:
        rows = conn.execute("SELECT id, counts FROM captures WHERE source = 'stream'").fetchall()
    done = []
    for capture_id, counts in rows:
        path = store.folder(capture_id) / WAND_FILE
        committed = 1 + WAND_PAIR * sum(c["pairs"] for c in json.loads(counts).values())
        try:
            data = path.read_bytes()
        except OSError:
            continue  # a missing file is register_orphans's and read_capture's to report
        lines = csv_records(data)  # as the writers count them: whole records, a crash's cut tail apart
        keep = sum(map(len, lines[:committed]))
        if len(data) > keep:
            os.truncate(path, keep)
            done.append(f"capture {capture_id}: cut {max(len(lines) - committed, 0)} wand.csv rows (and any row a "
                        "crash cut mid-line) of a frame set whose commit a crash interrupted (its client was not "
                        "answered and sends it again)")
    return done


def register_orphans(store: CaptureStore) -> list[str]:
    """Register capture folders that have no database row (a crash between the folder's rename
    and its row, or a database rebuilt after corruption)."""
    with connect(store.db_path) as conn:
        known = {r[0] for r in conn.execute("SELECT id FROM captures").fetchall()}
    done = []
    for capture_id in store.captured_ids():
        if capture_id in known:
            continue
        folder = store.folder(capture_id)
        staging = store.root / f".{capture_id}.partial"
        try:
            capture = read_capture(folder)
        except (ValueError, OSError) as exc:
            done.append(f"capture folder {folder} has no database row and cannot be read ({exc}); left as it is")
            continue
        folder.rename(staging)
        store.adopt(staging, capture_id, capture, "recovered", f"recovered {capture_id[:8]}",
                    created=staging.stat().st_mtime)
        done.append(f"capture folder {folder} had no database row; registered it again")
    return done


def drop_cut_last_line(path: Path) -> None:
    """Drop the last line of ``path`` if a crash cut it (no newline at its end)."""
    if not path.is_file() or path.stat().st_size == 0:
        return
    with open(path, "rb+") as fh:
        fh.seek(-1, os.SEEK_END)
        if fh.read(1) == b"\n":
            return
        data = path.read_bytes()
        fh.truncate(data.rfind(b"\n") + 1)
