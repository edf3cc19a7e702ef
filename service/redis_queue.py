"""Run jobs on workers elsewhere through Redis and rq (``pip install 'wandcal[redis]'``).

The API side enqueues the whole points-level capture (rig.json, wand.csv and static.csv as
text, a few MB at most), so a worker needs no access to the server's data directory: any
machine with wandcal installed runs ``rq worker --url redis://HOST:6379/0 wandcal``. Job
records stay in the server's SQLite database; :meth:`RedisQueue.refresh` mirrors the rq job's
state, progress and result into them, so a finished result outlives Redis' result TTL.
"""

from __future__ import annotations

import json
import time
from typing import Callable

from calib.errors import CalibrationError
from capture.folder import Capture, parse_static_csv, parse_wand_csv, rig_from_json
from service.jobs import JobRecord, JobState, JobStore
from service.worker import JobStopped, ThrottledProgress, solve

JOB_TIMEOUT_S = 3600  # a large rig with the LP method stays well under an hour on a small PC
RESULT_TTL_S = 7 * 24 * 3600  # results are copied into SQLite on the first poll; a week is ample
CANCEL_KEY = "wandcal:cancel:{}"


def _connect(url: str):
    from redis import Redis

    return Redis.from_url(url)


def capture_payload(folder_texts: dict[str, str | None], method: str, options: dict) -> dict:
    return {"files": folder_texts, "method": method, "options": options}


def run_payload(payload: dict) -> dict:
    """The rq task: rebuild the capture from its texts and solve it; progress goes into ``job.meta``."""
    from rq import get_current_job

    job = get_current_job()
    files = payload["files"]
    try:
        rig = rig_from_json(json.loads(files["rig.json"]))
        wand = parse_wand_csv(files["wand.csv"], rig)
        static = parse_static_csv(files["static.csv"], rig) if files.get("static.csv") else None
        capture = Capture(rig=rig, wand=wand, static=static)

        def report(progress: dict) -> bool:
            if job is None:
                return False
            job.meta["progress"] = progress
            job.save_meta()
            return bool(job.connection.exists(CANCEL_KEY.format(job.id)))

        started = time.perf_counter()
        result = solve(capture, payload["method"], payload["options"], ThrottledProgress(report))
        if job is not None:
            job.meta["solve_seconds"] = time.perf_counter() - started
            job.save_meta()
        return result
    except (CalibrationError, JobStopped) as exc:
        if job is not None:
            job.meta["error"] = str(exc) if isinstance(exc, CalibrationError) else "cancelled while running"
            job.save_meta()
        raise


class RedisQueue:
    """:class:`service.queue.JobQueue` on rq; the Redis server and its workers are run by the site."""

    def __init__(self, store: JobStore, read_files: Callable[[str], dict[str, str | None]], url: str, name: str):
        from rq import Queue

        self.store = store
        self.read_files = read_files
        self.redis = _connect(url)
        self.queue = Queue(name, connection=self.redis)

    def start(self) -> None:
        self.redis.ping()  # fail at startup, not at the first job, when Redis is unreachable

    def stop(self) -> None:
        self.redis.close()

    def submit(self, job: JobRecord) -> None:
        payload = capture_payload(self.read_files(job.capture_id), job.method, job.options)
        self.queue.enqueue_call(
            run_payload, args=(payload,), job_id=job.id, timeout=JOB_TIMEOUT_S, result_ttl=RESULT_TTL_S,
            failure_ttl=RESULT_TTL_S,
        )

    def cancel(self, job_id: str) -> JobRecord | None:
        from rq.job import Job

        record = self.refresh(job_id)
        if record is None or record.state.finished:
            return record
        if record.state is JobState.queued:
            Job.fetch(job_id, connection=self.redis).cancel()
        else:
            self.redis.set(CANCEL_KEY.format(job_id), 1, ex=JOB_TIMEOUT_S)
        return self.store.request_cancel(job_id)  # refreshed above, so the record matches rq

    def refresh(self, job_id: str) -> JobRecord | None:
        from rq.exceptions import NoSuchJobError
        from rq.job import Job, JobStatus

        record = self.store.get(job_id)
        if record is None or record.state.finished:
            return record
        try:
            job = Job.fetch(job_id, connection=self.redis)
        except NoSuchJobError:
            self.store.set_outcome(
                job_id, JobState.failed, finished=time.time(),
                error="the job vanished from Redis (flushed or expired); submit it again",
            )
            return self.store.get(job_id)
        status, meta = job.get_status(), job.get_meta()
        started = job.started_at.timestamp() if job.started_at else None
        ended = job.ended_at.timestamp() if job.ended_at else time.time()
        if status == JobStatus.FINISHED:
            self.store.set_outcome(
                job_id, JobState.done, result=job.return_value(), started=started, finished=ended, attempts=1,
                solve_seconds=meta.get("solve_seconds"), progress=meta.get("progress"),
            )
        elif status in (JobStatus.FAILED, JobStatus.STOPPED, JobStatus.CANCELED):
            cancelled = record.cancel_requested or status == JobStatus.CANCELED
            error = meta.get("error") or _last_line(job.exc_info) or f"the rq job ended as {status.value}"
            self.store.set_outcome(
                job_id, JobState.cancelled if cancelled else JobState.failed, error=error, started=started,
                finished=ended, attempts=1,
            )
        elif status == JobStatus.STARTED:
            self.store.set_outcome(job_id, JobState.running, started=started, attempts=1, progress=meta.get("progress"))
        return self.store.get(job_id)

    def drain(self) -> list[JobRecord]:
        from rq import SimpleWorker

        ids = list(self.queue.get_job_ids())
        SimpleWorker([self.queue], connection=self.redis).work(burst=True)
        return [self.refresh(i) for i in ids]


def _last_line(text: str | None) -> str | None:
    lines = [line for line in (text or "").strip().splitlines() if line.strip()]
    return lines[-1] if lines else None
