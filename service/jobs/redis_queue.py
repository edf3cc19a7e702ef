"""Run jobs on workers elsewhere through Redis and rq (``pip install 'wandcal[redis]'``).

The API side enqueues the whole points-level capture (rig.json, wand.csv, static.csv, points.csv,
axis.csv and floor.csv or drop.csv as text, a few MB at most; a ``solve_only`` job also its
standing result), so a worker needs no access to the server's data directory: any
machine with wandcal installed runs ``rq worker --url redis://HOST:6379/0 wandcal``. Job
records stay in the server's SQLite database; :meth:`RedisQueue.refresh` mirrors the rq job's
state, progress and result into them, so a finished result outlives Redis' result TTL.

Redis is a transport, the SQLite record the truth. While Redis is away (down, restarting, stopped)
the API reads the records from SQLite and answers what needs the queue (a new job, a cancellation)
with :class:`~wandcal.service.jobs.queue.QueueUnavailable`, a 503 with Retry-After; a job the API
had accepted but that Redis lost (restarted without persistence, flushed) is enqueued again from
its capture at the next poll. Guarantees: docs/reliability.md, "Jobs over Redis".

A job whose worker dies is re-queued once, then failed with the reason, as on the SQLite queue.
rq does the re-queueing (``Retry(max=1)``): a worker whose work horse dies (the kernel's OOM
killer, a crash in native code) retries the job at once, and rq's abandoned-job handling
(:class:`rq.registry.StartedJobRegistry` cleanup) retries the job of a worker that died with its
machine once that worker's heartbeat has lapsed. An error the task raises is its outcome, not a
crash: the failure callback :func:`on_failure` takes its retry away.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from wandcal.calib.errors import CalibrationError
from wandcal.capture.folder import Capture
from wandcal.service.jobs.queue import QueueUnavailable
from wandcal.service.jobs.records import MAX_ATTEMPTS, JobRecord, JobState, JobStore, not_retried
from wandcal.service.jobs.watch_job import WATCH_METHOD, run_watch, watch_files
from wandcal.service.jobs.worker import JobStopped, ThrottledProgress, solve, standing_result
from wandcal.service.storage import CAPTURE_FILES

JOB_TIMEOUT_S = 3600  # a large rig with the LP method stays well under an hour on a small PC
RESULT_TTL_S = 7 * 24 * 3600  # results are copied into SQLite on the first poll; a week is ample
CANCEL_KEY = "wandcal:cancel:{}"
RETRIES = MAX_ATTEMPTS - 1  # rq's Retry(max=...): re-queues after a crash, the first run not counted
DIED = "its rq worker died while running it"
# How often polls of running jobs run rq's abandoned-job cleanup: a dead worker is noticed only
# once its heartbeat (60 s or more) has lapsed, so every poll need not ask.
CLEANUP_EVERY_S = 10.0
# The API's Redis calls give up after this: a stopped Redis (SIGSTOP, a partitioned network) would
# otherwise hold every request that asks it. Workers keep rq's own connection, which waits.
REDIS_TIMEOUT_S = 2.0
# After a failed call the API leaves Redis alone this long (and says so in Retry-After): a page
# polling a dozen jobs then reads SQLite at once instead of waiting REDIS_TIMEOUT_S for each.
AWAY_S = 5.0
# A job the API accepted and Redis does not know is enqueued again, but not within this long of its
# creation: the enqueue that follows the record's INSERT may still be on its way.
VANISHED_AFTER_S = 10.0
VANISHED = "the job vanished from Redis (restarted without persistence, or flushed)"
log = logging.getLogger("wandcal.service")


def _connect(url: str):
    from redis import Redis
    from redis.backoff import NoBackoff
    from redis.retry import Retry

    return Redis.from_url(url, socket_timeout=REDIS_TIMEOUT_S, socket_connect_timeout=REDIS_TIMEOUT_S,
                          retry=Retry(NoBackoff(), 0))


def _unreachable() -> tuple[type[Exception], ...]:
    """redis-py's errors of a Redis that cannot be reached (down, loading its data, stopped)."""
    from redis.exceptions import ConnectionError, TimeoutError

    return ConnectionError, TimeoutError


PAYLOAD_FILES = CAPTURE_FILES  # the files of a points-level capture a solve reads, sent in the payload


def capture_payload(folder_texts: dict[str, str | None], method: str, options: dict,
                    standing: dict | None = None) -> dict:
    """What an rq worker needs: the capture's files as texts, the job, and for a ``solve_only`` job
    the result document it starts from."""
    return {"files": folder_texts, "method": method, "options": options, "standing": standing}


def payload_capture(files: dict[str, str | None]) -> Capture:
    """The capture rebuilt from its files' texts, read as the server reads its folder (every input
    kind: wand, static object, point tracks, axis points, floor or drop)."""
    import tempfile
    from pathlib import Path

    from wandcal.capture.folder import read_capture

    with tempfile.TemporaryDirectory(prefix="wandcal-rq-") as tmp:
        for name, text in files.items():
            if text is not None and name in PAYLOAD_FILES:
                (Path(tmp) / name).write_text(text)
        return read_capture(tmp)


def run_payload(payload: dict) -> dict:
    """The rq task: rebuild the capture from its texts and solve it; progress goes into ``job.meta``."""
    from rq import get_current_job

    job = get_current_job()

    def report(progress: dict) -> bool:
        if job is None:
            return False
        job.meta["progress"] = progress
        job.save_meta()
        return bool(job.connection.exists(CANCEL_KEY.format(job.id)))

    if payload["method"] == WATCH_METHOD:  # issue 36: the take's texts (service/jobs/watch_job.py)
        return run_watch(payload["files"], payload["options"], ThrottledProgress(report))
    capture = payload_capture(payload["files"])
    started = time.perf_counter()
    result = solve(capture, payload["method"], payload["options"], ThrottledProgress(report), payload.get("standing"))
    if job is not None:
        job.meta["solve_seconds"] = time.perf_counter() - started
        job.save_meta()
    return result


def on_failure(job, connection, exc_type, exc_value, traceback) -> None:
    """rq's failure callback, run where the job failed. An error the task raised (a capture that
    cannot be solved, a cancellation, a bug, rq's timeout) is the job's outcome: it is recorded and
    the job is not retried. rq calls this with :class:`rq.exceptions.AbandonedJobError` for a job
    whose worker died, which keeps its retry."""
    from rq.exceptions import AbandonedJobError

    if issubclass(exc_type, AbandonedJobError):
        return
    job.meta["attempt"] = _attempts(job, running=True)  # before the retry is taken away
    if issubclass(exc_type, CalibrationError):
        job.meta["error"] = str(exc_value)
    elif issubclass(exc_type, JobStopped):
        job.meta["error"] = "cancelled while running"
    else:
        job.meta["error"] = f"{exc_type.__name__}: {exc_value}"
    job.retries_left = 0  # saved with the failure that follows
    job.save_meta()


def _attempts(job, running: bool) -> int:
    """Runs of the rq ``job`` started so far (``running``: counting one that started)."""
    requeued = RETRIES - job.retries_left if job.retries_left is not None else 0
    return requeued + int(running)


class RedisQueue:
    """:class:`wandcal.service.jobs.queue.JobQueue` on rq; the Redis server and its workers are run by the site."""

    def __init__(self, store: JobStore, read_files: Callable[[str], dict[str, str | None]], url: str, name: str):
        from rq import Queue

        self.store = store
        self.read_files = read_files
        self.redis = _connect(url)
        self.queue = Queue(name, connection=self.redis)
        self._next_cleanup = 0.0  # time.monotonic() of the next abandoned-job cleanup
        self._away_until = 0.0  # time.monotonic() before which Redis is not asked (it failed just now)

    def start(self) -> None:
        self.redis.ping()  # fail at startup, not at the first job, when Redis is unreachable
        self._enqueue_unknown()

    def _enqueue_unknown(self) -> None:
        """At the start: a job whose record is unfinished and that Redis does not know is enqueued
        (a server killed between a job's INSERT and its enqueue; a Redis that lost it while this
        server was down). Only the data folder's owner starts a queue, so no enqueue is under way."""
        from rq.job import Job

        unknown = [r for r in self.store.unfinished() if not Job.exists(r.id, connection=self.redis)]
        for record in unknown:
            self._vanished(record, grace_s=0.0)

    def stop(self) -> None:
        self.redis.close()

    def _check_reachable(self) -> None:
        wait = self._away_until - time.monotonic()
        if wait > 0:
            raise QueueUnavailable(f"the job queue (Redis) is unreachable; try again in {wait:.0f} s", wait)

    def _went_away(self, exc: Exception) -> QueueUnavailable:
        if time.monotonic() >= self._away_until:
            log.warning("Redis is unreachable (%s): job records are read from SQLite, new jobs and cancellations "
                        "are refused with 503 for %g s, then Redis is asked again", exc, AWAY_S)
        self._away_until = time.monotonic() + AWAY_S
        return QueueUnavailable(f"the job queue (Redis) is unreachable ({exc}); try again in {AWAY_S:g} s", AWAY_S)

    def submit(self, job: JobRecord) -> None:
        """Enqueue the job; when Redis cannot take it, its record is withdrawn (the job was never
        accepted) and :class:`QueueUnavailable` raised."""
        try:
            self._check_reachable()
            try:
                self._enqueue(job)
            except _unreachable() as exc:
                raise self._went_away(exc) from None
        except QueueUnavailable:
            self.store.withdraw(job.id)
            raise

    def _enqueue(self, job: JobRecord) -> None:
        from rq import Callback, Retry

        if job.method == WATCH_METHOD:  # issue 36: a take watched, its folder's texts
            payload = capture_payload(watch_files(job.options["folder"]), job.method, job.options)
        else:
            payload = capture_payload(self.read_files(job.capture_id), job.method, job.options,
                                      standing_result(self.store, job))
        self.queue.enqueue_call(
            run_payload, args=(payload,), job_id=job.id, timeout=JOB_TIMEOUT_S, result_ttl=RESULT_TTL_S,
            failure_ttl=RESULT_TTL_S, retry=Retry(max=RETRIES), on_failure=Callback(on_failure),
        )

    def cancel(self, job_id: str) -> JobRecord | None:
        from rq.job import Job

        self._check_reachable()
        try:
            record = self._refresh(job_id)
            if record is None or record.state.finished:
                return record
            if record.state is JobState.queued:
                Job.fetch(job_id, connection=self.redis).cancel()
            else:
                self.redis.set(CANCEL_KEY.format(job_id), 1, ex=JOB_TIMEOUT_S)
        except _unreachable() as exc:
            raise self._went_away(exc) from None
        return self.store.request_cancel(job_id)  # refreshed above, so the record matches rq

    def refresh(self, job_id: str) -> JobRecord | None:
        """The record mirrored from rq; while Redis is unreachable, the record as SQLite has it."""
        if time.monotonic() < self._away_until:
            return self.store.get(job_id)
        try:
            return self._refresh(job_id)
        except _unreachable() as exc:
            self._went_away(exc)
            return self.store.get(job_id)

    def _refresh(self, job_id: str) -> JobRecord | None:
        from rq.exceptions import NoSuchJobError
        from rq.job import Job, JobStatus

        record = self.store.get(job_id)
        if record is None or record.state.finished:
            return record
        try:
            job = Job.fetch(job_id, connection=self.redis)
        except NoSuchJobError:
            return self._vanished(record)
        status, meta = job.get_status(), job.get_meta()
        started = job.started_at.timestamp() if job.started_at else None
        ended = job.ended_at.timestamp() if job.ended_at else time.time()
        attempts = _attempts(job, running=status != JobStatus.QUEUED)
        if status == JobStatus.FINISHED:
            self._mirror(
                job_id, JobState.done, result=job.return_value(), started=started, finished=ended, attempts=attempts,
                solve_seconds=meta.get("solve_seconds"), progress=meta.get("progress"),
            )
        elif status in (JobStatus.FAILED, JobStatus.STOPPED, JobStatus.CANCELED):
            cancelled = record.cancel_requested or status == JobStatus.CANCELED
            rq_reason = (_last_line(job.exc_info) or "").rstrip("; ")
            error = meta.get("error")
            if error is None and status == JobStatus.FAILED:  # the task raised nothing: its process died
                error = not_retried(f"{DIED} (rq: {rq_reason or 'no reason recorded'})", attempts,
                                    "the rq worker's log (and the kernel's, for the OOM killer)")
            self._mirror(
                job_id, JobState.cancelled if cancelled else JobState.failed,
                error=error or rq_reason or f"the rq job ended as {status.value}", started=started, finished=ended,
                attempts=meta.get("attempt", attempts),
            )
        elif status == JobStatus.STARTED:
            self._mirror(job_id, JobState.running, started=started, attempts=attempts,
                                   progress=meta.get("progress"))
            self._retry_abandoned()
        elif status == JobStatus.QUEUED:
            if attempts > 0:  # re-queued by rq after its worker died
                if (record.progress or {}).get("stage") != "requeued":  # said once, when the record first sees it
                    log.warning("job %s: %s; re-queued by rq (attempt %d of %d)", job_id, DIED, attempts, MAX_ATTEMPTS)
                self._mirror(job_id, JobState.queued, attempts=attempts,
                             progress={"stage": "requeued", "message": f"re-queued: {DIED}"})
            self._retry_abandoned()  # it may be one a worker took and never started
        return self.store.get(job_id)

    def _mirror(self, job_id: str, state: JobState, **fields) -> None:
        """Write rq's view into the record unless the record has finished meanwhile (another poll
        recorded the end first; a job solved twice): the first outcome is kept, this one logged."""
        if not self.store.set_outcome(job_id, state, **fields) and state.finished:
            log.info("job %s: a later outcome (%s) is not recorded: the record had finished first (a second "
                     "run, or a second poll) and keeps its first outcome", job_id, state.value)

    def _vanished(self, record: JobRecord, grace_s: float | None = None) -> JobRecord | None:
        """A job the API accepted that Redis does not know: enqueued again from its capture (its
        outcome is still recorded once: the record takes the first one it sees). ``grace_s``:
        not within this long of its creation (default :data:`VANISHED_AFTER_S`)."""
        if time.time() - record.created < (VANISHED_AFTER_S if grace_s is None else grace_s):
            return record  # its enqueue may still be under way
        if record.cancel_requested:
            self._mirror(record.id, JobState.cancelled, finished=time.time(), error=f"cancelled; {VANISHED}")
            return self.store.get(record.id)
        try:
            self._enqueue(record)
        except (OSError, CalibrationError) as exc:  # the capture was deleted meanwhile
            self._mirror(record.id, JobState.failed, finished=time.time(),
                                   error=f"{VANISHED}, and its capture cannot be read again ({exc}); submit a new job")
            return self.store.get(record.id)
        log.warning("job %s: %s; enqueued again from its capture", record.id, VANISHED)
        self._mirror(record.id, JobState.queued, progress={"stage": "requeued", "message": f"re-queued: {VANISHED}"})
        return self.store.get(record.id)

    def _retry_abandoned(self) -> None:
        """rq's abandoned-job handling for this queue, run now: a job whose worker died with its
        machine is re-queued (or failed) within ``CLEANUP_EVERY_S`` of its heartbeat lapsing, not at
        some worker's next maintenance (every 10 minutes by default). The lock is the one workers clean under."""
        from rq.registry import StartedJobRegistry
        from rq.timeouts import TimerDeathPenalty

        now = time.monotonic()
        if now < self._next_cleanup:
            return
        self._next_cleanup = now + CLEANUP_EVERY_S
        if not self.queue.acquire_maintenance_lock():
            return  # a worker is cleaning right now
        try:
            # the request thread is not the main thread: time the callback with a timer, not SIGALRM
            StartedJobRegistry(queue=self.queue, death_penalty_class=TimerDeathPenalty).cleanup()
            requeue_untaken(self.queue)
        finally:
            self.queue.release_maintenance_lock()

    def drain(self) -> list[JobRecord]:
        from rq import SimpleWorker

        ids = list(self.queue.get_job_ids())
        SimpleWorker([self.queue], connection=self.redis).work(burst=True)
        records = [self.refresh(i) for i in ids]
        return [r for r in records if r is not None]  # all: a job has its row (JobStore.create) before it is submitted


def requeue_untaken(queue, lapsed: bool = False) -> list[str]:
    """Put back on ``queue`` the jobs a worker took and never started; returns their ids.

    rq moves a job from the queue to an intermediate list, then into its started registry; a
    worker that dies or loses Redis in between (its reply lost in a Redis restart) leaves the job
    in neither: ``queued`` for ever to the record. rq's workers hand it on only at their
    maintenance, every 10 minutes. Here it goes back once it has stayed a minute (rq's own rule;
    ``lapsed``: at once, as if the minute had passed), within :data:`CLEANUP_EVERY_S`. It never
    started, so no attempt is counted."""
    intermediate = queue.intermediate_queue
    moved = []
    for job_id in intermediate.get_job_ids():
        if job_id in queue.started_job_registry:
            continue
        first_seen_now = intermediate.set_first_seen(job_id)
        if not lapsed and (first_seen_now or not intermediate.should_be_cleaned_up(job_id)):
            continue
        job = queue.fetch_job(job_id)
        intermediate.remove(job_id)
        if job is not None:
            queue.enqueue_job(job)
            log.warning("job %s: a worker took it off the queue and never started it (it died, or lost Redis); "
                        "put back on the queue", job_id)
            moved.append(job_id)
    return moved


def _last_line(text: str | None) -> str | None:
    lines = [line for line in (text or "").strip().splitlines() if line.strip()]
    return lines[-1] if lines else None
