"""Service benchmark: frame-set ingest rate and the job latency beyond the solve itself.

Starts the real server (``wandcal serve``) on a loopback port and drives it over HTTP.
Run: ``python bench/bench_service.py [--framesets 40] [--jobs 5]``; writes the "Service"
section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import replace_section  # noqa: E402
from tests.service.conftest import Server, capture_files, free_port, server_env, wait_job  # noqa: E402
from wandcal.calib.sim.render import render_blobs  # noqa: E402
from wandcal.calib.sim.simulate import simulate_capture  # noqa: E402
from wandcal.capture.folder import rig_to_json, write_capture  # noqa: E402

CAMERAS = 8  # the figure: 8 x 1280x1024 PNG per frame set
SECTION = "## Service"


def frameset_payloads(sim, count: int) -> list[dict]:
    out = []
    rng = np.random.default_rng(0)
    for f in range(count):
        files = {}
        for i, cam in enumerate(sim.rig.cameras):
            uv = sim.wand.uv[(sim.wand.frame == f) & (sim.wand.camera == i)]
            image = render_blobs((cam.height, cam.width), uv, sigma_px=1.5, peak=200.0, noise=2.0, rng=rng)
            files[cam.id] = (f"{cam.id}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png")
        out.append(files)
    return out


def bench_ingest(server: Server, sim, count: int) -> dict:
    payloads = frameset_payloads(sim, count)
    png_bytes = statistics.mean(sum(len(v[1]) for v in p.values()) for p in payloads)
    with server.client() as c:
        rig = {"rig.json": ("rig.json", json.dumps(rig_to_json(sim.rig)).encode())}
        capture_id = c.post("/captures", files=rig).json()["id"]
        start = time.perf_counter()
        for f, files in enumerate(payloads):
            r = c.post(f"/captures/{capture_id}/framesets", data={"frame": str(f)}, files=files)
            r.raise_for_status()
        seconds = time.perf_counter() - start
        pairs = sum(cov["pairs"] for cov in c.get(f"/captures/{capture_id}").json()["coverage"])
    return {"framesets": count, "seconds": seconds, "rate": count / seconds, "png_mb": png_bytes / 1e6, "pairs": pairs}


def bench_jobs(server: Server, folder: Path, count: int) -> dict:
    overheads, solves, totals = [], [], []
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        for _ in range(count):
            start = time.perf_counter()
            job = c.post("/jobs", json={"capture_id": capture_id, "method": "ba"}).json()
            done = wait_job(c, job["id"])
            total = time.perf_counter() - start
            assert done["state"] == "done", done["error"]
            solve = server_solve_seconds(server, job["id"])
            totals.append(total)
            solves.append(solve)
            overheads.append(total - solve)
    return {
        "jobs": count, "total_median": statistics.median(totals), "solve_median": statistics.median(solves),
        "overhead_median": statistics.median(overheads), "overhead_max": max(overheads),
    }


def server_solve_seconds(server: Server, job_id: str) -> float:
    """The worker's own measurement of the solve (load + calibrate), from the job database."""
    import sqlite3

    db = Path(server.env["WANDCAL_DATA_DIR"]) / "wandcal.sqlite3"
    with sqlite3.connect(db) as conn:
        return conn.execute("SELECT solve_seconds FROM jobs WHERE id = ?", (job_id,)).fetchone()[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--framesets", type=int, default=40)
    parser.add_argument("--jobs", type=int, default=5)
    parser.add_argument("--no-write", action="store_true", help="print only; leave docs/benchmarks.md alone")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        (tmp / "replay").mkdir()
        server = Server(port=free_port(), env=server_env(tmp, workers=1, framesets_per_second=1000),
                        log=tmp / "server.log").start()
        try:
            sim8 = simulate_capture(cameras=CAMERAS, frames=args.framesets, seed=1)
            ingest = bench_ingest(server, sim8, args.framesets)
            sim4 = simulate_capture(cameras=4, frames=300, noise_px=0.3, seed=11)
            write_capture(tmp / "small", sim4.rig, sim4.wand, sim4.static)
            jobs = bench_jobs(server, tmp / "small", args.jobs)
        finally:
            server.stop()
    table = "\n".join([
        "| measure | value |",
        "|---|---|",
        f"| frame-set ingest, {CAMERAS} x 1280x1024 PNG ({ingest['png_mb']:.2f} MB per set), detection included "
        f"| {ingest['rate']:.1f} frame sets/s ({ingest['framesets']} sets in {ingest['seconds']:.1f} s) |",
        f"| job wall time, 4 cameras x 300 frames, method ba (median of {jobs['jobs']}) | {jobs['total_median']:.2f} s |",
        f"| of which the solve (load + calibrate, in the worker) | {jobs['solve_median']:.2f} s |",
        f"| overhead beyond the solve: queue, claim, HTTP polling at 50 ms (median / max) "
        f"| {jobs['overhead_median'] * 1000:.0f} ms / {jobs['overhead_max'] * 1000:.0f} ms |",
        "",
        f"Machine: {platform.machine()}, {platform.python_implementation()} {platform.python_version()}, "
        f"{__import__('os').cpu_count()} cores; one solver process; server and client on one host.",
    ])
    print(table)
    if not args.no_write:
        command = f"python bench/bench_service.py --framesets {args.framesets} --jobs {args.jobs}"
        replace_section(SECTION.removeprefix("## "), f"Command: `{command}`\n\n{table}")


if __name__ == "__main__":
    main()
