"""`--method paper`'s rounds on the acceptance rig (8 x 1500), with and without jumps along the tail.

The problem is the one `--method paper` solves in bench_acceptance.py: the pipeline runs to the
outlier pass (its robust `ba`), and `refine_paper` is then timed alone, once per jump cap (0: the
paper's plain rounds; decision 0033). Reports rounds, jumps, CPU and wall seconds, the LP's share,
and the largest camera-centre distance between the runs' answers (the same fixed point, to the
stop's 5 um).

Usage: python bench/bench_paper_speed.py [--caps 10,0] [--seed 11] [--no-write]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish
from wandcal.calib.geometry import camera_centers
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.solve import paper


class _Caught(Exception):
    """refine_paper's arguments, caught on their way in."""


def paper_problem(seed: int) -> tuple:
    """refine_paper's arguments in the acceptance run of ``--method paper``."""
    sim = simulate_capture(8, 1500, noise_px=0.3, seed=seed)
    real = paper.refine_paper

    def catch(*args, **kwargs):
        raise _Caught(args)

    paper.refine_paper = catch
    try:
        calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(method="paper"))
    except _Caught as caught:
        return caught.args[0]
    finally:
        paper.refine_paper = real
    raise SystemExit("--method paper did not reach refine_paper")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--caps", default="10,0", help="jump caps to run (0: no jumps)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    R, t, wand, problem, fixed, up = paper_problem(args.seed)[:6]
    rows, centres = [], {}
    for cap in (float(c) for c in args.caps.split(",")):
        paper.JUMP_CAP = cap
        cpu, wall = time.process_time(), time.perf_counter()
        R1, t1, _, info = paper.refine_paper(R, t, wand, problem, fixed, up)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        centres[cap] = camera_centers(R1, t1)
        rows.append(f"| {cap:g} | {info['status']} | {info['iterations']} | {info['jumps']} | {cpu:.1f} | {wall:.1f} | "
                    f"{info['lp_seconds'] / info['seconds']:.0%} |")
        print(rows[-1], flush=True)
    caps = list(centres)
    apart = max(float(np.linalg.norm(centres[c] - centres[caps[0]], axis=1).max()) for c in caps) * 1e6
    body = "\n".join([
        f"`refine_paper` alone on the acceptance rig's problem (seed {args.seed}, after the outlier pass); load "
        f"average {os.getloadavg()[0]:.1f} at the end. Answers at most {apart:.1f} um apart (camera centres).",
        "",
        "| jump cap | status | rounds | jumps | CPU s | wall s | LP share |",
        "|---|---|---|---|---|---|---|",
        *rows,
    ])
    return publish("Seed paper's method: rounds at 8 x 1500", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
