"""The soak: many tiny jobs through one server and its local solver processes, sampling what could
creep (resident memory, open descriptors, threads, the database's size, the data folder's disk use).

    python bench/soak.py                      # 10,000 tiny jobs (about 40 minutes on 2 cores not shared)
    python bench/soak.py --minutes 50         # as many as fit in 50 minutes on a busy machine
    python bench/soak.py --jobs 1000          # what fits; the table says how many ran
    python bench/soak.py --no-write           # print only; leave docs/benchmarks.md alone

Goals (issue 34): after the warm-up (the first ``--warmup`` of the jobs), resident memory grows by
at most 10 %, and descriptors and threads stay flat. The database grows by each job's record
(about 10 kB with its result) unless a retention period is set (docs/reliability.md, "Retention").
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import write_section
from tests.service.conftest import Server, capture_files, free_port, server_env, simulated_capture

IN_FLIGHT = 16  # jobs queued ahead of the solvers: enough to keep both busy, few enough to poll cheaply
GROWTH_GOAL = 0.10  # issue 34: memory growth after warm-up
# The jobs are tiny so that 10,000 fit in about 40 minutes on 2 shared cores: the soak looks for
# what creeps per job (records, descriptors, threads, memory), not at solver time. 2 cameras and 60
# frames, with no second solve after outlier rejection: 0.06 CPU-s a solve against 0.12 for
# 3 x 120 with it, and every job still runs the whole pipeline and writes a whole result.
TINY_CAMERAS = 2
TINY_FRAMES = 60
TINY_OPTIONS = {"reject_outliers": False}
POLL_S = 0.1  # the client's pause between polls of the oldest unfinished job (each poll costs the server a request)


@dataclass(frozen=True)
class Sample:
    jobs: int  # finished so far
    seconds: float
    rss_mb: float  # the server's resident set
    workers_rss_mb: float  # its solver processes', summed
    fds: int  # the server's open descriptors plus its solvers'
    threads: int  # the same, threads
    db_mb: float  # wandcal.sqlite3
    wal_mb: float  # its -wal (reused after each checkpoint: bounded by SQLite's 1000-page auto-checkpoint)
    disk_mb: float  # the whole data folder


def _status(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0


def _children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rpartition(")")[2].split()[1]) == pid:
                out.append(int(stat.parent.name))
        except (OSError, ValueError):
            continue
    return out


def _folder_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def sample(server: Server, data: Path, jobs: int, start: float) -> Sample:
    pid = server.proc.pid
    procs = [pid, *_children(pid)]
    fds = threads = 0
    for p in procs:
        try:
            fds += len(os.listdir(f"/proc/{p}/fd"))
            threads += _status(p, "Threads")
        except OSError:
            continue
    db, wal = ((data / n).stat().st_size if (data / n).exists() else 0 for n in ("wandcal.sqlite3", "wandcal.sqlite3-wal"))
    workers_rss = sum(_status(p, "VmRSS") for p in procs[1:] if Path(f"/proc/{p}").exists())
    return Sample(jobs, time.monotonic() - start, _status(pid, "VmRSS") / 1024, workers_rss / 1024, fds, threads,
                  db / 1e6, wal / 1e6, _folder_mb(data))


def soak(server: Server, data: Path, capture_ids: list[str], jobs: int, every: int,
         minutes: float | None = None) -> list[Sample]:
    """Submit ``jobs`` jobs, ``IN_FLIGHT`` at a time, polling each to its end; a sample every
    ``every`` and one at the end. After ``minutes`` no more are submitted: the ones in flight
    finish and the run ends with what it did (on a machine too busy for the whole soak)."""
    start = time.monotonic()
    stop_at = start + minutes * 60 if minutes else float("inf")
    samples = [sample(server, data, 0, start)]
    pending: list[str] = []
    finished = submitted = 0
    with server.client() as c:
        while pending or (submitted < jobs and time.monotonic() < stop_at):
            while submitted < jobs and len(pending) < IN_FLIGHT and time.monotonic() < stop_at:
                answer = c.post("/jobs", json={"capture_id": capture_ids[submitted % len(capture_ids)], "method": "ba",
                                               "options": TINY_OPTIONS})
                answer.raise_for_status()
                pending.append(answer.json()["id"])
                submitted += 1
            job = c.get(f"/jobs/{pending[0]}").json()
            if job["state"] not in ("done", "failed", "cancelled"):
                time.sleep(POLL_S)
                continue
            assert job["state"] == "done", job["error"]
            pending.pop(0)
            finished += 1
            if finished % every == 0 or not (pending or (submitted < jobs and time.monotonic() < stop_at)):
                samples.append(sample(server, data, finished, start))
                _print(samples[-1])
    return samples


def _print(s: Sample) -> None:
    print(f"{s.jobs:6d} jobs {s.seconds:7.0f} s  server {s.rss_mb:6.1f} MB  solvers {s.workers_rss_mb:6.1f} MB"
          f"  fds {s.fds:4d}  threads {s.threads:3d}  db {s.db_mb:6.1f} + {s.wal_mb:4.1f} MB  disk {s.disk_mb:6.1f} MB",
          flush=True)


def table(samples: list[Sample], warm: Sample, jobs_goal: int) -> str:
    last = samples[-1]
    growth = last.rss_mb / warm.rss_mb - 1
    workers_growth = last.workers_rss_mb / warm.workers_rss_mb - 1
    per_job_kb = (last.db_mb - warm.db_mb) * 1e3 / max(last.jobs - warm.jobs, 1)
    rate = last.jobs / last.seconds
    rows = [
        "| jobs finished | seconds | server RSS (MB) | solvers' RSS (MB) | descriptors | threads | database + WAL (MB) | data folder (MB) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    picks = sorted({0, 1, *range(0, len(samples), max(1, len(samples) // 8)), len(samples) - 1})
    rows += [f"| {s.jobs} | {s.seconds:.0f} | {s.rss_mb:.1f} | {s.workers_rss_mb:.1f} | {s.fds} | {s.threads} | "
             f"{s.db_mb:.1f} + {s.wal_mb:.1f} | {s.disk_mb:.1f} |" for s in (samples[i] for i in picks)]
    fds = [s.fds for s in samples[1:]]
    threads = [s.threads for s in samples[1:]]
    summary = [
        "",
        f"Jobs run: {last.jobs} of the goal's {jobs_goal:,} ({rate:.2f} jobs/s; {jobs_goal:,} would take "
        f"{jobs_goal / rate / 3600:.1f} h at this rate)." if last.jobs < jobs_goal else f"Jobs run: {last.jobs:,}.",
        f"Memory after the warm-up ({warm.jobs} jobs): server {warm.rss_mb:.1f} -> {last.rss_mb:.1f} MB "
        f"({growth:+.1%}), solvers {warm.workers_rss_mb:.1f} -> {last.workers_rss_mb:.1f} MB ({workers_growth:+.1%}); "
        f"goal <= +{GROWTH_GOAL:.0%}.",
        f"Descriptors {min(fds)}-{max(fds)}, threads {min(threads)}-{max(threads)} over every sample after the first job.",
        f"Database: {per_job_kb:.1f} kB a job after the warm-up (every record and result is kept: the default "
        f"retention); its WAL at most {max(s.wal_mb for s in samples):.1f} MB (reused after each checkpoint).",
    ]
    return "\n".join(rows + summary)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=10_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--samples", type=int, default=40)
    parser.add_argument("--warmup", type=float, default=0.1, help="fraction of the jobs before the reference sample")
    parser.add_argument("--frames", type=int, default=TINY_FRAMES, help="frames of each tiny capture")
    parser.add_argument("--minutes", type=float, help="submit no more after this long; the table says how many ran")
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(scratch)
        (tmp / "replay").mkdir()
        server = Server(port=free_port(), env=server_env(tmp, workers=args.workers), log=tmp / "server.log").start()
        try:
            with server.client() as c:
                ids = []
                for k in range(3):
                    capture, _ = simulated_capture(tmp / f"capture{k}", cameras=TINY_CAMERAS, frames=args.frames,
                                                   noise_px=0.3, seed=100 + k)
                    ids.append(c.post("/captures", files=capture_files(capture)).json()["id"])
            samples = soak(server, tmp / "data", ids, args.jobs, max(1, args.jobs // args.samples), args.minutes)
        finally:
            server.stop()
    warm = min(samples[1:], key=lambda s: abs(s.jobs - args.warmup * samples[-1].jobs))
    text = (table(samples, warm, 10_000) + f"\n\n{args.workers} solver processes; 3 tiny captures ({TINY_CAMERAS} cameras, {args.frames} "
            f"frames, options {TINY_OPTIONS}), {IN_FLIGHT} jobs in flight; load average {load:.1f} at the start on {os.cpu_count()} cores.")
    print(text)
    if not args.no_write:
        write_section("Soak", text)


if __name__ == "__main__":
    main()
