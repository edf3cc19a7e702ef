"""The chaos run: the documented Redis/rq deployment (docs/deploy.md) under worker kills, Redis
restarts, a Redis outage and an API restart; every accepted job must end exactly once.

    python bench/chaos.py                 # 300 jobs, 24 worker kills, 4 Redis restarts, 30 s away
    python bench/chaos.py --no-write      # print only; leave docs/benchmarks.md alone

What runs, all on loopback: a ``redis-server`` started here (append-only file, fsync always), the
API (``wandcal serve`` with ``queue = "redis"`` and no local solver), and ``rq worker`` processes,
each kept running by a supervisor here as systemd's ``Restart=always`` would (two of them from
another folder with no WANDCAL_* settings, as services on a second machine). A client submits tiny
captures' jobs (a 503 is retried after its Retry-After; only a 202 is an accepted job) and polls
every unfinished job, as the page does. Meanwhile:

- workers are SIGKILLed at random points: most often the work horse (the process solving a job,
  at a random moment of its solve or of its result's write), sometimes the whole worker with it;
- Redis is restarted: shut down (its data kept), SIGKILLed (kept: fsync always), and SIGKILLed
  with its data deleted, as a Redis without persistence loses everything;
- Redis is SIGSTOPped for ``--away`` seconds (it accepts connections and answers nothing): the run
  checks that the API meanwhile answers reads from SQLite and a 503 with Retry-After for a new job;
- the API is SIGKILLed and started again while jobs run.

At the end every job in the database (accepted or not) must be finished, each accepted job
exactly once: its first finished state and result never change afterwards, none is lost or stuck.
The rq workers' logs say how often a job's solve completed: more than once is the at-least-once
execution docs/reliability.md describes, never a second result.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import shutil
import sqlite3
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.chaos_processes import QUEUE, RedisServer, Workers, kill
from bench.common import write_section
from tests.service.conftest import REPO, Server, capture_files, free_port, server_env, simulated_capture

FINISHED = ("done", "failed", "cancelled")
# rq notices a worker that died with its machine when its heartbeat lapses (rq's job-monitoring
# interval, 30 s, plus 60 s) and the server's next poll cleans up (10 s): after the chaos, a job
# still unfinished when no job has finished for this long is stuck.
STALL_S = 150.0
HEARTBEAT_LAPSE_S = 30 + 60 + 30  # rq's job-monitoring interval, its 60 s to spare, and a margin
SETTLE_S = 1800.0  # and the run ends this long after the chaos whatever happens (a backlog on a slow machine)
POLL_S = 0.2  # the client's pause between rounds of polls of the unfinished jobs
LOG_WAIT_S = 10.0  # at the end, how long a solve still running is given to log its end
# The API's restart is waited for this long: a start imports the service and pings Redis, over a
# minute on 2 cores at a load average of 30 (seen: the restart outlived the tests' 60 s, and the run hung)
API_START_S = 600.0


@dataclass(frozen=True)
class Plan:
    """What the run does. ``worker_kills`` are spread over the submission; one in
    ``whole_worker_every`` kills the worker with its horse (0: horses only)."""

    jobs: int = 300
    workers: int = 3
    worker_kills: int = 24
    whole_worker_every: int = 4
    redis_restarts: tuple[str, ...] = ("shutdown", "sigkill", "lost", "shutdown")
    away_s: float = 30.0
    api_restarts: int = 1
    submit_s: float = 150.0  # the jobs are submitted over this long (the chaos happens meanwhile)
    settle_s: float = SETTLE_S
    stall_s: float = STALL_S
    # tests only: once the queue has stalled this long, rq's abandoned-job cleanup is run as if the
    # heartbeats had lapsed (90 s), as tests/service/test_redis.py does; None waits for the lapse
    lapse_after_s: float | None = None
    captures: int = 3
    seed: int = 34


@dataclass
class Report:
    accepted: list[str] = field(default_factory=list)
    refused: int = 0  # 503s (and connection errors while the API restarted) of POST /jobs, retried
    horse_kills: int = 0
    worker_kills: int = 0
    redis_restarts: list[str] = field(default_factory=list)
    api_restarts: int = 0
    away: dict = field(default_factory=dict)
    first_end: dict[str, tuple[str, str]] = field(default_factory=dict)  # job id: (state, result digest)
    final: dict[str, tuple[str, str]] = field(default_factory=dict)  # every row at the end, as the API answers it
    unaccepted_rows: int = 0  # rows of POSTs whose answer was lost (the API killed meanwhile)
    unaccepted_unfinished: int = 0
    errors: Counter = field(default_factory=Counter)
    solves: Counter = field(default_factory=Counter)  # job id: "Job OK" lines in the workers' logs
    seconds: float = 0.0

    @property
    def lost(self) -> list[str]:
        return [j for j in self.accepted if j not in self.final]

    @property
    def stuck(self) -> list[str]:
        return [j for j in self.accepted if j in self.final and self.final[j][0] not in FINISHED]

    @property
    def changed(self) -> list[str]:
        """Jobs whose outcome changed after it was first seen finished: a duplicate result. Every
        job polled counts, the rows of unanswered POSTs too (their end is compared with their own
        row's, not taken for a lost one)."""
        return [j for j, end in self.first_end.items() if self.final.get(j) != end]

    def states(self) -> Counter:
        return Counter(self.final[j][0] for j in self.accepted if j in self.final)

    @property
    def ok(self) -> bool:
        return not (self.lost or self.stuck or self.changed or self.unaccepted_unfinished) and bool(self.accepted)


def _digest(job: dict) -> str:
    return hashlib.sha256(json.dumps([job.get("result"), job.get("error")], sort_keys=True).encode()).hexdigest()[:16]


class Client:
    """Submits the jobs and polls the unfinished ones, recording each job's first finished state."""

    def __init__(self, server: Server, report: Report, capture_ids: list[str]):
        self.server, self.report, self.capture_ids = server, report, capture_ids
        self.unfinished: set[str] = set()
        self._lock = threading.Lock()

    def _http(self) -> httpx.Client:
        return httpx.Client(base_url=self.server.url + "/api/v1", timeout=30.0)

    def submit(self, count: int, over_s: float, halt: threading.Event) -> None:
        start = time.monotonic()
        with self._http() as c:
            for n in range(count):
                time.sleep(max(0.0, start + over_s * n / count - time.monotonic()))
                while not halt.is_set():
                    try:
                        answer = c.post("/jobs", json={"capture_id": self.capture_ids[n % len(self.capture_ids)],
                                                       "method": "ba", "options": {"use_static": True}})
                    except httpx.TransportError:
                        self.report.refused += 1
                        time.sleep(0.5)  # the API is restarting
                        continue
                    if answer.status_code == 202:
                        with self._lock:
                            self.report.accepted.append(answer.json()["id"])
                            self.unfinished.add(answer.json()["id"])
                        break
                    assert answer.status_code == 503, (answer.status_code, answer.text)
                    assert int(answer.headers["Retry-After"]) >= 1
                    self.report.refused += 1
                    time.sleep(min(float(answer.headers["Retry-After"]), 2.0))

    def poll(self, halt: threading.Event) -> None:
        with self._http() as c:
            while not halt.is_set():
                with self._lock:
                    ids = list(self.unfinished)
                for job_id in ids:
                    try:
                        answer = c.get(f"/jobs/{job_id}")
                    except httpx.TransportError:
                        time.sleep(0.5)
                        break
                    if answer.status_code != 200:
                        self.report.errors[f"GET /jobs/{{id}}: {answer.status_code}"] += 1
                        continue
                    job = answer.json()
                    if job["state"] in FINISHED:
                        with self._lock:
                            self.unfinished.discard(job_id)
                            self.report.first_end.setdefault(job_id, (job["state"], _digest(job)))
                time.sleep(POLL_S)


def _outage_probe(server: Server, report: Report, job_id: str | None) -> None:
    """While Redis is stopped: reads answer from SQLite, a new job gets 503 with Retry-After."""
    with httpx.Client(base_url=server.url + "/api/v1", timeout=30.0) as c:
        t0 = time.monotonic()
        read = c.get(f"/jobs/{job_id}") if job_id else c.get("/jobs")
        report.away["read"] = f"{read.status_code} in {time.monotonic() - t0:.1f} s"
        t0 = time.monotonic()
        listed = c.get("/jobs")
        report.away["list"] = f"{listed.status_code} in {time.monotonic() - t0:.1f} s"
        captures = c.get("/captures").json()["captures"]
        t0 = time.monotonic()
        new = c.post("/jobs", json={"capture_id": captures[0]["id"], "method": "ba"})
        report.away["submit"] = (f"{new.status_code} (Retry-After {new.headers.get('Retry-After')}) in "
                                 f"{time.monotonic() - t0:.1f} s")
        report.away["health"] = str(c.get("/health").status_code)
        report.away["ok"] = (read.status_code == 200 and listed.status_code == 200 and new.status_code == 503
                             and "Retry-After" in new.headers)


def _chaos(plan: Plan, rng: random.Random, redis: RedisServer, workers: Workers, server: Server, report: Report,
           client: Client, done: threading.Event) -> None:
    """The faults, spread over the submission: kills throughout, the rest at fixed fractions.
    ``done`` is set whatever happens; a fault that could not be made is counted in ``report.errors``."""
    events: list[tuple[float, str]] = [(plan.submit_s * (k + 0.5) / plan.worker_kills, "kill")
                                       for k in range(plan.worker_kills)]
    events += [(plan.submit_s * (k + 1) / (len(plan.redis_restarts) + 2), f"redis:{how}")
               for k, how in enumerate(plan.redis_restarts)]
    events += [(plan.submit_s * 0.5, "away")] if plan.away_s > 0 else []
    events += [(plan.submit_s * (k + 0.3) / max(plan.api_restarts, 1), "api") for k in range(plan.api_restarts)]
    start = time.monotonic()
    kills = 0
    try:
        for at, what in sorted(events):
            time.sleep(max(0.0, start + at - time.monotonic()))
            if what == "kill":
                kills += 1
                _kill_a_worker(rng, workers, report, whole=plan.whole_worker_every > 0
                               and kills % plan.whole_worker_every == 0)
            elif what.startswith("redis:"):
                redis.restart(what.partition(":")[2])
                report.redis_restarts.append(what.partition(":")[2])
            elif what == "away":
                with client._lock:
                    some = next(iter(client.unfinished), None) or (report.accepted[0] if report.accepted else None)
                redis.pause(plan.away_s, during=lambda: _outage_probe(server, report, some))
            elif what == "api":
                server.kill()
                server.start(timeout_s=API_START_S)
                report.api_restarts += 1
    except Exception as exc:  # the run goes on to its audit, which then fails on this
        report.errors[f"chaos: {type(exc).__name__}: {str(exc).splitlines()[0]}"] += 1
    finally:
        done.set()


def _kill_a_worker(rng: random.Random, workers: Workers, report: Report, whole: bool) -> None:
    """SIGKILL a busy work horse (and with ``whole`` its worker first) at a random moment of its job."""
    deadline = time.monotonic() + 10
    while (busy := workers.busy_horse(rng)) is None and time.monotonic() < deadline:
        time.sleep(0.02)
    if busy is None:
        return
    time.sleep(rng.uniform(0.0, 0.3))  # somewhere in the solve or the write of its result
    worker, horse = busy
    if whole:
        worker.kill()  # first, so that it cannot see its horse die and handle that itself
        report.worker_kills += 1
    else:
        report.horse_kills += 1
    kill(horse)


def upload_captures(server: Server, folder: Path, count: int) -> list[str]:
    """``count`` tiny captures (3 cameras, 120 frames: a solve well under a second), uploaded."""
    ids = []
    with server.client() as c:
        for k in range(count):
            capture, _ = simulated_capture(folder / f"capture{k}", cameras=3, frames=120, noise_px=0.3, seed=100 + k)
            answer = c.post("/captures", files=capture_files(capture))
            answer.raise_for_status()
            ids.append(answer.json()["id"])
    return ids


def _lapse_heartbeats(url: str) -> None:
    """rq's abandoned-job cleanup as a worker's maintenance runs it once the heartbeats have lapsed,
    and the server's return of jobs a worker took and never started as it runs after a minute."""
    from redis import Redis
    from rq import Queue
    from rq.registry import StartedJobRegistry

    from wandcal.service.jobs.redis_queue import requeue_untaken

    StartedJobRegistry(QUEUE, connection=Redis.from_url(url)).cleanup(timestamp=time.time() + HEARTBEAT_LAPSE_S)
    requeue_untaken(Queue(QUEUE, connection=Redis.from_url(url)), lapsed=True)  # and a job taken, never started


def _audit(db: Path, server: Server, report: Report) -> None:
    """Every row of the database at the end, read as a client reads it (GET /jobs/{id}: the digest
    then covers the same text as the polls', the error's paths made relative to the data folder)."""
    with sqlite3.connect(db) as conn:
        rows = dict(conn.execute("SELECT id, state FROM jobs").fetchall())
    accepted = set(report.accepted)
    with server.client() as c:
        for job_id, stored in rows.items():
            job = c.get(f"/jobs/{job_id}").json()
            if job["state"] != stored:
                report.errors[f"GET /jobs/{{id}} answered {job['state']}, the database holds {stored}"] += 1
            report.final[job_id] = (job["state"], _digest(job))
            if job_id not in accepted:
                report.unaccepted_rows += 1
                report.unaccepted_unfinished += job["state"] not in FINISHED


def run(plan: Plan, folder: Path) -> Report:
    """Run ``plan`` in ``folder`` (everything it starts is stopped before it returns)."""
    rng = random.Random(plan.seed)
    report = Report()
    started = time.monotonic()
    redis = RedisServer(folder / "redis", free_port())
    redis.start()
    (folder / "replay").mkdir(parents=True, exist_ok=True)
    env = server_env(folder, queue="redis", redis_url=redis.url, redis_queue_name=QUEUE, workers=0)
    env["PYTHONPATH"] = str(REPO)
    server = Server(port=free_port(), env=env, log=folder / "server.log")
    workers = Workers(redis.url, plan.workers, env, folder)
    halt, chaos_done = threading.Event(), threading.Event()
    threads: list[threading.Thread] = []
    try:
        server.start()
        capture_ids = upload_captures(server, folder / "captures", plan.captures)
        workers.start()
        client = Client(server, report, capture_ids)
        threads = [threading.Thread(target=client.submit, args=(plan.jobs, plan.submit_s, halt), daemon=True),
                   threading.Thread(target=client.poll, args=(halt,), daemon=True),
                   threading.Thread(target=_chaos, args=(plan, rng, redis, workers, server, report, client, chaos_done),
                                    daemon=True)]
        for t in threads:
            t.start()
        threads[0].join()
        chaos_done.wait()
        # the jobs of POSTs whose answer a kill of the API cut off: a page listing the jobs polls them too
        with sqlite3.connect(Path(env["WANDCAL_DATA_DIR"]) / "wandcal.sqlite3") as conn:
            unanswered = {r[0] for r in conn.execute("SELECT id FROM jobs WHERE state IN ('queued', 'running')")}
        with client._lock:
            client.unfinished |= unanswered - set(report.accepted)
        deadline = time.monotonic() + plan.settle_s
        last, progress, lapsed = -1, time.monotonic(), False
        while time.monotonic() < min(deadline, progress + plan.stall_s):
            with client._lock:
                left = len(client.unfinished)
            if not left:
                break
            if left != last:
                last, progress, lapsed = left, time.monotonic(), False
            if plan.lapse_after_s is not None and not lapsed and time.monotonic() - progress > plan.lapse_after_s:
                _lapse_heartbeats(redis.url)
                lapsed = True
            time.sleep(POLL_S)
        halt.set()
        for t in threads:
            t.join(30)
        workers.wait_idle(LOG_WAIT_S)  # a solve still running (a re-run): its end goes into the logs
        _audit(Path(env["WANDCAL_DATA_DIR"]) / "wandcal.sqlite3", server, report)
    finally:
        halt.set()
        workers.stop()
        server.kill()
        redis.stop()
    report.solves = workers.solves()
    report.seconds = time.monotonic() - started
    return report


def table(plan: Plan, report: Report) -> str:
    states = report.states()
    twice = sum(1 for j in report.accepted if report.solves[j] > 1)
    rows = [
        ("jobs accepted (202)", f"{len(report.accepted)} (goal >= 300)" if plan.jobs >= 300 else str(len(report.accepted))),
        ("POST /jobs refused (503, or the API restarting) and retried", str(report.refused)),
        ("worker kills: work horse / whole worker", f"{report.horse_kills} / {report.worker_kills} "
         f"(goal >= 20 in all)" if plan.worker_kills >= 20 else f"{report.horse_kills} / {report.worker_kills}"),
        ("Redis restarts", f"{len(report.redis_restarts)}: {', '.join(report.redis_restarts)}"),
        (f"Redis stopped (SIGSTOP) {plan.away_s:g} s: read / list / new job / health",
         " / ".join(str(report.away.get(k, "-")) for k in ("read", "list", "submit", "health"))),
        ("API restarts (SIGKILL, start)", str(report.api_restarts)),
        ("finished: done / failed / cancelled", f"{states['done']} / {states['failed']} / {states['cancelled']}"),
        ("lost / stuck / outcome changed after it was seen", f"{len(report.lost)} / {len(report.stuck)} / "
         f"{len(report.changed)} (goal 0 / 0 / 0)"),
        ("jobs solved more than once (at-least-once execution; one result kept)", str(twice)),
        ("rows of unanswered POSTs, unfinished", f"{report.unaccepted_rows}, {report.unaccepted_unfinished}"),
        ("unexpected answers while polling", ", ".join(f"{k} x{v}" for k, v in report.errors.items()) or "none"),
        ("wall time", f"{report.seconds:.0f} s"),
    ]
    lines = ["| | |", "|---|---|"] + [f"| {a} | {b} |" for a, b in rows]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=Plan.jobs)
    parser.add_argument("--kills", type=int, default=Plan.worker_kills)
    parser.add_argument("--away", type=float, default=Plan.away_s, help="seconds Redis is stopped")
    parser.add_argument("--submit-s", type=float, default=Plan.submit_s)
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it (logs, database)")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    if shutil.which("redis-server") is None:
        sys.exit("chaos: redis-server is not installed (apt-get install redis-server)")
    plan = Plan(jobs=args.jobs, worker_kills=args.kills, away_s=args.away, submit_s=args.submit_s)
    load = os.getloadavg()[0]
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        report = run(plan, args.keep)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            report = run(plan, Path(tmp))
    text = (table(plan, report) + f"\n\n`python bench/chaos.py` (seed {plan.seed}); {plan.workers} rq workers, "
            f"load average {load:.1f} at the start on {os.cpu_count()} cores.")
    print(text)
    if report.stuck or report.lost or report.changed:
        print("stuck:", report.stuck[:10], "lost:", report.lost[:10], "changed:", report.changed[:10])
    if not args.no_write:
        write_section("Chaos", text)
    sys.exit(0 if report.ok else 1)


if __name__ == "__main__":
    main()
