"""Peak memory against the size of the data (issue 20, class 3): the largest wand.csv a capture
may hold (wandcal.capture.csv_tables.MAX_CSV_BYTES) read by the folder reader and calibrated, and the
largest blob-set request body (wandcal.service.request_limits.MAX_BLOBSETS_BODY_BYTES) posted to a real
server. Each figure is the peak resident set (VmHWM) above the process's own before the work,
divided by the data's size: the multiple docs/reliability.md publishes.

Run: ``python bench/bench_memory.py [--calibrate]`` (prints a table; the figures go into
docs/reliability.md by hand, with this command).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

MB = 1024 * 1024
CHILD = r"""
import sys, time
from pathlib import Path
def hwm():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
def rss():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
from wandcal.capture.folder import read_capture
from wandcal.calib.run.calibrate import calibrate
folder = Path(sys.argv[1])
base = rss()
t = time.perf_counter()
cap = read_capture(folder)
read_peak, read_s = hwm() - base, time.perf_counter() - t
print("read", read_peak, read_s, len(cap.wand), flush=True)
if sys.argv[2] == "1":
    t = time.perf_counter()
    calibrate(cap.rig, cap.wand, cap.static)
    print("calibrate", hwm() - base, time.perf_counter() - t, flush=True)
"""


def big_capture(folder: Path, target_bytes: int) -> int:
    """A capture whose wand.csv is just under ``target_bytes``: a simulated 8-camera wanding
    repeated at later frame numbers. Returns the file's size."""
    import numpy as np

    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.capture.folder import write_capture
    from wandcal.drivers.capture_files import WAND_FILE

    sim = simulate_capture(cameras=8, frames=1500, noise_px=0.3, seed=5)
    write_capture(folder, sim.rig, sim.wand, sim.static)
    header = (folder / WAND_FILE).read_bytes().partition(b"\n")[0] + b"\n"
    ids = sim.rig.ids
    written = len(header)
    with open(folder / WAND_FILE, "wb") as fh:
        fh.write(header)
        for r in range(10**6):
            frame = sim.wand.frame + r * 10_000
            chunk = "".join(f"{f},{ids[c]},{u:.4f},{v:.4f}\r\n"
                            for f, c, (u, v) in zip(frame, sim.wand.camera, sim.wand.uv)).encode()
            if written + len(chunk) > target_bytes:
                break
            fh.write(chunk)
            written += len(chunk)
    del np
    return (folder / WAND_FILE).stat().st_size


def measure_csv(calibrate: bool) -> list[str]:
    from wandcal.capture.csv_tables import MAX_CSV_BYTES

    with tempfile.TemporaryDirectory() as tmp:
        size = big_capture(Path(tmp), MAX_CSV_BYTES)
        out = subprocess.run([sys.executable, "-c", CHILD, tmp, "1" if calibrate else "0"], capture_output=True,
                             text=True, check=True).stdout.split("\n")
    rows = []
    for line in out:
        if line:
            what, peak, seconds, *rest = line.split()
            rows.append(f"| wand.csv, {what} | {size / MB:.1f} MB | {int(peak) / MB:.0f} MB | "
                        f"{int(peak) / size:.1f} | {float(seconds):.1f} s |")
    return rows


def server_hwm(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError("no VmHWM")


def measure_blobsets() -> list[str]:
    import httpx

    from tests.service.conftest import Server, free_port, server_env
    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.capture.folder import rig_to_json
    from wandcal.drivers.capture_files import RIG_FILE
    from wandcal.service.request_limits import MAX_BLOBSETS_BODY_BYTES
    from wandcal.service.schemas import MAX_BLOB_SETS

    sim = simulate_capture(cameras=8, frames=10, noise_px=0.3, seed=5)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        srv = Server(port=free_port(), env=server_env(Path(tmp), workers=0), log=Path(tmp) / "server.log")
        (Path(tmp) / "replay").mkdir()
        srv.start()
        try:
            with httpx.Client(base_url=srv.url + "/api/v1", timeout=600) as client:
                capture = client.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)))})
                capture_id = capture.json()["id"]
                # as many blobs per camera as fit the body limit: the body a client can make largest
                per_camera = 1
                while True:
                    body = _body(sim.rig.ids, MAX_BLOB_SETS, per_camera + 1)
                    if len(body) > MAX_BLOBSETS_BODY_BYTES:
                        break
                    per_camera += 1
                body = _body(sim.rig.ids, MAX_BLOB_SETS, per_camera)
                time.sleep(1.0)  # the server settles after its start
                before = server_hwm(srv.proc.pid)
                t = time.perf_counter()
                r = client.post(f"/captures/{capture_id}/blobsets", content=body,
                                headers={"content-type": "application/json"})
                seconds = time.perf_counter() - t
                assert r.status_code == 201, r.text
                peak = server_hwm(srv.proc.pid) - before
                rows.append(f"| blob-set body ({MAX_BLOB_SETS} sets, {per_camera} blobs a camera) | "
                            f"{len(body) / MB:.1f} MB | {peak / MB:.0f} MB | {peak / len(body):.1f} | {seconds:.1f} s |")
        finally:
            srv.stop()
    return rows


def _body(ids: list[str], sets: int, per_camera: int) -> bytes:
    blobs = {cid: [[100.0 + 3 * k + 0.123, 200.0 + 2 * k + 0.456] for k in range(per_camera)] for cid in ids}
    return json.dumps({"sets": [{"frame": f, "blobs": blobs} for f in range(sets)]}).encode()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--calibrate", action="store_true", help="also calibrate the largest wand.csv (minutes)")
    args = parser.parse_args()
    lines = ["| data | size | peak above the process's own | multiple | time |", "|---|---|---|---|---|"]
    lines += measure_csv(args.calibrate)
    lines += measure_blobsets()
    print("\n".join(lines))


if __name__ == "__main__":
    main()
