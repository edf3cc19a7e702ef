"""Refinement methods side by side: the LP performance goals of docs/benchmarks.md.

For each simulated rig (4 x 500, 8 x 2000, 16 x 3000 frames at 0.3 px), clean and with 8% of
camera-frames carrying one gross outlier (20-60 px), over several seeds, every method refines
the same labelled problem from the same start (the pipeline's static PnP / resection start).
Errors are measured in the gauge of the bundle adjustment (gauge camera held at its truth; see
calib/judge/crb.py), where the Cramér-Rao bound is computed from the BA Jacobian at the truth.

Usage: python bench/bench_methods.py [--seeds 3] [--repeats 3] [--paper-rigs 4x500] [--no-write]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish, timed
from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.judge.quality import free_wand_lengths
from wandcal.calib.sim.scenes import prepared_scene
from wandcal.calib.solve.ba import bundle_adjust
from wandcal.calib.solve.lp import refine_lp
from wandcal.calib.solve.paper import refine_paper

NOISE = 0.3
RIGS = [(4, 500), (8, 2000), (16, 3000)]
UP = np.array([0.0, 0.0, 1.0])


def run_method(method, model, setup):
    if method == "ba":
        x, info = bundle_adjust(model)
        R, t = model.poses(x)
    elif method == "lp":
        x, info = refine_lp(model)
        R, t = model.poses(x)
    else:
        R, t, _, info = refine_paper(model.R0, model.t0, model.wand(model.x0()), setup.problem, model.fixed, UP)
    return R, t, info


def measure(n_cams, n_frames, outliers, seed, repeats, methods):
    scene = prepared_scene(n_cams, n_frames, NOISE, seed, outliers)
    setup, T = scene.setup, scene.sim.truth
    model = setup.model
    bound_c, bound_r = pose_crb(setup.problem, T.R, T.t, T.wand[setup.frames], 0, NOISE)
    out = {}
    for method in methods:
        times, res = [], None
        for _ in range(repeats if method != "paper" else 1):
            res, seconds = timed(run_method, method, model, setup)
            times.append(seconds)
        R, t, info = res
        ec, er = gauge_errors(R, t, T.R, T.t, 0)
        lengths = free_wand_lengths(R, t, setup.problem)
        out[method] = {
            "seconds": float(np.median(times)),
            "centre": ec[1:], "rotation": er[1:],
            "crb_c": bound_c[1:], "crb_r": bound_r[1:],
            "iterations": info["iterations"],
            "lp_share": info.get("lp_seconds", 0.0) / max(float(np.median(times)), 1e-12) if method != "ba" else 0.0,
            "wand_std": float(lengths.std()),
            "status": info["status"],
        }
    return out


def rms(values):
    return float(np.sqrt(np.mean(np.square(np.concatenate(values)))))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per method and seed (median)")
    ap.add_argument("--paper-rigs", default="4x500", help="rigs on which the slow 'paper' method also runs, e.g. 4x500,8x2000")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    paper_rigs = {tuple(int(v) for v in r.split("x")) for r in args.paper_rigs.split(",") if r}

    goal_rows, abs_rows = [], []
    for n_cams, n_frames in RIGS:
        clean_ba_centre = []
        for outliers in (0.0, 0.08):
            methods = ["ba", "lp"] + (["paper"] if (n_cams, n_frames) in paper_rigs and outliers == 0 else [])
            runs = [measure(n_cams, n_frames, outliers, seed, args.repeats, methods) for seed in range(args.seeds)]
            if outliers == 0:
                clean_ba_centre = [r["ba"]["centre"] for r in runs]
                clean_ba_rot = [r["ba"]["rotation"] for r in runs]
            label = f"{n_cams} x {n_frames}" + (", 8% outliers" if outliers else "")
            for method in methods:
                rs = [r[method] for r in runs]
                t_ratio = np.median([r[method]["seconds"] / r["ba"]["seconds"] for r in runs])
                c_ratio = rms([r["centre"] for r in rs]) / rms(clean_ba_centre)
                r_ratio = rms([r["rotation"] for r in rs]) / rms(clean_ba_rot)
                crb_c = rms([r["centre"] / r["crb_c"] for r in rs])
                crb_r = rms([r["rotation"] / r["crb_r"] for r in rs])
                goal_rows.append(
                    f"| {label} | {method} | {t_ratio:.2f} | {c_ratio:.2f} | {r_ratio:.2f} | {crb_c:.2f} / {crb_r:.2f} | "
                    f"{np.mean([r['iterations'] for r in rs]):.1f} | {100 * np.mean([r['lp_share'] for r in rs]):.0f}% |"
                )
                abs_rows.append(
                    f"| {label} | {method} | {np.median([r['seconds'] for r in rs]):.2f} | {1000 * rms([r['centre'] for r in rs]):.3f} | "
                    f"{np.degrees(rms([r['rotation'] for r in rs])) * 3600:.1f} | {1000 * np.mean([r['wand_std'] for r in rs]):.3f} | "
                    f"{', '.join(sorted({r['status'] for r in rs}))} |"
                )
                print(goal_rows[-1], flush=True)
    body = f"""
Simulated rigs at {NOISE} px blob noise, {args.seeds} seeds each; every method starts from the pipeline's
initial poses on the same labelled problem. Errors are camera-centre and rotation errors in the gauge of
the bundle adjustment (the first camera held at its true pose, scale from the wand), where the
Cramér-Rao bound (CRB) is computed from the BA Jacobian at the truth. "Error ratio" divides the RMS
error over cameras and seeds by that of `ba` **on the clean rig with the same seeds**, so the outlier
rows measure robustness against the clean reference. Times are medians of {args.repeats} runs; the time
ratio is the median over seeds of (method time / `ba` time) measured in the same run.

### Goal table (LP performance issue)

| rig | method | time / ba | centre error / clean ba | rotation error / clean ba | error / sqrt(CRB) (centre / rotation) | iterations | LP share |
|---|---|---|---|---|---|---|---|
{chr(10).join(goal_rows)}

### Absolute figures

| rig | method | seconds | centre error RMS (mm) | rotation error RMS (arcsec) | free wand-length std (mm) | status |
|---|---|---|---|---|---|---|
{chr(10).join(abs_rows)}
"""
    return publish("Refinement methods", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
