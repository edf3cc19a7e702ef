"""How ``--method lp`` scales in the number of cameras (issue 8), beside ``ba``.

For 8, 16 and 32 cameras x 2000 frames at 0.3 px, clean and with 8% of camera-frames carrying
one gross outlier, every camera but the gauge starts 1 degree and 3 cm off its true pose (about a
random axis and in a random direction; frames triangulated there), and both methods refine the
same labelled problem. Errors are camera-centre errors in the gauge of the bundle adjustment
(calib/judge/crb.py). Times are medians of ``--repeats`` runs of each method, run alternately, as wall
and as CPU time (the process's, BLAS on one thread: other users of a shared machine disturb it
far less than the wall clock); the scaling exponent is the least-squares slope of log(time) on
log(cameras).

Usage: python bench/bench_lp_scaling.py [--cameras 8,16,32] [--frames 2000] [--seeds 2] [--repeats 3]
       [--methods lp,ba] [--json out.json] [--no-write]
``--module PATH`` times the ``refine_lp`` of another file (for before/after tables): a copy of the one-file
``lp.py`` of before the calib/solve/lp/ package, or of calib/solve/lp/refine.py (which runs the installed package's phases).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core per solver: the machine is shared and timings noisy
import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import publish, timed
from wandcal.calib.judge.crb import gauge_errors
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene

NOISE = 0.3
START_DEGREES = 1.0  # the common start of the issue: every free camera this far off in rotation
START_METRES = 0.03  # and this far in position


def _refiners(methods, module):
    out = {}
    for method in methods:
        if method == "ba":
            from wandcal.calib.solve.ba import bundle_adjust
            out["ba"] = bundle_adjust
        elif method == "lp":
            if module:
                spec = importlib.util.spec_from_file_location("slp_under_test", module)
                mod = importlib.util.module_from_spec(spec)
                sys.path.insert(0, str(Path(module).parent))
                spec.loader.exec_module(mod)
                out["lp"] = mod.refine_lp
            else:
                from wandcal.calib.solve.lp import refine_lp
                out["lp"] = refine_lp
    return out


def measure(n_cams, n_frames, outliers, seed, repeats, refiners):
    scene = prepared_scene(n_cams, n_frames, NOISE, seed, outliers)
    model = perturbed_model(scene, START_DEGREES, START_METRES, seed)
    T = scene.sim.truth
    times = {m: [] for m in refiners}
    cpu = {m: [] for m in refiners}
    results = {}
    for _ in range(repeats):
        for method, fn in refiners.items():  # alternately, so that load on the machine hits both
            start = time.process_time()
            (x, info), seconds = timed(fn, model)
            cpu[method].append(time.process_time() - start)
            times[method].append(seconds)
            results[method] = (x, info)
    out = {}
    for method, (x, info) in results.items():
        ec, _ = gauge_errors(*model.poses(x), T.R, T.t, 0)
        out[method] = {
            "seconds": float(np.median(times[method])), "times": times[method],
            "cpu_seconds": float(np.median(cpu[method])), "cpu_times": cpu[method],
            "centre_rms_mm": 1000 * float(np.sqrt(np.mean(ec[1:] ** 2))),
            "iterations": info.get("iterations"), "status": info.get("status"),
            "lp_seconds": float(info.get("lp_seconds", 0.0)),
        }
    return out


def exponent(cams, seconds) -> float:
    return float(np.polyfit(np.log(cams), np.log(seconds), 1)[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", default="8,16,32")
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--methods", default="lp,ba")
    ap.add_argument("--outliers", default="0,0.08")
    ap.add_argument("--module", default="", help="path of another slp.py whose refine_lp is timed as 'lp'")
    ap.add_argument("--json", default="")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    cams = [int(c) for c in args.cameras.split(",")]
    refiners = _refiners(args.methods.split(","), args.module)
    load_before = os.getloadavg()
    runs = {}
    for outliers in (float(v) for v in args.outliers.split(",")):
        for n in cams:
            for seed in range(args.seeds):
                key = f"{n}x{args.frames}/{outliers:g}/{seed}"
                runs[key] = measure(n, args.frames, outliers, seed, args.repeats, refiners)
                print(key, json.dumps({m: {k: v for k, v in r.items() if not k.endswith("times")} for m, r in runs[key].items()}),
                      flush=True)
    load_after = os.getloadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=1))

    rows = []
    for method in refiners:
        for outliers in (float(v) for v in args.outliers.split(",")):
            secs, cpus = [], []
            for n in cams:
                rs = [runs[f"{n}x{args.frames}/{outliers:g}/{s}"] for s in range(args.seeds)]
                sec = float(np.median([r[method]["seconds"] for r in rs]))
                cpu = float(np.median([r[method]["cpu_seconds"] for r in rs]))
                secs.append(sec)
                cpus.append(cpu)
                ratios = [float(np.median([r[method][k] / r["ba"][k] for r in rs])) if "ba" in refiners else float("nan")
                          for k in ("seconds", "cpu_seconds")]
                err = float(np.sqrt(np.mean([r[method]["centre_rms_mm"] ** 2 for r in rs])))
                share = float(np.median([r[method]["lp_seconds"] / r[method]["seconds"] for r in rs]))
                its = float(np.mean([r[method]["iterations"] for r in rs]))
                status = ", ".join(sorted({str(r[method]["status"]) for r in rs}))
                rows.append(f"| {n} x {args.frames} | {100 * outliers:.0f}% | {method} | {sec:.2f} | {ratios[0]:.2f} | {cpu:.2f} | "
                            f"{ratios[1]:.2f} | {err:.3f} | {its:.1f} | {100 * share:.0f}% | {status} |")
            if len(cams) > 1:
                rows.append(f"| exponent {cams[0]}-{cams[-1]} | {100 * outliers:.0f}% | {method} | cameras^{exponent(cams, secs):.2f} | | "
                            f"cameras^{exponent(cams, cpus):.2f} | | | | | |")
    body = f"""
{args.frames} frames at {NOISE} px, {args.seeds} seeds, every free camera started {START_DEGREES:g} deg and
{100 * START_METRES:g} cm off its true pose; BLAS on one thread; load average (1 min) {load_before[0]:.1f} before the run,
{load_after[0]:.1f} after. Seconds (wall) and CPU seconds: median over runs and seeds; "/ ba": median over seeds of the
ratio measured side by side; centre error: RMS over cameras and seeds in the gauge of the bundle
adjustment; iterations: LP steps (lp), Levenberg-Marquardt iterations (ba); "LP": the share of
the wall time in the LP solves (interior point and HiGHS).

| rig | outliers | method | seconds | / ba | CPU s | CPU / ba | centre error RMS (mm) | iterations | LP | status |
|---|---|---|---|---|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
    return publish("LP scaling", body, not args.no_write)


if __name__ == "__main__":
    sys.exit(main())
