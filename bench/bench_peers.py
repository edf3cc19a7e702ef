"""wandcal's refinement beside COLMAP's bundle adjuster (pycolmap, Ceres underneath), on the same
labelled observations from the same start, side by side in one run; and the whole
`wandcal calibrate` process timed beside COLMAP's solve.

Each rig is simulated (0.3 px noise, no L-frame), labelled at the truth, and started from the true
poses moved by 1 degree and 3 cm (seeded), the wand triangulated there. Solvers:
- `ba`: wandcal.calib.solve.ba.bundle_adjust (Cauchy loss) run to its statistical stop;
- `ba+cleanup`: the pipeline's refinement (robust stage, one outlier pass, least squares polish);
- `lp`: wandcal.calib.solve.lp.refine_lp;
- `colmap`, `colmap-cauchy`: COLMAP's default bundle adjuster (Ceres, DENSE_SCHUR) with every
  wand end a free 3D point (COLMAP has no wand length), intrinsics held, the gauge fixed by two
  cameras' poses (TWO_CAMS_FROM_WORLD); the Cauchy scale is the one `ba` ends with. Its
  iterations are Ceres's successful+unsuccessful steps; its time is the adjuster's set-up and
  solve, not the Python that fills the reconstruction.
Errors are camera-centre RMS after a similarity alignment to the truth (COLMAP's scale is the
start's). Memory is the bench process's peak RSS during the solve (VmHWM reset before it, so it
includes the scene the bench holds); the `wandcal calibrate` process's own peak is in the second
table. Ratios are
to `colmap` (or `colmap-cauchy` on outlier rigs) from the same repeat; medians of the repeats.

Usage: python bench/bench_peers.py [--repeats 3] [--rigs 8x1500,16x2500] [--skip-large] [--process-only] [--no-write]
Needs pycolmap (`pip install '.[bench]'`). A full run writes the sections "Peers" (the solvers) and
"Peers: the whole command" of docs/benchmarks.md; --process-only writes the second alone.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import aligned_rms_mm, peak_rss_mb, reset_peak_rss, write_section  # noqa: E402
from bench.whole_process import PROBE  # noqa: E402
from wandcal.calib.geometry import camera_centers, rotvec_to_matrix  # noqa: E402
from wandcal.calib.observations import wand_pairs  # noqa: E402
from wandcal.calib.run.options import CalibrationOptions  # noqa: E402
from wandcal.calib.run.refine import build_problem, refine, reject_outliers, up_direction  # noqa: E402
from wandcal.calib.sim.simulate import simulate_capture  # noqa: E402
from wandcal.calib.solve.ba import bundle_adjust  # noqa: E402
from wandcal.calib.start.labels import label_ends  # noqa: E402

RIGS = ("8x1500", "8x2000", "16x2500", "32x2000", "8x32000")
LARGE = "8x32000"
NOTES = ("Each rig simulated at 0.3 px without an L-frame and labelled at the true poses; every solver starts from the "
         "true poses moved by 1 degree and 3 cm (seeded), the wand triangulated there. COLMAP gets one PINHOLE camera "
         "and one image per wandcal camera, the undistorted observations (normalised xy times f plus the principal "
         "point) and a free 3D point per wand end and frame (it has no wand length); intrinsics held, gauge "
         "TWO_CAMS_FROM_WORLD, the Cauchy scale the one `ba` ends with; its time is the adjuster's set-up and solve. "
         "Centre error: RMS after a similarity alignment to the truth (wandcal.calib.geometry.kabsch, scale=True). Ratios are "
         "to `colmap` (`colmap-cauchy` on the outlier rows) of the same repeat. Peak RSS is the bench process's VmHWM "
         "reset before each solve, so it includes the scene the bench holds; the whole command's own peak is in the "
         "next section.")
OUTLIERS = 0.08
NOISE_PX = 0.3


def scene(cameras: int, frames: int, outliers: float, seed: int = 1, shape: str | None = None):
    """(sim, labelled wand, setup from the perturbed start); ``shape``: a rig of calib/sim/shapes.py
    at its default size instead of `wandcal simulate`'s ring."""
    if shape is not None:
        from wandcal.calib.sim.shapes import RigShape, default_size, simulate_shape

        rig = RigShape(shape, cameras, default_size(shape))
        return perturbed_start(simulate_shape(rig, frames, NOISE_PX, outliers, seed, static=False), seed)
    return perturbed_start(simulate_capture(cameras, frames, NOISE_PX, outliers, False, seed), seed)


def perturbed_start(sim, seed: int):
    """(sim, labelled wand, setup): labelled at the true poses, started 1 deg and 3 cm off them."""
    cameras = len(sim.rig.cameras)
    rng = np.random.default_rng(seed + 100)
    pairs = wand_pairs(sim.rig, sim.wand)
    R, t = sim.truth.R.copy(), sim.truth.t.copy()
    labelled, _ = label_ends(R, t, pairs, np.ones(cameras, bool), sim.rig.wand_length)
    axis = rng.normal(size=(cameras, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    R0 = np.array([rotvec_to_matrix(a * np.radians(1.0)) for a in axis]) @ R
    C = camera_centers(R, t) + rng.normal(size=(cameras, 3)) * 0.03 / np.sqrt(3)
    t0 = -np.einsum("nij,nj->ni", R0, C)
    R0[0], t0[0] = R[0], t[0]
    return sim, labelled, build_problem(sim.rig, labelled, R0, t0, 0)


def centre_error_mm(R, t, sim) -> float:
    return aligned_rms_mm(camera_centers(R, t), sim.truth.centers)


def run_ba(sim, labelled, setup):
    x, info = bundle_adjust(setup.model)
    return (*setup.model.poses(x), info["iterations"], info.get("loss_scale_px"))


def run_ba_cleanup(sim, labelled, setup):
    options, tell = CalibrationOptions(), lambda e: None
    r = refine(sim.rig, labelled, setup, None, None, "ba", options, tell, up_direction(sim.rig, setup.model.R0, setup.model.t0, setup), final=False)
    r = reject_outliers(r, "ba", options, tell)
    return r.R, r.t, r.info["iterations"], None


def run_lp(sim, labelled, setup):
    from wandcal.calib.solve.lp import refine_lp

    x, info = refine_lp(setup.model)
    return (*setup.model.poses(x), info["iterations"], None)


def image_ids(setup) -> np.ndarray:
    """(N,) COLMAP's image (and camera) id of each camera: 1, 2, ... except that the camera whose
    start centre is farthest from the first camera's takes id 2.

    COLMAP's TWO_CAMS_FROM_WORLD gauge holds the first image's pose and one translation coordinate
    of the next image (by id) it finds with a baseline, the one along the baseline's largest
    component. On a ring the next camera by number is the first one's neighbour (0.5 m away at
    128 cameras, against 6.4 m across): the held coordinate then pins the scale by a short lever,
    the reduced camera system is near singular, and Ceres's sparse Schur solve failed ("CHOLMOD
    warning: Matrix not positive definite") and wandered off (30 mm after 101 steps; decision
    0019). The same gauge on the camera across the ring converges (0.186 mm after 6 steps)."""
    from wandcal.calib.geometry import camera_centers

    C = camera_centers(setup.model.R0, setup.model.t0)
    ids = np.arange(1, len(C) + 1)
    far = int(np.argmax(np.linalg.norm(C - C[0], axis=1)))
    ids[[1, far]] = ids[[far, 1]]
    return ids


def colmap_reconstruction(sim, setup):
    import pycolmap

    rec = pycolmap.Reconstruction()
    m, p = setup.model, setup.problem
    wand = m.wand(m.x0()).reshape(-1, 3)
    point = p.point
    ids = image_ids(setup)
    for c, cam in enumerate(sim.rig.cameras):
        fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
        i = int(ids[c])
        rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                                                        params=[fx, fy, cx, cy], camera_id=i))
        sel = np.flatnonzero(p.camera == c)
        pixels = p.xy[sel] * [fx, fy] + [cx, cy]  # the undistorted observations wandcal fits
        image = pycolmap.Image(name=cam.id, keypoints=pixels, camera_id=i, image_id=i)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(m.R0[c]), m.t0[c])
        rec.add_image_with_trivial_frame(image, pose)
    tracks = {}
    for c in range(len(sim.rig.cameras)):
        sel = np.flatnonzero(p.camera == c)
        for k, obs in enumerate(sel):
            tracks.setdefault(int(point[obs]), []).append(pycolmap.TrackElement(int(ids[c]), k))
    for pt, elements in tracks.items():
        rec.add_point3D(wand[pt], pycolmap.Track(elements))
    return rec


def run_colmap(sim, labelled, setup, cauchy_px: float | None = None):
    import pycolmap

    rec = colmap_reconstruction(sim, setup)
    options = pycolmap.BundleAdjustmentOptions(refine_focal_length=False, refine_principal_point=False,
                                               refine_extra_params=False, print_summary=False)
    if cauchy_px is not None:
        options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
        options.ceres.loss_function_scale = cauchy_px
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    start = time.perf_counter()
    adjuster = pycolmap.create_default_bundle_adjuster(options, config, rec)
    summary = adjuster.solve()
    seconds = time.perf_counter() - start
    ids = image_ids(setup)
    R = np.array([rec.image(int(i)).cam_from_world().rotation.matrix() for i in ids])
    t = np.array([rec.image(int(i)).cam_from_world().translation for i in ids])
    ceres = getattr(summary, "ceres_summary", None)
    iterations = f"{ceres.num_successful_steps}+{ceres.num_unsuccessful_steps}" if ceres is not None else "?"
    return R, t, iterations, seconds


def measure(label, fn, *args):
    reset_peak_rss()
    start = time.perf_counter()
    out = fn(*args)
    seconds = time.perf_counter() - start
    if label.startswith("colmap"):
        seconds = out[3]  # its solve alone, not building the reconstruction in Python
    return {"seconds": seconds, "R": out[0], "t": out[1], "iterations": out[2], "peak_mb": peak_rss_mb(), "extra": out[3]}


def calibrate_process(cameras: int, frames: int, outliers: float, repeats: int) -> tuple[float, float]:
    """Median wall time (s) and peak RSS (MB) of the whole `wandcal calibrate` process on a
    simulated capture folder (the default one, with its L-frame, as a new user would make it)."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "capture"
        subprocess.run([sys.executable, "-m", "wandcal.service.cli", "simulate", str(folder), "--cameras", str(cameras),
                        "--frames", str(frames), "--outliers", str(outliers)], check=True, capture_output=True, cwd=REPO)
        times, peaks = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            done = subprocess.run([sys.executable, "-c", PROBE, "calibrate", str(folder), "--quiet",
                                   "--out", str(Path(tmp) / "result.json")], check=True, capture_output=True, text=True, cwd=REPO)
            times.append(time.perf_counter() - start)
            peaks.append(float(done.stderr.strip().splitlines()[-1]) / 1024)
    return float(np.median(times)), float(max(peaks))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rigs", default=",".join(RIGS))
    ap.add_argument("--skip-large", action="store_true", help=f"leave out the {LARGE} rig (minutes) for a quick run")
    ap.add_argument("--no-lp", action="store_true", help="leave out --method lp (slow at 32 cameras)")
    ap.add_argument("--process-only", action="store_true",
                    help="only the whole-command timings (and COLMAP's solve for their ratio), in their own section")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        print("bench_peers needs pycolmap: pip install '.[bench]'", file=sys.stderr)
        return 2
    rows = ["| rig | outliers | solver | s (median) | ratio to COLMAP | iterations | centre error (mm) | peak RSS (MB) |",
            "|---|---|---|---|---|---|---|---|"]
    process_rows = ["| rig | outliers | `wandcal calibrate` process (s) | COLMAP solve (s) | ratio | process peak RSS (MB) |",
                    "|---|---|---|---|---|---|"]
    for rig in [r for r in args.rigs.split(",") if not (args.skip_large and r == LARGE)]:
        cameras, frames = (int(v) for v in rig.split("x"))
        for outliers in (0.0, OUTLIERS):
            process_rig = (rig in ("8x1500", "16x2500", "8x32000") and outliers == 0.0) or (rig == "8x1500" and outliers)
            if args.process_only and not process_rig:
                continue
            sim, labelled, setup = scene(cameras, frames, outliers)
            results: dict[str, list[dict]] = {}
            for _ in range(args.repeats):
                if args.process_only:
                    results.setdefault("colmap" if not outliers else "colmap-cauchy", []).append(
                        measure("colmap", run_colmap, sim, labelled, setup, None if not outliers else run_ba(sim, labelled, setup)[3]))
                    continue
                ba = measure("ba", run_ba, sim, labelled, setup)
                results.setdefault("ba", []).append(ba)
                results.setdefault("ba+cleanup", []).append(measure("ba+cleanup", run_ba_cleanup, sim, labelled, setup))
                if not args.no_lp:
                    results.setdefault("lp", []).append(measure("lp", run_lp, sim, labelled, setup))
                results.setdefault("colmap", []).append(measure("colmap", run_colmap, sim, labelled, setup))
                results.setdefault("colmap-cauchy", []).append(
                    measure("colmap-cauchy", run_colmap, sim, labelled, setup, ba["extra"]))
            reference = "colmap-cauchy" if outliers else "colmap"
            for name, runs in ({} if args.process_only else results).items():
                secs = [r["seconds"] for r in runs]
                ratios = [r["seconds"] / ref["seconds"] for r, ref in zip(runs, results[reference])]
                last = runs[-1]
                rows.append(f"| {rig} | {outliers:.0%} | {name} | {np.median(secs):.3f} | {np.median(ratios):.2f} | "
                            f"{last['iterations']} | {centre_error_mm(last['R'], last['t'], sim):.3f} | {max(r['peak_mb'] for r in runs):.0f} |")
                print(rows[-1], flush=True)
            if process_rig:
                proc, peak = calibrate_process(cameras, frames, outliers, args.repeats)
                colmap_s = float(np.median([r["seconds"] for r in results[reference]]))
                process_rows.append(f"| {rig} | {outliers:.0%} | {proc:.2f} | {colmap_s:.3f} ({reference}) | {proc / colmap_s:.1f} | {peak:.0f} |")
                print(process_rows[-1], flush=True)
    goals = ("Goals (issue 8): the process ≤ 6× COLMAP at 8 × 1500, ≤ 3× at 16 × 2500, ≤ 2× COLMAP-with-Cauchy at "
             "8 × 1500 with 8% outliers; the refinement (`ba+cleanup`) ≤ 1.5× COLMAP on each; memory at 8 × 32,000 "
             "under 600 MB. Both solvers ran on one core (Ceres multi-threads only above 50,000 residuals; wandcal's "
             "BLAS is held to one thread).")
    process = ("The whole command, Python start-up included, beside COLMAP's solve of the same rig (median of "
               f"{args.repeats} runs each; peak RSS is the process's own VmHWM):\n\n" + "\n".join(process_rows) + "\n\n" + goals)
    solvers = NOTES + "\n\n" + "\n".join(rows) + "\n\n" + goals
    print(process if args.process_only else solvers + "\n\n" + process)
    if not args.no_write:
        if not args.process_only:
            write_section("Peers", solvers)
        write_section("Peers: the whole command", process)
    return 0


if __name__ == "__main__":
    sys.exit(main())
