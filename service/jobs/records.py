"""Job records and their states, kept in SQLite (arq style: explicit states, attempts, timestamps).

A job moves ``queued -> running -> done | failed | cancelled``. A job whose worker died (the
server was killed, or the process crashed) goes back to ``queued`` once, then ``failed`` with the
reason. Every write of an outcome carries the claim's ``run_token``, so a stale worker of an
earlier attempt can never overwrite the outcome of a later one; an outcome mirrored from Redis
is written only to an unfinished row (:meth:`JobStore.set_outcome`). A finished row is never
written again: every job ends exactly once.
"""

from __future__ import annotations

import enum
import json
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from wandcal.service.db import connect, transaction

# The first run plus one re-queue after a crash: a job that takes its worker down twice is
# probably what takes it down, so it fails instead of looping.
MAX_ATTEMPTS = 2


def not_retried(reason: str, attempt: int, log: str = "the server log") -> str:
    """The error of a job whose worker died on its last attempt: what happened, and what to do."""
    return (f"{reason} during attempt {attempt} of {MAX_ATTEMPTS}; the job is not retried again. "
            f"Check {log} and the capture, then submit a new job")


class JobState(str, enum.Enum):
    queued = "queued"
    running = "running"
    done = "done"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobState.done, JobState.failed, JobState.cancelled)


UNFINISHED = (JobState.queued.value, JobState.running.value)  # the states a record may still leave


@dataclass(frozen=True)
class JobRecord:
    """A snapshot of one job's row. Times are Unix seconds."""

    id: str
    capture_id: str
    method: str
    options: dict
    state: JobState
    attempts: int
    created: float
    started: float | None
    finished: float | None
    progress: dict | None
    result: dict | None
    error: str | None
    cancel_requested: bool
    solve_seconds: float | None

    @classmethod
    def from_row(cls, row) -> JobRecord:
        return cls(
            id=row["id"],
            capture_id=row["capture_id"],
            method=row["method"],
            options=json.loads(row["options"]),
            state=JobState(row["state"]),
            attempts=row["attempts"],
            created=row["created"],
            started=row["started"],
            finished=row["finished"],
            progress=json.loads(row["progress"]) if row["progress"] else None,
            result=json.loads(row["result"]) if row["result"] else None,
            error=row["error"],
            cancel_requested=bool(row["cancel_requested"]),
            solve_seconds=row["solve_seconds"],
        )


@dataclass(frozen=True)
class Claim:
    """A job taken by one worker; ``token`` authorises writing its outcome."""

    job: JobRecord
    token: str


class JobStore:
    """All reads and writes of job rows. Safe to use from several processes at once."""

    def __init__(self, db_path: Path):
        self.db_path = Path(db_path)

    def create(self, capture_id: str, method: str, options: dict) -> JobRecord:
        job_id = uuid.uuid4().hex
        with connect(self.db_path) as conn:
            conn.execute(
                "INSERT INTO jobs (id, capture_id, method, options, state, created) VALUES (?, ?, ?, ?, ?, ?)",
                (job_id, capture_id, method, json.dumps(options), JobState.queued.value, time.time()),
            )
        return self.stored(job_id)

    def get(self, job_id: str) -> JobRecord | None:
        with connect(self.db_path) as conn:
            row = conn.execute("SELECT * FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return JobRecord.from_row(row) if row else None

    def stored(self, job_id: str) -> JobRecord:
        """The record of a job this store holds (rows are never deleted); LookupError if it has none."""
        record = self.get(job_id)
        if record is None:
            raise LookupError(f"job {job_id} has no row in {self.db_path}")
        return record

    def newest(self, capture_id: str | None = None, limit: int = 100) -> list[JobRecord]:
        """Up to ``limit`` jobs, newest first: of one capture, or of all when ``capture_id`` is None."""
        query, args = "SELECT * FROM jobs", []
        if capture_id is not None:
            query, args = query + " WHERE capture_id = ?", [capture_id]
        with connect(self.db_path) as conn:
            rows = conn.execute(query + " ORDER BY created DESC LIMIT ?", (*args, limit)).fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def count(self, state: JobState) -> int:
        with connect(self.db_path) as conn:
            return conn.execute("SELECT COUNT(*) FROM jobs WHERE state = ?", (state.value,)).fetchone()[0]

    def claim(self, worker_pid: int, job_id: str | None = None) -> Claim | None:
        """Take the oldest queued job (or ``job_id`` if it is queued) and mark it running."""
        token = uuid.uuid4().hex
        with transaction(self.db_path) as conn:
            if job_id is None:
                row = conn.execute(
                    "SELECT id FROM jobs WHERE state = ? ORDER BY created LIMIT 1", (JobState.queued.value,)
                ).fetchone()
            else:
                row = conn.execute(
                    "SELECT id FROM jobs WHERE state = ? AND id = ?", (JobState.queued.value, job_id)
                ).fetchone()
            if row is None:
                return None
            conn.execute(
                "UPDATE jobs SET state = ?, attempts = attempts + 1, started = ?, run_token = ?, worker_pid = ?,"
                " progress = ? WHERE id = ?",
                (
                    JobState.running.value,
                    time.time(),
                    token,
                    worker_pid,
                    json.dumps({"stage": "start", "message": "loading the capture"}),
                    row["id"],
                ),
            )
        return Claim(job=self.stored(row["id"]), token=token)

    def report_progress(self, job_id: str, token: str, progress: dict) -> bool:
        """Store the latest progress; returns True when the job should stop (cancelled or lost)."""
        with connect(self.db_path) as conn:
            cur = conn.execute(
                "UPDATE jobs SET progress = ? WHERE id = ? AND run_token = ? AND state = ?",
                (json.dumps(progress), job_id, token, JobState.running.value),
            )
            if cur.rowcount == 0:
                return True  # re-queued or finished by someone else: this run no longer owns the job
            row = conn.execute("SELECT cancel_requested FROM jobs WHERE id = ?", (job_id,)).fetchone()
        return bool(row["cancel_requested"])

    def finish(
        self, job_id: str, token: str, state: JobState, *, result: dict | None = None, error: str | None = None,
        solve_seconds: float | None = None, progress: dict | None = None,
    ) -> bool:
        """Record the outcome of the claim ``token``; False if that claim no longer owns the job."""
        assert state.finished
        with connect(self.db_path) as conn:
            cur = conn.execute(
                "UPDATE jobs SET state = ?, finished = ?, result = ?, error = ?, solve_seconds = ?, run_token = NULL,"
                " progress = COALESCE(?, progress) WHERE id = ? AND run_token = ? AND state = ?",
                (
                    state.value,
                    time.time(),
                    json.dumps(result) if result is not None else None,
                    error,
                    solve_seconds,
                    json.dumps(progress) if progress is not None else None,
                    job_id,
                    token,
                    JobState.running.value,
                ),
            )
        return cur.rowcount == 1

    def set_outcome(self, job_id: str, state: JobState, **fields) -> bool:
        """Mirror a state reported by an external queue (Redis) into the record, unless the record
        is finished: a compare-and-set on the row's state, so the first outcome recorded is kept and
        neither a second finisher (a job solved twice) nor a stale mirror (a poll that read rq before
        another poll recorded the end) can replace it. False when the row was finished (or gone)."""
        cols = {"state": state.value}
        for key in ("attempts", "started", "finished", "error", "solve_seconds"):
            if fields.get(key) is not None:
                cols[key] = fields[key]
        for key in ("progress", "result"):
            if fields.get(key) is not None:
                cols[key] = json.dumps(fields[key])
        assignments = ", ".join(f"{k} = ?" for k in cols)
        with connect(self.db_path) as conn:
            cur = conn.execute(f"UPDATE jobs SET {assignments} WHERE id = ? AND state IN (?, ?)",
                               (*cols.values(), job_id, *UNFINISHED))
        return cur.rowcount == 1

    def unfinished(self) -> list[JobRecord]:
        """The queued and running jobs, oldest first."""
        with connect(self.db_path) as conn:
            rows = conn.execute("SELECT * FROM jobs WHERE state IN (?, ?) ORDER BY created", UNFINISHED).fetchall()
        return [JobRecord.from_row(r) for r in rows]

    def withdraw(self, job_id: str) -> None:
        """Delete a job that was never accepted (its queue refused it), if still queued."""
        with connect(self.db_path) as conn:
            conn.execute("DELETE FROM jobs WHERE id = ? AND state = ?", (job_id, JobState.queued.value))

    def request_cancel(self, job_id: str) -> JobRecord | None:
        """Cancel a queued job now; ask a running one to stop at its next progress report."""
        now = time.time()
        with transaction(self.db_path) as conn:
            conn.execute(
                "UPDATE jobs SET state = ?, finished = ?, error = ? WHERE id = ? AND state = ?",
                (JobState.cancelled.value, now, "cancelled before it started", job_id, JobState.queued.value),
            )
            conn.execute(
                "UPDATE jobs SET cancel_requested = 1 WHERE id = ? AND state = ?", (job_id, JobState.running.value)
            )
        return self.get(job_id)

    def recover(self, reason: str, worker_pids: list[int] | None = None) -> list[JobRecord]:
        """Running jobs whose worker is gone (all of them at startup, or those of ``worker_pids``):
        re-queue each once, fail it after :data:`MAX_ATTEMPTS`, finish it as cancelled if asked."""
        now = time.time()
        with transaction(self.db_path) as conn:
            query = "SELECT * FROM jobs WHERE state = ?"
            args: list[str | int] = [JobState.running.value]
            if worker_pids is not None:
                query += f" AND worker_pid IN ({','.join('?' * len(worker_pids))})"
                args += list(worker_pids)
            rows = conn.execute(query, args).fetchall()
            for row in rows:
                if row["cancel_requested"]:
                    new, error = JobState.cancelled, "cancelled; its worker stopped"
                elif row["attempts"] >= MAX_ATTEMPTS:
                    new, error = JobState.failed, not_retried(reason, row["attempts"])
                else:
                    new, error = JobState.queued, None
                conn.execute(
                    "UPDATE jobs SET state = ?, error = ?, run_token = NULL, worker_pid = NULL, progress = ?,"
                    " finished = ? WHERE id = ?",
                    (
                        new.value,
                        error,
                        json.dumps({"stage": "requeued", "message": f"re-queued: {reason}"})
                        if new is JobState.queued
                        else row["progress"],
                        now if new.finished else None,
                        row["id"],
                    ),
                )
        return [self.stored(r["id"]) for r in rows]

    def cancelling(self) -> dict[str, int]:
        """{job id: worker pid} of running jobs asked to cancel."""
        with connect(self.db_path) as conn:
            rows = conn.execute(
                "SELECT id, worker_pid FROM jobs WHERE state = ? AND cancel_requested = 1", (JobState.running.value,)
            ).fetchall()
        return {r["id"]: r["worker_pid"] for r in rows}
