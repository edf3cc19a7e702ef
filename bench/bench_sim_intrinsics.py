"""Clean simulated rigs whose given intrinsics are a few per cent off (``simulate --intrinsics-error``):
does each camera's honest sigma cover its displacement from the truth, is the limiting intrinsic
named, and is any such rig called poor or given a fault?

Each rig is the simulator's ring (L-frame, 0.3 px noise) calibrated with ``ba`` as given; a
camera's displacement is its centre's distance from the truth after the best similarity map
(bench/common.aligned_centres_mm), against its ``geometry_std_honest_mm`` (a 3-D RMS). The focal
sigma drawn from is the judgement's default 2% unless ``--focal-std`` writes it into rig.json.

Usage: python bench/bench_sim_intrinsics.py [--cameras 6,8,16] [--focal 1,2,3] [--seeds 1,2,3]
       [--principal PX] [--distortion K] [--tangential P] [--focal-std] [--frames N]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import aligned_centres_mm
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.intrinsics import IntrinsicsError, with_intrinsics_error
from wandcal.calib.sim.simulate import simulate_capture


def run(cameras: int, frames: int, error: IntrinsicsError, seed: int) -> dict:
    """One rig: its level, faults, and per camera (displacement mm, geometry sigma, honest sigma,
    whether its focal length is named among the verdict's limits)."""
    sim = with_intrinsics_error(simulate_capture(cameras, frames, 0.3, 0.0, True, seed), error, seed)
    doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    moved = aligned_centres_mm(np.array([c["center"] for c in doc["cameras"]]), sim.truth.centers)
    limits = doc["verdict"].get("limits") or []
    rows = [(float(d), c.get("geometry_std_mm"), c.get("geometry_std_honest_mm"),
             any(lim["camera"] == c["id"] and lim.get("parameter", "focal length") == "focal length" for lim in limits))
            for d, c in zip(moved, doc["cameras"])]
    return {"level": doc["verdict"]["level"], "faults": [f"{f['kind']} {f.get('camera') or ''}".strip()
                                                         for f in doc["verdict"].get("faults") or []],
            "poor": [c["id"] for c in doc["cameras"] if c.get("verdict", {}).get("level") == "poor"], "rows": rows}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="6,8,16")
    ap.add_argument("--focal", default="1,2,3", help="focal sigmas drawn from, per cent")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--principal", type=float, default=0.0, help="principal point sigma drawn from, px")
    ap.add_argument("--distortion", type=float, default=0.0, help="k1, k2 sigma drawn from")
    ap.add_argument("--tangential", type=float, default=None, help="p1, p2 sigma drawn from (default --distortion)")
    ap.add_argument("--focal-std", action="store_true", help="write focal_std_px as the sigma drawn from")
    ap.add_argument("--frames", type=int, default=1500)
    args = ap.parse_args()
    print("cameras focal% seed | level | faults | poor cameras | within 1/2/3 honest sigma | named | "
          "displacement mm max | honest mm median | geometry mm median")
    totals = np.zeros(5, dtype=int)
    start = time.process_time()
    for n in map(int, args.cameras.split(",")):
        for pct in map(float, args.focal.split(",")):
            for seed in map(int, args.seeds.split(",")):
                got = run(n, args.frames, IntrinsicsError(pct / 100, args.principal, args.distortion, args.focal_std, args.tangential), seed)
                d, g, h, named = (np.array(x, dtype=float) for x in zip(*got["rows"]))
                within = [int(np.sum(d <= k * h)) for k in (1, 2, 3)]
                totals += [len(d), *within, int(named.sum())]
                print(f"{n:3d} {pct:4g} {seed:3d} | {got['level']} | {', '.join(got['faults']) or '-'} | "
                      f"{', '.join(got['poor']) or '-'} | {'/'.join(map(str, within))} of {len(d)} | {int(named.sum())} | "
                      f"{d.max():.1f} | {np.median(h):.1f} | {np.median(g):.2f}", flush=True)
    cams, w1, w2, w3, named_total = totals
    print(f"total {cams} cameras: within 1 honest sigma {w1} ({100 * w1 / cams:.0f}%), 2: {w2} ({100 * w2 / cams:.0f}%), "
          f"3: {w3} ({100 * w3 / cams:.0f}%); focal named as the limit {named_total} ({100 * named_total / cams:.0f}%); "
          f"{time.process_time() - start:.0f} CPU s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
