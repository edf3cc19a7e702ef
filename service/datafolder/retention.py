"""Retention: old results and captures deleted only when the settings allow it (default: never).

Two settings, each off unless set (docs/reliability.md, "Retention"):

| setting | deletes, once older than that many days |
|---|---|
| ``keep_results_days`` | a finished job (``done``, ``failed``, ``cancelled``): its record, its result and its drawn report |
| ``keep_captures_days`` | a capture created that long ago whose jobs are all finished that long ago (or that has none), with those jobs, its frame-set rows and its folder |

A queued or running job, and its capture, are never deleted. The owner of the data folder prunes
at its start and every :data:`PRUNE_EVERY_S` after. The order makes a crash keep rather than
lose: the rows go first (one transaction), then the folder is renamed ``captures/.<id>.deleting``
and removed; a folder a crash left at the rename is removed at the next prune, and one left before
it has no row and is registered again at the next start (recovery).
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from wandcal.service.db import transaction
from wandcal.service.jobs.records import JobState
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
    captures_root = Path(data_dir) / "captures"
    jobs: list[str] = []
    captures: list[str] = []
    marks = ",".join("?" * len(FINISHED))
    with transaction(db_path) as conn:
        if retention.captures_days is not None:
            cutoff = now - retention.captures_days * DAY_S
            captures = [r[0] for r in conn.execute(
                f"SELECT id FROM captures c WHERE created < ? AND NOT EXISTS (SELECT 1 FROM jobs j WHERE "
                f"j.capture_id = c.id AND (j.state NOT IN ({marks}) OR COALESCE(j.finished, j.created) >= ?))",
                (cutoff, *FINISHED, cutoff))]
            for capture_id in captures:
                jobs += [r[0] for r in conn.execute("SELECT id FROM jobs WHERE capture_id = ?", (capture_id,))]
                conn.execute("DELETE FROM jobs WHERE capture_id = ?", (capture_id,))
                conn.execute("DELETE FROM framesets WHERE capture_id = ?", (capture_id,))
                conn.execute("DELETE FROM captures WHERE id = ?", (capture_id,))
        if retention.results_days is not None:
            cutoff = now - retention.results_days * DAY_S
            old = [r[0] for r in conn.execute(
                f"SELECT id FROM jobs WHERE state IN ({marks}) AND COALESCE(finished, created) < ?", (*FINISHED, cutoff))]
            conn.executemany("DELETE FROM jobs WHERE id = ?", [(j,) for j in old])
            jobs += old
    for job_id in jobs:
        shutil.rmtree(report_folder(data_dir, job_id), ignore_errors=True)
    for capture_id in captures:
        folder = captures_root / capture_id
        if folder.is_dir():
            folder.rename(captures_root / DELETING.format(capture_id))
    for leftover in captures_root.glob(DELETING.format("*")):  # this prune's, and a crash's
        shutil.rmtree(leftover, ignore_errors=True)
    if jobs or captures:
        log.info("retention: deleted %d finished job(s) and %d capture(s) (keep_results_days %s, "
                 "keep_captures_days %s): %s", len(jobs), len(captures), retention.results_days,
                 retention.captures_days, ", ".join(captures + jobs))
    return jobs, captures


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
