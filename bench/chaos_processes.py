"""The processes of the chaos run (bench/chaos.py): ``redis-server`` with its append-only file, and
the ``rq worker`` processes, each restarted when it dies, with the means to stop, kill and freeze them.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

QUEUE = "wandcal"
# workers 1, 2, ... load the solver once (docs/deploy.md); worker 0 is the plain `rq worker`
PRELOADED = ("-w", "wandcal.service.jobs.rq_worker.Worker")
REDIS_START_S = 20.0  # a fresh redis-server answers PING within milliseconds; an AOF replay takes longer


class RedisServer:
    """``redis-server`` on a loopback port, with its append-only file fsynced at every write."""

    def __init__(self, folder: Path, port: int):
        self.folder, self.port = folder, port
        self.url = f"redis://127.0.0.1:{port}/0"
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        with open(self.folder / "redis.log", "ab") as log:  # the child keeps its own descriptor
            self.proc = subprocess.Popen(
                ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--dir", str(self.folder),
                 "--appendonly", "yes", "--appendfsync", "always", "--save", ""],
                stdout=log, stderr=subprocess.STDOUT,
            )
        from redis import Redis

        deadline = time.monotonic() + REDIS_START_S
        while True:
            try:
                Redis.from_url(self.url, socket_timeout=1).ping()
                return
            except Exception:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise RuntimeError(f"redis-server did not start: {(self.folder / 'redis.log').read_text()[-2000:]}") from None
                time.sleep(0.05)

    def restart(self, how: str) -> None:
        """``shutdown``: SIGTERM (it writes its data); ``sigkill``: its data kept on disk; ``lost``:
        SIGKILL and its files deleted, as a Redis without persistence comes back empty."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGTERM if how == "shutdown" else signal.SIGKILL)
        self.proc.wait(30)
        if how == "lost":
            for leftover in self.folder.iterdir():
                if leftover.name != "redis.log":
                    shutil.rmtree(leftover) if leftover.is_dir() else leftover.unlink()
        self.start()

    def pause(self, seconds: float, during=None) -> None:
        """SIGSTOP for ``seconds``: connections are accepted and nothing is answered. ``during()`` runs
        once it is stopped."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGSTOP)
        end = time.monotonic() + seconds
        try:
            if during is not None:
                during()
            time.sleep(max(0.0, end - time.monotonic()))
        finally:
            self.proc.send_signal(signal.SIGCONT)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.kill()
            self.proc.wait(10)


class Workers:
    """``rq worker`` processes, each restarted when it dies (systemd's ``Restart=always``)."""

    def __init__(self, url: str, count: int, env: dict, folder: Path):
        self.url, self.env, self.folder = url, env, folder
        self.procs: list[subprocess.Popen | None] = [None] * count
        self._halt = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._supervise, daemon=True)

    def _spawn(self, i: int) -> subprocess.Popen:
        # worker 0 beside the API; the others as services of another machine: own folder, no WANDCAL_* settings
        home = self.folder / f"worker{i}"
        home.mkdir(parents=True, exist_ok=True)
        env = self.env if i == 0 else {k: v for k, v in self.env.items() if not k.startswith("WANDCAL_")}
        return subprocess.Popen(
            [sys.executable, "-m", "rq.cli", "worker", *(PRELOADED if i else ()), "--url", self.url,
             "--name", f"chaos-{i}-{time.time_ns()}", QUEUE],
            cwd=home, env=env, stdout=open(home / "worker.log", "ab"), stderr=subprocess.STDOUT,
        )

    def start(self) -> None:
        with self._lock:
            self.procs = [self._spawn(i) for i in range(len(self.procs))]
        self._thread.start()

    def _supervise(self) -> None:
        while not self._halt.wait(0.5):
            with self._lock:
                for i, proc in enumerate(self.procs):
                    if proc is not None and proc.poll() is not None:
                        self.procs[i] = self._spawn(i)

    def busy_horse(self, rng: random.Random) -> tuple[subprocess.Popen, int] | None:
        """A worker and the pid of its work horse, for a worker that is running a job now."""
        with self._lock:
            procs = [p for p in self.procs if p is not None and p.poll() is None]
        rng.shuffle(procs)
        tree = children()
        for proc in procs:
            for pid in tree.get(proc.pid, []):
                return proc, pid
        return None

    def wait_idle(self, timeout_s: float) -> None:
        """Until no worker runs a job (or ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while self.busy_horse(random.Random(0)) is not None and time.monotonic() < deadline:
            time.sleep(0.05)

    def stop(self) -> None:
        self._halt.set()
        self._thread.join(5)
        with self._lock:
            for proc in self.procs:
                if proc is not None and proc.poll() is None:
                    proc.kill()
                    proc.wait(10)
            for horse in (pid for p in self.procs if p for pid in children().get(p.pid, [])):
                kill(horse)

    def solves(self) -> Counter:
        """Per job id, the solves that completed ("Job OK" in the workers' logs)."""
        count: Counter = Counter()
        for log in self.folder.glob("worker*/worker.log"):
            for line in log.read_text(errors="replace").splitlines():
                if "Job OK" in line and line.rstrip().endswith(")"):
                    count[line.rstrip()[:-1].rpartition("(")[2]] += 1
        return count


def children() -> dict[int, list[int]]:
    """{parent pid: [child pids]} from /proc."""
    out: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rpartition(")")[2].split()
        except OSError:
            continue
        out.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    return out


def kill(pid: int) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.kill(pid, signal.SIGKILL)
