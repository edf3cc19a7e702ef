"""``ba`` on rigs of every shape (calib/sim/shapes.py): iterations, seconds and error against the
truth, beside a reference run whose robust stage stops only when every parameter (frames too) is
within its standard errors (the rule before decision 0032).

Each rig: 3000 wand frames, 0.3 px noise, 2% gross outliers, |k1| up to 0.1, each frame seen by
2-4 cameras, an L-frame at the origin; the whole pipeline (`calibrate`, method ba).

Usage: python bench/bench_shapes.py [--cameras 32,64] [--shapes ring,dome,tiers,hallway] [--frames 3000] [--no-reference]
    [--no-write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from unittest import mock

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import aligned_rms_mm, machine, replace_section, timed
from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape

TITLE = "Rigs of every shape: ba's iterations (issue 33, decision 0032)"


def one(shape: RigShape, frames: int, seed: int, reference: bool) -> tuple[int, float, float]:
    """(iterations, seconds, aligned centre RMS error in mm) of ba's whole pipeline on the shape."""
    sim = simulate_shape(shape, frames=frames, seed=seed)
    with mock.patch("wandcal.calib.run.refine.methods.WAND_FRAMES_IN_STOP", reference):
        result, seconds = timed(calibrate, sim.rig, sim.wand, sim.static, options=CalibrationOptions(method="ba"))
    return int(result.solver.iterations), seconds, aligned_rms_mm(result.centers, sim.truth.centers)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="32,64")
    ap.add_argument("--shapes", default="ring,dome,tiers,hallway")
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-reference", action="store_true", help="leave out the reference runs (minutes each at 256 cameras)")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows = ["| shape | size (m) | cameras | iterations | seconds | error (mm) | reference: iterations | seconds | error (mm) | error / reference |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for kind in args.shapes.split(","):
        for n in map(int, args.cameras.split(",")):
            shape = RigShape(kind, n, default_size(kind))
            try:
                it, sec, err = one(shape, args.frames, args.seed, reference=False)
                rit, rsec, rerr = (one(shape, args.frames, args.seed, reference=True) if not args.no_reference
                                   else (0, float("nan"), float("nan")))
            except CalibrationError as exc:  # the row says why, and the others still run
                row = f"| {kind} | {shape.size_m:g} | {n} | failed: {exc} | | | | | | |"
            else:
                row = (f"| {kind} | {shape.size_m:g} | {n} | {it} | {sec:.1f} | {err:.2f} | {rit} | {rsec:.1f} | {rerr:.2f} | "
                       f"{err / rerr:.3f} |")
            print(row, flush=True)
            rows.append(row)
    command = "python bench/bench_shapes.py " + " ".join(sys.argv[1:])
    text = (f"`{command.strip()}` ({machine()}).\n\n{args.frames} wand frames, 0.3 px, 2% gross outliers, |k1| up to 0.1, "
            "each frame seen by 2-4 cameras, L-frame; the whole pipeline with `ba`. Iterations: the robust stage's and the "
            "polish's together. Error: RMS of the camera centres against the truth after the best similarity. The reference "
            "runs the robust stage until every parameter, frames too, is within 0.5 standard errors (the rule before "
            "decision 0032).\n\n" + "\n".join(rows))
    if not args.no_write:
        replace_section(TITLE, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
