"""Running calibration jobs: one function shared by worker processes, ``drain()`` and Redis workers.

Worker processes are started with the ``spawn`` method (a clean interpreter, no inherited
locks or sockets) and die with the server (``PR_SET_PDEATHSIG``), so a killed server leaves no
solver writing behind its back; the restarted server re-queues the job instead.

The pool talks to its workers through a semaphore (wake) and a lock-free shared byte (stop),
never a ``multiprocessing.Event``: an Event's ``set()`` waits for every process asleep in its
``wait()`` to acknowledge, so one worker killed while asleep (a cancellation's kill racing the
job's end) hung every later ``set()``, and with it ``wandcal serve``'s stop (issue 21). Workers
ignore SIGINT (a terminal's Ctrl-C and the systemd unit's KillSignal reach the whole group): the
server decides how they stop.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import multiprocessing
import os
import signal
import sqlite3
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from wandcal.calib.errors import CalibrationError
from wandcal.capture.folder import Capture
from wandcal.service.db import disk_full
from wandcal.service.jobs.records import MAX_ATTEMPTS, Claim, JobRecord, JobState, JobStore
from wandcal.service.jobs.watch_job import WATCH_METHOD, run_watch, watch_files
from wandcal.service.schemas import JobOptions

log = logging.getLogger("wandcal.worker")

PROGRESS_INTERVAL_S = 0.2  # write progress at most this often: the page polls every second
POLL_INTERVAL_S = 0.25  # an idle worker looks for work this often (and at once when woken)
MONITOR_INTERVAL_S = 0.5  # the pool checks for dead workers and overdue cancellations this often
CANCEL_GRACE_S = 2.0  # a running job asked to cancel is killed if it has not stopped by then
# On stop, idle workers leave within one POLL_INTERVAL_S; a worker still busy after this is solving
# a job, which is killed and queued again (the server's stop must end within a few seconds).
STOP_GRACE_S = 1.0
PR_SET_PDEATHSIG = 1  # linux/prctl.h
DISK_FULL_RETRY_S = 1.0  # a full disk frees when someone acts: checking once a second costs nothing


class JobStopped(Exception):
    """Raised from the progress callback to abort ``calibrate`` (cancelled, or the job was lost)."""


def solve(capture: Capture, method: str, options: dict, progress: Callable[[dict], None],
          standing: dict | None = None) -> dict:
    """Calibrate a capture with a job's ``options`` (as stored: ``JobOptions``'s JSON, any field
    left out taking its default); returns the ``wandcal-result/1`` document. With ``solve_only``,
    ``standing`` is the result document of the job ``from_job`` and only the named cameras are
    re-solved, as ``wandcal calibrate --from RESULT --solve-only CAM`` does."""
    job = JobOptions.model_validate(options)
    if job.solve_only:
        return _solve_only(capture, job, method, progress, standing)
    from wandcal.calib.run.calibrate import calibrate  # the solver; imported here so the API process never loads it

    static = capture.static if job.use_static else None
    result = calibrate(capture.rig, capture.wand, static=static, options=job.calibration(method), progress=progress,
                       points=capture.points, axis=capture.axis, vertical=capture.vertical)
    return result.to_json()


def _solve_only(capture: Capture, job: JobOptions, method: str, progress: Callable[[dict], None],
                standing: dict | None) -> dict:
    from wandcal.capture.result_file import result_from_json
    from wandcal.service.standing_result import solve_only_capture

    if standing is None:
        raise CalibrationError(f"job {job.from_job} (from_job) has no result any more: it was deleted; re-solve from "
                               "another done job, or calibrate afresh")
    source = f"the result of job {job.from_job}"
    options = job.calibration(method)
    options.check()
    return solve_only_capture(result_from_json(standing, source), capture, job.solve_only, options, source=source,
                              capture_name="the job's capture", progress=progress).to_json()


def standing_result(store: JobStore, job: JobRecord) -> dict | None:
    """The result document a ``solve_only`` job starts from (its ``from_job``'s), or None."""
    from_job = (job.options or {}).get("from_job")
    record = store.get(from_job) if from_job else None
    return record.result if record is not None else None


class ThrottledProgress:
    """The progress callback: forwards at most one report per interval, and stops the solve when told."""

    def __init__(self, report: Callable[[dict], bool], interval_s: float = PROGRESS_INTERVAL_S):
        self.report = report
        self.interval_s = interval_s
        self.last = 0.0

    def __call__(self, update: dict) -> None:
        now = time.monotonic()
        if now - self.last < self.interval_s:
            return
        self.last = now
        clean = {k: update[k] for k in ("stage", "iteration", "cost", "message") if k in update}
        try:
            stop = self.report(clean)
        except sqlite3.OperationalError as exc:
            if not disk_full(exc):
                raise
            return  # progress is not worth failing a solve for; the outcome waits for room (finish_durably)
        if stop:
            raise JobStopped()


def run_claim(store: JobStore, load_capture: Callable[[str], Capture], claim: Claim) -> None:
    """Run one claimed job to its outcome and record it (unless the claim was lost meanwhile)."""
    job, token = claim.job, claim.token
    progress = ThrottledProgress(lambda p: store.report_progress(job.id, token, p))
    started = time.perf_counter()
    try:
        if job.method == WATCH_METHOD:  # issue 36: a take watched (service/jobs/watch_job.py)
            result = run_watch(watch_files(job.options["folder"]), job.options, progress)
        else:
            capture = load_capture(job.capture_id)
            result = solve(capture, job.method, job.options, progress, standing_result(store, job))
    except JobStopped:
        current = store.get(job.id)
        if current is not None and current.cancel_requested:
            finish_durably(store, job.id, token, JobState.cancelled, error="cancelled while running")
        return
    except CalibrationError as exc:
        finish_durably(store, job.id, token, JobState.failed, error=str(exc))
        return
    except Exception as exc:  # a solver bug: keep the worker alive and say what happened
        log.error("job %s failed:\n%s", job.id, traceback.format_exc())
        finish_durably(
            store, job.id, token, JobState.failed,
            error=f"internal error {type(exc).__name__}: {exc}; this is a bug, please report it with the capture",
        )
        return
    seconds = time.perf_counter() - started
    finish_durably(
        store, job.id, token, JobState.done, result=result, solve_seconds=seconds,
        progress={"stage": "done", "message": f"solved in {seconds:.1f} s"},
    )


def finish_durably(store: JobStore, job_id: str, token: str, state: JobState, retry_s: float = DISK_FULL_RETRY_S,
                   **outcome) -> bool:
    """:meth:`JobStore.finish`, waiting while the disk is full: a solve's outcome is kept in memory
    until it can be written, instead of being lost with the worker (a killed worker's job is
    re-queued at the next start, so waiting here loses nothing either)."""
    warned = False
    while True:
        try:
            return store.finish(job_id, token, state, **outcome)
        except sqlite3.OperationalError as exc:
            if not disk_full(exc):
                raise
            if not warned:
                log.error("job %s: cannot record its outcome, the disk is full; retrying every %g s", job_id, retry_s)
                warned = True
            time.sleep(retry_s)


def _die_with_parent() -> None:
    with contextlib.suppress(OSError, AttributeError):  # not Linux: the parent-pid check in the loop still ends the worker
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def worker_main(db_path: str, data_dir: str, wake, stop, parent: int | None = None) -> None:
    """Entry point of a spawned worker process: claim and run jobs until told to stop.

    ``wake``: a semaphore released when a job is queued; ``stop``: a shared byte, non-zero to stop.
    ``parent`` is the server's pid, passed in: a server that dies before this process sets
    PR_SET_PDEATHSIG would otherwise leave it polling forever under init (seen in the tests)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    parent = os.getppid() if parent is None else parent
    from wandcal.service.storage import CaptureStore

    store = JobStore(Path(db_path))
    captures = CaptureStore(Path(data_dir), Path(db_path), None)
    import wandcal.calib.run.calibrate  # noqa: F401  (load the solver before the first job, not during it)
    while not stop.value and os.getppid() == parent:
        try:
            claim = store.claim(os.getpid())
        except sqlite3.OperationalError as exc:  # a full disk: claim nothing until there is room
            if not disk_full(exc):
                raise
            claim = None
        if claim is None:
            wake.acquire(timeout=POLL_INTERVAL_S)
            continue
        run_claim(store, captures.load, claim)


class WorkerPool:
    """N solver processes plus a monitor thread that replaces dead ones and enforces cancellation."""

    def __init__(self, store: JobStore, data_dir: Path, size: int):
        self.store = store
        self.data_dir = data_dir
        self.size = size
        self.ctx = multiprocessing.get_context("spawn")
        self.wake = self.ctx.Semaphore(0)
        self.stop_event = self.ctx.RawValue("b", 0)  # no lock: one byte written by the pool alone
        self.procs: list = []
        self._monitor: threading.Thread | None = None
        self._halt = threading.Event()
        self._cancel_seen: dict[str, float] = {}

    def _spawn(self):
        proc = self.ctx.Process(
            target=worker_main,
            args=(str(self.store.db_path), str(self.data_dir), self.wake, self.stop_event, os.getpid()),
            name="wandcal-worker",
            daemon=True,
        )
        proc.start()
        return proc

    def start(self) -> None:
        self.procs = [self._spawn() for _ in range(self.size)]
        self._monitor = threading.Thread(target=self._watch, name="wandcal-pool-monitor", daemon=True)
        self._monitor.start()

    def notify(self) -> None:
        """A job was queued: wake an idle worker (sem_post never blocks, whoever died)."""
        self.wake.release()

    def _watch(self) -> None:
        while not self._halt.wait(MONITOR_INTERVAL_S):
            self._enforce_cancellations()
            for i, proc in enumerate(self.procs):
                if proc.is_alive() or self._halt.is_set():
                    continue
                why = f"its worker process exited unexpectedly (exit code {proc.exitcode})"
                log_recovered(self.store.recover(why, [proc.pid]), why)
                self.procs[i] = self._spawn()

    def _enforce_cancellations(self) -> None:
        now = time.monotonic()
        pending = self.store.cancelling()
        self._cancel_seen = {j: self._cancel_seen.get(j, now) for j in pending}
        for job_id, pid in pending.items():
            if now - self._cancel_seen[job_id] > CANCEL_GRACE_S:
                for proc in self.procs:
                    if proc.pid == pid and proc.is_alive():
                        proc.kill()  # the monitor then records the job as cancelled and respawns

    def stop(self, grace_s: float = STOP_GRACE_S) -> None:
        """Stop the workers: idle ones leave at once, a busy one is given ``grace_s`` and then
        killed, its job queued again for the next start. Returns within about ``grace_s`` + 1 s."""
        deadline = time.monotonic() + grace_s
        self._halt.set()
        self.stop_event.value = 1
        for _ in self.procs:
            self.wake.release()
        if self._monitor is not None:
            self._monitor.join(grace_s)  # it may be replacing a worker: the new one sees the stop at once
        for proc in self.procs:
            proc.join(max(deadline - time.monotonic(), 0.0))
        for proc in self.procs:
            if proc.is_alive():
                proc.kill()
        for proc in self.procs:
            proc.join(1.0)
        pids = [p.pid for p in self.procs]
        if pids:
            why = "the server stopped while the job was running"
            log_recovered(self.store.recover(why, pids), why)


def log_recovered(jobs: list[JobRecord], why: str) -> None:
    """Every job a recovery queued again (or failed, past its attempts), in the service's log:
    "job ID: WHY: now queued (attempt 1 of 2)"."""
    for job in jobs:
        logging.getLogger("wandcal.service").warning(
            "job %s: %s: now %s (attempt %d of %d)%s", job.id, why, job.state.value, job.attempts, MAX_ATTEMPTS,
            f": {job.error}" if job.error else "")
