"""`POST /captures/{id}/check` against `wandcal check`: is the check bounded enough to answer at once
(docs/decisions/0043-check-over-http.md)?

Simulated ring rigs (`wandcal simulate --shape ring`, 0.3 px, L-frame, seed 1) calibrated by
`wandcal calibrate`; then the result checked against its own capture: `wandcal check` as a whole
process (wall seconds, Python's start-up included), and the route in-process (`TestClient`,
no workers) with the result posted, each request's wall and CPU seconds (the route's thread
included: body parsing, reading the stored capture, the check). CPU beside wall because the
machine is shared.

Usage: python bench/bench_check_http.py [--cameras 16,128] [--frames 3000] [--repeats 3] [--no-write]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish
from bench.whole_process import simulate

TITLE = "Check over HTTP"


def _wandcal(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "wandcal.service.cli", *argv], capture_output=True, text=True, check=False)


def one_rig(cameras: int, frames: int, repeats: int) -> str:
    """One table row: the rig, the CLI's exit and wall seconds, the route's exit code and its runs."""
    from fastapi.testclient import TestClient

    from wandcal.service.main import create_app
    from wandcal.service.settings import Settings

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "capture"
        simulate(folder, cameras, frames, shape="ring")
        done = _wandcal("calibrate", str(folder), "--quiet")
        if done.returncode:
            return f"| {cameras} x {frames} | calibrate refused: {done.stderr.strip().splitlines()[-1]} | | | | |"
        started = time.perf_counter()
        cli = _wandcal("check", str(folder / "result.json"), str(folder))
        cli_wall = time.perf_counter() - started
        doc = json.loads((folder / "result.json").read_text())
        app = create_app(Settings(data_dir=Path(tmp) / "data", workers=0))
        with TestClient(app, base_url="http://127.0.0.1/api/v1") as client:
            names = [n for n in ("rig.json", "wand.csv", "static.csv") if (folder / n).is_file()]
            capture_id = client.post("/captures", files={n: (n, (folder / n).read_bytes()) for n in names}).json()["id"]
            runs = []
            for _ in range(repeats):
                wall, cpu = time.perf_counter(), time.process_time()
                answer = client.post(f"/captures/{capture_id}/check", json={"result": doc})
                runs.append((time.perf_counter() - wall, time.process_time() - cpu))
        walls, cpus = sorted(w for w, _ in runs), sorted(c for _, c in runs)
        return (f"| {cameras} x {frames} | {cli.returncode}, {cli_wall:.2f} | {answer.json().get('exit_code')} | "
                f"{cpus[len(cpus) // 2]:.2f} ({', '.join(f'{c:.2f}' for c in cpus)}) | "
                f"{walls[len(walls) // 2]:.2f} | {len(json.dumps(doc)) / 1024:.0f} KiB |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cameras", default="16,128")
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows = [one_rig(int(n), args.frames, args.repeats) for n in args.cameras.split(",")]
    text = ("| rig (ring) | `wandcal check`: exit, wall s | route's exit_code | route CPU s, median (runs) | route wall s, "
            "median | result posted |\n|---|---|---|---|---|---|\n" + "\n".join(rows)
            + f"\n\n1-minute load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the end.")
    return publish(TITLE, text, not args.no_write)


if __name__ == "__main__":
    raise SystemExit(main())
