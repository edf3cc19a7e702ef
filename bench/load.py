"""Load on the real server over loopback: concurrent uploads, jobs and frame-set streams, each
bounded in count, and what they measure (throughput, latency percentiles, the server's peak
memory) and check (every acknowledged request's data is stored, nothing is lost).

Used by ``bench/bench_load.py`` (the "Load" section of docs/benchmarks.md) and by
``tests/reliability/test_load.py`` (the same runs, small, in CI).
"""

from __future__ import annotations

import statistics
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import httpx
import numpy as np

from wandcal.calib.sim.render import render_blobs

REQUEST_TIMEOUT_S = 120.0  # a request queued behind a full server still gets its answer


@dataclass
class Run:
    """One load run: per-request latencies (s), its wall time (s), and what it checked."""

    what: str
    latencies: list[float] = field(default_factory=list)
    seconds: float = 0.0
    lost: int = 0
    statuses: dict[int, int] = field(default_factory=dict)
    sets: int = 0  # frame sets carried, where a request carries many (blob sets)

    @property
    def count(self) -> int:
        return len(self.latencies)

    def percentile(self, q: float) -> float:
        return float(np.percentile(self.latencies, q)) if self.latencies else float("nan")

    @property
    def rate(self) -> float:
        """Requests a second, or frame sets a second where a request carries many."""
        return (self.sets or self.count) / self.seconds if self.seconds else float("nan")

    def row(self, unit: str) -> str:
        return (f"| {self.what} | {self.count} | {self.rate:.1f} {unit}/s | {1000 * self.percentile(50):.0f} ms | "
                f"{1000 * self.percentile(99):.0f} ms | {self.lost} |")


def _timed(run: Run, lock: threading.Lock, send) -> httpx.Response:
    start = time.perf_counter()
    r = send()
    with lock:
        run.latencies.append(time.perf_counter() - start)
        run.statuses[r.status_code] = run.statuses.get(r.status_code, 0) + 1
    return r


def concurrent_uploads(client: httpx.Client, files: dict, count: int, concurrency: int) -> tuple[Run, list[dict]]:
    """``count`` uploads of the capture ``files``, ``concurrency`` at a time; then every answered
    capture is read back: a 201 whose capture is missing or differs counts as lost."""
    run, lock = Run(f"upload, {concurrency} at a time"), threading.Lock()
    start = time.perf_counter()
    with ThreadPoolExecutor(concurrency) as pool:
        answers = list(pool.map(lambda _: _timed(run, lock, lambda: client.post("/captures", files=files)),
                                range(count)))
    run.seconds = time.perf_counter() - start
    made = [a.json() for a in answers if a.status_code == 201]
    listed = {c["id"]: c for c in client.get("/captures", params={}).json()["captures"]}
    for capture in made:
        stored = listed.get(capture["id"]) or client.get(f"/captures/{capture['id']}").json()
        run.lost += stored.get("frames") != capture["frames"] or stored.get("coverage") != capture["coverage"]
    run.lost += count - len(made) - sum(n for s, n in run.statuses.items() if s in (413, 429, 503, 507))
    return run, made


def concurrent_jobs(client: httpx.Client, capture_ids: list[str], count: int, concurrency: int,
                    timeout_s: float) -> tuple[Run, list[dict]]:
    """``count`` jobs submitted ``concurrency`` at a time, each followed until it ends; latency is
    submit to done. A job that does not end done, or whose result lacks a camera, is lost."""
    run, lock = Run(f"job (submit to done), {concurrency} submitted at a time"), threading.Lock()

    def one(k: int) -> dict:
        start = time.perf_counter()
        job = client.post("/jobs", json={"capture_id": capture_ids[k % len(capture_ids)], "method": "ba"}).json()
        deadline = start + timeout_s
        while time.perf_counter() < deadline:
            job = client.get(f"/jobs/{job['id']}").json()
            if job["state"] in ("done", "failed", "cancelled"):
                break
            time.sleep(0.05)
        with lock:
            run.latencies.append(time.perf_counter() - start)
        return job

    start = time.perf_counter()
    with ThreadPoolExecutor(concurrency) as pool:
        jobs = list(pool.map(one, range(count)))
    run.seconds = time.perf_counter() - start
    run.lost = sum(j["state"] != "done" or not j.get("result") or len(j["result"]["cameras"]) == 0 for j in jobs)
    return run, jobs


def frameset_pool(sim, count: int, seed: int = 0) -> list[tuple[dict, dict[str, np.ndarray]]]:
    """``count`` rendered frame sets of the simulated capture ``sim``: (multipart files, the true
    blob centres per camera). Rendering is done before any timing."""
    rng = np.random.default_rng(seed)
    out = []
    for f in range(count):
        files, truth = {}, {}
        for i, cam in enumerate(sim.rig.cameras):
            uv = sim.wand.uv[(sim.wand.frame == f) & (sim.wand.camera == i)]
            image = render_blobs((cam.height, cam.width), uv, sigma_px=1.5, peak=200.0, noise=2.0, rng=rng)
            files[cam.id] = (f"{cam.id}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png")
            truth[cam.id] = uv
        out.append((files, truth))
    return out


def stream_framesets(client: httpx.Client, capture_id: str, pool: list, count: int, concurrency: int,
                     rate_hz: float | None = None) -> Run:
    """Stream ``count`` frame sets (the pool's, cycled, frame numbers 0..count-1) into a capture,
    ``concurrency`` requests in flight, paced at ``rate_hz`` if given. Then every acknowledged
    frame set must be stored: the capture's frame-set count and wand pairs per camera must match
    what the acknowledged answers reported."""
    run, lock = Run(f"frame set, {concurrency} in flight" + (f", paced at {rate_hz:g}/s" if rate_hz else "")),\
        threading.Lock()
    acknowledged: list[dict] = []
    start = time.perf_counter()

    def one(f: int) -> None:
        if rate_hz:
            delay = start + f / rate_hz - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        files = pool[f % len(pool)][0]
        r = _timed(run, lock, lambda: client.post(f"/captures/{capture_id}/framesets", data={"frame": str(f)},
                                                  files=files))
        if r.status_code == 201:
            with lock:
                acknowledged.append(r.json())

    with ThreadPoolExecutor(concurrency) as pool_:
        list(pool_.map(one, range(count)))
    run.seconds = time.perf_counter() - start
    stored = client.get(f"/captures/{capture_id}").json()
    pairs = {}
    for a in acknowledged:
        for cam in a["wand_cameras"]:
            pairs[cam] = pairs.get(cam, 0) + 1
    run.lost = (count - len(acknowledged)) + abs(stored["framesets"] - len(acknowledged)) + sum(
        abs(cov["pairs"] - pairs.get(cov["id"], 0)) for cov in stored["coverage"])
    return run


def blob_set_batches(sim, count: int, batch: int) -> list[list[dict]]:
    """``count`` frame sets of ``sim`` as the blob-set requests' JSON, ``batch`` sets a request
    (frame numbers 0..count-1, the simulated frames cycled). Built before any timing."""
    ids, w = sim.rig.ids, sim.wand
    frames = int(w.frame.max()) + 1
    per_frame: list[dict] = [{} for _ in range(frames)]
    for f, cam, uv in zip(w.frame.tolist(), w.camera.tolist(), w.uv.tolist()):
        per_frame[f].setdefault(ids[cam], []).append(uv)
    sets = [{"frame": f, "blobs": per_frame[f % frames]} for f in range(count)]
    return [sets[k:k + batch] for k in range(0, count, batch)]


def stream_blobsets(client: httpx.Client, capture_id: str, batches: list[list[dict]], concurrency: int,
                    rate_hz: float | None = None) -> Run:
    """Post the batches (``concurrency`` in flight, paced so that ``rate_hz`` frame sets a second
    go out, if given); then every acknowledged set must be stored, as in :func:`stream_framesets`.
    The Run counts frame sets, not requests: its latencies are per request."""
    size = len(batches[0])
    run = Run(f"blob sets, {size} a request, {concurrency} in flight" + (f", paced at {rate_hz:g}/s" if rate_hz else ""))
    lock, acknowledged = threading.Lock(), []
    start = time.perf_counter()

    def one(k: int) -> None:
        if rate_hz:
            delay = start + k * size / rate_hz - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        r = _timed(run, lock, lambda: client.post(f"/captures/{capture_id}/blobsets", json={"sets": batches[k]}))
        if r.status_code == 201:
            with lock:
                acknowledged.append(r.json())

    with ThreadPoolExecutor(concurrency) as pool_:
        list(pool_.map(one, range(len(batches))))
    run.seconds = time.perf_counter() - start
    sent = sum(map(len, batches))
    stored = client.get(f"/captures/{capture_id}").json()
    stored_sets = sum(a["stored"] for a in acknowledged)
    wand_rows = sum(a["wand_rows"] for a in acknowledged)
    run.lost = (sent - stored_sets) + abs(stored["framesets"] - stored_sets) + abs(
        2 * sum(cov["pairs"] for cov in stored["coverage"]) - wand_rows)
    run.sets = sent
    return run


def peak_rss_mb(pid: int) -> float:
    """A process's peak resident set (VmHWM), MB (Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def children(pid: int) -> list[int]:
    """The process's direct children (the solver workers), from /proc."""
    path = Path(f"/proc/{pid}/task/{pid}/children")
    return [int(p) for p in path.read_text().split()] if path.exists() else []


def median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")
