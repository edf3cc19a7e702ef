"""``--sync auto`` with a 3-marker wand (decision 0044): 5 cameras x 600 frames, camera 3 two
frames + 0.3 frame late; each offset's error (frames) against its standard error, and the
centres' distance (mm, after a similarity alignment) from the same capture calibrated in time,
and both against the truth. Goal (issue 32): within 2 mm of the synchronised result.

    python bench/bench_sync_markers.py [--seeds 4-6] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.common import aligned_centres_mm, aligned_rms_mm, publish
from bench.matrix_inputs import CW500_M
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.simulate import simulate_capture

LATE = np.array([0.0, 0.0, 2.3, 0.0, 0.0])  # frames: camera 3 two frames and 0.3 late
TITLE = "Sync with a multi-marker wand"


def one_seed(seed: int) -> str:
    sim = simulate_capture(5, 600, 0.3, 0.0, False, seed, wand_markers=CW500_M)
    synced = calibrate(sim.rig, sim.wand)
    late = simulate_capture(5, 600, 0.3, 0.0, False, seed, wand_markers=CW500_M, offsets=LATE)
    r = calibrate(late.rig, late.wand, options=CalibrationOptions(sync="auto"))
    found = np.array([c["offset_frames"] for c in r.sync["cameras"]])
    std = np.array([c["offset_std_frames"] or 0.0 for c in r.sync["cameras"]])
    err = found - LATE
    return (f"| {seed} | {np.abs(err).max():.4f} | {np.abs(err[1:] / std[1:]).max():.1f} | "
            f"{aligned_centres_mm(r.centers, synced.centers).max():.3f} | {aligned_rms_mm(r.centers, late.truth.centers):.3f} | "
            f"{aligned_rms_mm(synced.centers, sim.truth.centers):.3f} | {'yes' if r.wand_report.marker_pairs else 'no'} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="4-6")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args(argv)
    first, _, last = args.seeds.partition("-")
    rows = [one_seed(s) for s in range(int(first), int(last or first) + 1)]
    text = "\n".join(["| seed | largest offset error, frames | largest error / SE | centres from the synchronised result, "
                      "max mm (goal 2) | auto's centre error vs truth, RMS mm | synchronised, RMS mm | every marker used |",
                      "|---|---|---|---|---|---|---|", *rows])
    return publish(TITLE, text, not args.no_write)


if __name__ == "__main__":
    raise SystemExit(main())
