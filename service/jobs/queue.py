"""The job interface the API talks to, and its default backend: SQLite plus local worker processes.

``JobQueue`` is what routes use; ``SQLiteQueue`` (here) and ``RedisQueue``
(:mod:`wandcal.service.jobs.redis_queue`) implement it. Job records always live in the service's SQLite
database, so finished results survive whatever happens to the queue.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from wandcal.capture.folder import Capture
from wandcal.service.jobs.records import MAX_ATTEMPTS, JobRecord, JobStore
from wandcal.service.jobs.worker import WorkerPool, run_claim

RESTART_REASON = "the server stopped while the job was running"
log = logging.getLogger("wandcal.service")


class QueueUnavailable(Exception):
    """The queue cannot be reached just now (Redis down): a new job or a cancellation is answered
    503 with ``Retry-After: retry_after_s``; reads are answered from the records."""

    def __init__(self, message: str, retry_after_s: float):
        super().__init__(message)
        self.retry_after_s = retry_after_s


class JobQueue(Protocol):
    store: JobStore

    def start(self) -> None:
        """Recover after a restart and start executing jobs."""

    def stop(self) -> None: ...

    def submit(self, job: JobRecord) -> None:
        """Queue a job whose record ``store.create`` has just written."""

    def cancel(self, job_id: str) -> JobRecord | None: ...

    def refresh(self, job_id: str) -> JobRecord | None:
        """The job's record, brought up to date with the queue."""

    def drain(self) -> list[JobRecord]:
        """Run every queued job to its end in this process, oldest first (tests, benchmarks)."""


class SQLiteQueue:
    """The database is the queue: workers claim the oldest queued row in an immediate transaction."""

    def __init__(self, store: JobStore, load_capture: Callable[[str], Capture], data_dir: Path, workers: int):
        self.store = store
        self.load_capture = load_capture
        self.pool = WorkerPool(store, data_dir, workers) if workers > 0 else None

    def start(self) -> None:
        # only the data folder's owner starts a queue (service/folder_lock.py): every running job is its own
        for job in self.store.recover(RESTART_REASON):
            log.warning("job %s was running when the server stopped: now %s (attempt %d of %d)%s", job.id,
                        job.state.value, job.attempts, MAX_ATTEMPTS, f": {job.error}" if job.error else "")
        if self.pool is not None:
            self.pool.start()

    def stop(self) -> None:
        if self.pool is not None:
            self.pool.stop()

    def submit(self, job: JobRecord) -> None:
        if self.pool is not None:
            self.pool.notify()

    def cancel(self, job_id: str) -> JobRecord | None:
        return self.store.request_cancel(job_id)

    def refresh(self, job_id: str) -> JobRecord | None:
        return self.store.get(job_id)

    def drain(self) -> list[JobRecord]:
        done = []
        while (claim := self.store.claim(os.getpid())) is not None:
            run_claim(self.store, self.load_capture, claim)
            done.append(self.store.stored(claim.job.id))
        return done
