"""The seed paper's simulation protocol, reproduced: wand-length accuracy on held-out frames.

From the authors' public MATLAB code (Masoudas/CameraCalibration, Newton/Main_Program.m): 4 cameras
of 1200 x 900 px with f = 984 px, 300 wand frames of a 300 mm wand, blob noise sigma in {0.5, 1, 2,
3, 4, 5} px (their loop is `for noise=[0.5 1:5]`), 200 trials per level. After calibration, 100
held-out frames are triangulated with the estimated cameras; the metric is the mean and the std of
their wand lengths. Each method runs through the whole pipeline (static PnP start, labelling,
refinement; no outlier rejection, the data are clean). The camera layout differs from theirs (their
poses come from .mat files): see wandcal.calib.sim.simulate.simulate_paper_protocol.

Usage: python bench/bench_paper_protocol.py [--trials 200] [--paper-trials 10] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish, timed
from wandcal.calib.errors import CalibrationError
from wandcal.calib.observations import wand_pairs
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.simulate import simulate_paper_protocol
from wandcal.calib.solve.paper import MAX_ROUNDS
from wandcal.calib.start.labels import label_ends, wand_lengths

NOISE_LEVELS = (0.5, 1.0, 2.0, 3.0, 4.0, 5.0)


def held_out_lengths(result, rig, test) -> np.ndarray:
    """Wand lengths (metres) of the held-out frames, triangulated with the calibrated cameras."""
    pairs = wand_pairs(rig, test)
    labelled, _ = label_ends(result.R, result.t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)
    lengths = wand_lengths(result.R, result.t, labelled)
    return lengths[np.isfinite(lengths)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=200, help="trials per noise level for ba and lp")
    ap.add_argument("--paper-trials", type=int, default=10, help="trials per noise level for the slow paper method")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    rows = []
    for noise in NOISE_LEVELS:
        stats = {m: {"mean": [], "std": [], "seconds": [], "failed": 0} for m in ("paper", "lp", "ba")}
        for trial in range(args.trials):
            sim, test, _ = simulate_paper_protocol(noise, seed=1000 * int(noise * 10) + trial)
            for method in ("paper", "lp", "ba"):
                if method == "paper" and trial >= args.paper_trials:
                    continue
                try:
                    result, seconds = timed(
                        calibrate, sim.rig, sim.wand, sim.static,
                        options=CalibrationOptions(method=method, reject_outliers=False),
                    )
                except CalibrationError:
                    stats[method]["failed"] += 1
                    continue
                lengths = held_out_lengths(result, sim.rig, test) * 1000
                stats[method]["mean"].append(lengths.mean())
                stats[method]["std"].append(lengths.std())
                stats[method]["seconds"].append(seconds)
        for method, s in stats.items():
            n = len(s["mean"])
            if n == 0:
                continue
            rows.append(
                f"| {noise} | {method} | {n} | {np.mean(s['mean']):.2f} +- {np.std(s['mean']):.2f} | "
                f"{np.mean(s['std']):.2f} +- {np.std(s['std']):.2f} | {np.median(s['seconds']):.2f} | {s['failed']} |"
            )
            print(rows[-1], flush=True)
    body = f"""
Held-out wand length (true 300 mm) over 100 test frames per trial, triangulated with the calibrated
cameras: the mean over trials of each trial's mean and std, +- their spread over trials. `paper` runs
its rotation/LP rounds to convergence (at most {MAX_ROUNDS}) on the first {args.paper_trials} trials
of each level; `lp` and `ba` run {args.trials} trials per level.

| noise (px) | method | trials | wand length mean (mm) | wand length std (mm) | seconds (median) | failed |
|---|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
    return publish("Seed paper's simulation protocol", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
