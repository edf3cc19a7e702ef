"""Retention: old results and captures deleted only when the settings allow it (default: never).

Two settings, each off unless set (docs/reliability.md, "Retention"):

| setting | deletes, once older than that many days |
|---|---|
| ``keep_results_days`` | a finished job (``done``, ``failed``, ``cancelled``): its record, its result and its drawn report |
| ``keep_captures_days`` | a capture created that long ago whose jobs are all finished that long ago (or that has none), with those jobs, its frame-set rows and its folder |

Watch takes (issue 36, ``takes/`` in the data folder) go with what they belong to: a watch job's
take folder (``takes/<name>``, its ``options["folder"]``) with the job, a live watch's
(``takes/live-<capture id>``: the standing result it was started with) with its capture. A take
folder that nothing names (a live watch whose recording was never stored, an upload a crash cut
off before its job was queued) goes once it is older than the setting its kind follows.

A queued or running job, and its capture, are never deleted. The owner of the data folder prunes
at its start and every :data:`PRUNE_EVERY_S` after. The order makes a crash keep rather than
lose: the rows go first (one transaction), then the folder is renamed ``captures/.<id>.deleting``
(``takes/.<name>.deleting``) and removed; a folder a crash left at the rename is removed at the next prune, and one left before
it has no row and is registered again at the next start (recovery).
"""

from __future__ import annotations

import json
import logging
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from wandcal.service.db import transaction
from wandcal.service.jobs.records import JobState
from wandcal.service.jobs.watch_job import LIVE_TAKE_PREFIX, TAKES_DIR, WATCH_METHOD
from wandcal.service.report.store import report_folder

log = logging.getLogger("wandcal.service")
PRUNE_EVERY_S = 3600.0  # retention is counted in days: once an hour is prompt enough and costs nothing
DAY_S = 86400.0
DELETING = ".{}.deleting"
FINISHED = tuple(s.value for s in JobState if s.finished)


@dataclass(frozen=True)
class Retention:
    """How long to keep finished jobs and captures, days; None keeps them for ever."""

    results_days: float | None = None
    captures_days: float | None = None

    @property
    def prunes(self) -> bool:
        return self.results_days is not None or self.captures_days is not None


def prune(data_dir: Path, db_path: Path, retention: Retention, now: float | None = None) -> tuple[list[str], list[str]]:
    """Delete what ``retention`` allows (module docstring); returns (job ids, capture ids) deleted."""
    now = time.time() if now is None else now
    data_dir = Path(data_dir)
    jobs: list[str] = []
    captures: list[str] = []
    takes: list[str] = []  # take folders (names under takes/) that go with the jobs and captures
    marks = ",".join("?" * len(FINISHED))
    with transaction(db_path) as conn:
        if retention.captures_days is not None:
            cutoff = now - retention.captures_days * DAY_S
            captures = [r[0] for r in conn.execute(
                f"SELECT id FROM captures c WHERE created < ? AND NOT EXISTS (SELECT 1 FROM jobs j WHERE "
                f"j.capture_id = c.id AND (j.state NOT IN ({marks}) OR COALESCE(j.finished, j.created) >= ?))",
                (cutoff, *FINISHED, cutoff))]
            for capture_id in captures:
                rows = conn.execute("SELECT id, method, options FROM jobs WHERE capture_id = ?", (capture_id,)).fetchall()
                jobs += [r[0] for r in rows]
                takes += _take_folders(rows) + [LIVE_TAKE_PREFIX + capture_id]
                conn.execute("DELETE FROM jobs WHERE capture_id = ?", (capture_id,))
                conn.execute("DELETE FROM framesets WHERE capture_id = ?", (capture_id,))
                conn.execute("DELETE FROM captures WHERE id = ?", (capture_id,))
        if retention.results_days is not None:
            cutoff = now - retention.results_days * DAY_S
            rows = conn.execute(f"SELECT id, method, options FROM jobs WHERE state IN ({marks}) AND "
                                "COALESCE(finished, created) < ?", (*FINISHED, cutoff)).fetchall()
            conn.executemany("DELETE FROM jobs WHERE id = ?", [(r[0],) for r in rows])
            jobs += [r[0] for r in rows]
            takes += _take_folders(rows)
        takes += _unnamed_takes(conn, data_dir / TAKES_DIR, retention, now)
    for job_id in jobs:
        shutil.rmtree(report_folder(data_dir, job_id), ignore_errors=True)
    _remove_folders(data_dir / "captures", captures)
    _remove_folders(data_dir / TAKES_DIR, takes)
    if jobs or captures:
        log.info("retention: deleted %d finished job(s) and %d capture(s) (keep_results_days %s, "
                 "keep_captures_days %s): %s", len(jobs), len(captures), retention.results_days,
                 retention.captures_days, ", ".join(captures + jobs))
    return jobs, captures


def _take_folders(rows) -> list[str]:
    """The take folders' names (under takes/) of watch jobs among ``rows`` (id, method, options JSON)."""
    names = []
    for _, method, options in rows:
        folder = json.loads(options or "{}").get("folder") if method == WATCH_METHOD else None
        if isinstance(folder, str) and folder:
            names.append(Path(folder).name)  # the name alone: only takes/ is ever pruned
    return names


def _unnamed_takes(conn, root: Path, retention: Retention, now: float) -> list[str]:
    """Take folders no job or capture names, older than the setting their kind follows: a live
    watch's (``live-<capture id>``) the captures' one, an uploaded take's the results' one."""
    if not root.is_dir():
        return []
    named = set(_take_folders(conn.execute("SELECT id, method, options FROM jobs WHERE method = ?", (WATCH_METHOD,))))
    captures = {r[0] for r in conn.execute("SELECT id FROM captures")}
    old = []
    for folder in root.iterdir():
        live = folder.name.startswith(LIVE_TAKE_PREFIX)
        days = retention.captures_days if live else retention.results_days
        if folder.name.startswith(".") or days is None or folder.name in named:
            continue
        if live and folder.name.removeprefix(LIVE_TAKE_PREFIX) in captures:
            continue  # goes with its capture
        if folder.stat().st_mtime < now - days * DAY_S:
            old.append(folder.name)
    return old


def _remove_folders(root: Path, names: list[str]) -> None:
    """Each folder of ``names`` under ``root`` renamed ``.<name>.deleting`` and removed, with any a
    crash left renamed (module docstring)."""
    for name in names:
        folder = root / name
        if folder.is_dir():
            folder.rename(root / DELETING.format(name))
    for leftover in root.glob(DELETING.format("*")):  # this prune's, and a crash's
        shutil.rmtree(leftover, ignore_errors=True)


KEPT_RESULTS_DIR = "results"  # <data_dir>/results/<job id>.json: results kept when their job is deleted


def delete_finished_job(data_dir: Path, db_path: Path, job_id: str, keep_result: bool = False) -> Path | None:
    """Delete a finished job as retention does (its record, result and drawn report), on request
    (``DELETE /jobs/{id}``). ``keep_result``: its result document is first written to
    ``results/<job_id>.json`` in the data folder; that path is returned (None when nothing was kept).
    A job that is not finished (or has no row) is left alone: LookupError."""
    marks = ",".join("?" * len(FINISHED))
    with transaction(db_path) as conn:
        row = conn.execute(f"SELECT result FROM jobs WHERE id = ? AND state IN ({marks})", (job_id, *FINISHED)).fetchone()
        if row is None:
            raise LookupError(f"job {job_id} is not a finished job of {db_path}")
        kept = None
        if keep_result and row[0]:
            kept = Path(data_dir) / KEPT_RESULTS_DIR / f"{job_id}.json"
            kept.parent.mkdir(parents=True, exist_ok=True)
            kept.write_text(row[0] + "\n")  # before the row goes: a crash in between keeps both
        conn.execute("DELETE FROM jobs WHERE id = ?", (job_id,))
    shutil.rmtree(report_folder(data_dir, job_id), ignore_errors=True)
    log.info("deleted finished job %s on request%s", job_id, f"; its result is kept in {kept}" if kept else "")
    return kept


class Pruner:
    """Runs :func:`prune` at start and every ``every_s`` in a daemon thread, while the app lives."""

    def __init__(self, data_dir: Path, db_path: Path, retention: Retention, every_s: float = PRUNE_EVERY_S):
        self.args = (data_dir, db_path, retention)
        self.every_s = every_s
        self._halt = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        if not self.args[2].prunes:
            return  # the default: nothing is ever deleted, and no thread runs
        self._thread = threading.Thread(target=self._run, name="wandcal-retention", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                prune(*self.args)
            except Exception:  # a locked database or a full disk: the next round tries again
                log.exception("retention: pruning failed; trying again in %g s", self.every_s)
            if self._halt.wait(self.every_s):
                return

    def stop(self) -> None:
        self._halt.set()
        if self._thread is not None:
            self._thread.join(5)
