"""``wandcal simulate``, ``wandcal calibrate`` and ``wandcal demo``, and the arguments of those and of
``wandcal check`` (its run: :mod:`wandcal.service.cli.check`). What they read beside the blobs
is in :mod:`wandcal.service.cli.inputs`; what they print, :mod:`wandcal.service.cli.summary`."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from wandcal.calib.errors import CalibrationError
from wandcal.calib.run.calibrate import DEFAULT_METHOD, METHODS, calibrate
from wandcal.calib.solve.ba import DEFAULT_LOSS, LOSSES
from wandcal.calib.solve.paper import MAX_ROUNDS
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.sync import DEFAULT_SYNC, SYNC_MODES
from wandcal.capture.folder import read_capture, write_capture
from wandcal.service.cli.args import MAX_SEED, MAX_SYNC_OFFSET, number, whole
from wandcal.service.cli.check import run_check
from wandcal.service.cli.inputs import capture_rate, points_level, result_for, timestamp_start
from wandcal.service.cli.progress import ProgressLine
from wandcal.service.cli.summary import format_summary, truth_table

TRUTH_FILE = "truth.json"
# Bounds of the numeric options (exit 2 outside them). 10,000 paper rounds are ~40 min at 8 x 1500,
# where the scheme converges in ~170; a day is a time limit no LP step needs.
MAX_PAPER_ROUNDS = 10_000
MAX_LP_SECONDS = 86_400.0
# The simulator holds every observation in memory (~100 bytes a camera-frame): 64 cameras by
# 100,000 frames is ~0.6 GB, the most a demo should ask of a workstation.
MAX_SIM_CAMERAS = 64
MAX_SIM_FRAMES = 100_000
MAX_NOISE_PX = 100.0  # blob noise past this hides the wand in any image
RESULT_FILE = "result.json"  # the default method's result; the others get their own (result_path)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="write a simulated capture folder with its truth.json")
    p.add_argument("out", type=Path, help="folder to write")
    _sim_args(p, cameras=8, frames=1500)
    p.set_defaults(run=run_simulate)

    p = sub.add_parser("calibrate", help="calibrate a capture folder and write wandcal-result/1 JSON")
    p.add_argument("capture", type=Path, help="capture folder (points level, or image level: detected first)")
    p.add_argument("--out", type=Path, help="result file (default: CAPTURE/result.json for ba, "
                   "CAPTURE/result-lp.json and CAPTURE/result-paper.json for the others, so that no method's "
                   "result replaces another's)")
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD, help=f"refinement method (default {DEFAULT_METHOD})")
    p.add_argument("--max-rounds", type=whole(1, MAX_PAPER_ROUNDS), default=None, metavar="N",
                   help=f"paper: most rotation/LP rounds, 1 to {MAX_PAPER_ROUNDS} (default {MAX_ROUNDS})")
    p.add_argument("--lp-time-limit", type=number(0, MAX_LP_SECONDS, low_open=True), default=None, metavar="S",
                   help="lp and paper: seconds allowed for each LP solve (default: no limit)")
    p.add_argument("--keep-outliers", action="store_true", help="do not drop gross-outlier camera-frames")
    p.add_argument("--loss", choices=LOSSES, default=DEFAULT_LOSS,
                   help=f"ba: robust loss (default {DEFAULT_LOSS}; 'linear' is plain least squares)")
    p.add_argument("--refine-intrinsics", type=_intrinsics_list, default=(), metavar="LIST",
                   help=f"ba: also refine these per camera, comma-separated from {','.join(INTRINSICS)} (default: none)")
    p.add_argument("--sync", choices=SYNC_MODES, default=DEFAULT_SYNC,
                   help="auto: find each camera's time offset from the wand, for cameras without a trigger (docs/sync.md)")
    p.add_argument("--sync-max-offset", type=whole(1, MAX_SYNC_OFFSET), default=None, metavar="FRAMES", help="with --sync auto: frames searched")
    p.add_argument("--sync-drift", action="store_true", help="with --sync auto: also each camera's rate difference")
    p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")
    p.add_argument("--from", dest="from_result", type=Path, metavar="RESULT",
                   help="start from this result: with --solve-only, every other camera keeps its pose exactly")
    p.add_argument("--solve-only", type=_id_list, metavar="CAM[,CAM]",
                   help="with --from: re-solve only these cameras (e.g. the ones 'wandcal check' names)")
    p.set_defaults(run=run_calibrate)

    p = sub.add_parser("check", help="judge a result's cameras against a fresh wand capture: did any move?",
                       epilog="exit status: 0 every camera agrees; 1 a camera moved (named, with the command to re-solve "
                       "it); 2 bad input, or a capture of another rig; 3 no answer: some camera could not be judged, "
                       "or most cameras disagree (the rig was rebuilt: calibrate afresh)")
    p.add_argument("result", type=Path, help="wandcal-result/1 file")
    p.add_argument("capture", type=Path, help="a fresh wand capture of the same rig")
    p.add_argument("--json", action="store_true", help='print {"cameras": [{"id", "moved", "rms_px", ...}]}')
    p.set_defaults(run=run_check)

    p = sub.add_parser("demo", help="simulate a rig, calibrate it and compare with the truth")
    _sim_args(p, cameras=6, frames=800)
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD)
    p.add_argument("--keep", type=Path, help="also keep the simulated capture and result in this folder")
    p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")
    p.set_defaults(run=run_demo)


def _sim_args(p: argparse.ArgumentParser, cameras: int, frames: int) -> None:
    p.add_argument("--cameras", type=whole(2, MAX_SIM_CAMERAS), default=cameras, metavar="N",
                   help=f"cameras on a ring around the volume, 2 to {MAX_SIM_CAMERAS} (default {cameras})")
    p.add_argument("--frames", type=whole(10, MAX_SIM_FRAMES), default=frames, metavar="N",
                   help=f"wand frames, 10 to {MAX_SIM_FRAMES} (default {frames})")
    p.add_argument("--noise", type=number(0, MAX_NOISE_PX), default=0.3, metavar="PX",
                   help="blob noise, pixels (std; default 0.3)")
    p.add_argument("--outliers", type=number(0, 1, high_open=True), default=0.0, metavar="SHARE",
                   help="share of camera-frames with a gross outlier, 0 to below 1 (default 0)")
    p.add_argument("--no-static", action="store_true", help="no L-frame")
    p.add_argument("--seed", type=whole(0, MAX_SEED), default=1,
                   help="random seed: the same seed gives the same rig (default 1)")


def _intrinsics_list(text: str) -> tuple[str, ...]:
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [name for name in names if name not in INTRINSICS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown {unknown[0]!r}; choose from {','.join(INTRINSICS)}")
    return names


def _id_list(text: str) -> tuple[str, ...]:
    ids = tuple(name.strip() for name in text.split(",") if name.strip())
    if not ids:
        raise argparse.ArgumentTypeError("give at least one camera id")
    return ids


def _simulate(args):
    from wandcal.calib.sim.simulate import simulate_capture  # simulate and demo only: calibrate does not pay for it

    return simulate_capture(args.cameras, args.frames, args.noise, args.outliers, not args.no_static, args.seed)


def run_simulate(args) -> int:
    sim = _simulate(args)
    write_capture(args.out, sim.rig, sim.wand, sim.static)
    (args.out / TRUTH_FILE).write_text(json.dumps(sim.truth.to_json(sim.rig)) + "\n")
    print(f"wrote {args.out}: {len(sim.rig.cameras)} cameras, {args.frames} frames, {len(sim.wand)} wand blobs")
    return 0


def run_calibrate(args) -> int:
    from threadpoolctl import threadpool_limits

    # BLAS on one thread for the whole command, as the server sets it at its start (service/main.py):
    # ba and lp pin it for their solves already, and the products outside them (pair tables,
    # uncertainty) are too small for a second thread to pay for its hand-offs and spinning
    # (64 x 3000: 5.28 -> 4.86 s CPU, 5.01 -> 4.86 s wall; docs/decisions/0025)
    with threadpool_limits(limits=1, user_api="blas"):
        progress = ProgressLine(quiet=args.quiet)
        try:
            result = _calibrated(args, progress)
        finally:
            progress.close()  # the line ends before the summary, or an error, is printed
        return _write_result(args, result.to_json())


def _calibrated(args, progress):
    folder = points_level(args.capture, progress)
    cap = read_capture(folder)
    if args.max_rounds is not None and args.method != "paper":
        raise CalibrationError(f"--max-rounds counts the paper method's rounds; --method {args.method} has none "
                               "(drop it, or add --method paper)")
    if args.lp_time_limit is not None and args.method == "ba":
        raise CalibrationError("--lp-time-limit bounds the LP solves of --method lp and paper; ba solves no LP "
                               "(drop it, or choose one of those)")
    if args.from_result is not None or args.solve_only:
        return _solve_only(args, cap, progress)
    options = {"max_rounds": args.max_rounds, "time_limit": args.lp_time_limit, "reject_outliers": not args.keep_outliers,
               "loss": args.loss, "refine_intrinsics": args.refine_intrinsics, "sync": args.sync,
               "sync_max_offset": args.sync_max_offset, "sync_drift": args.sync_drift, "frame_rate_hz": capture_rate(folder),
               "sync_start": timestamp_start(folder, cap.rig, capture_rate(folder)) if args.sync == "auto" else None}
    return calibrate(cap.rig, cap.wand, cap.static, args.method, progress=progress, options=options,
                     points=cap.points, axis=cap.axis)


def _solve_only(args, cap, progress):
    from wandcal.calib.run.resolve import solve_only

    if args.from_result is None or not args.solve_only:
        raise CalibrationError("--from RESULT and --solve-only CAM[,CAM] go together: name the result to start from "
                               "and the cameras to re-solve")
    if args.method != "ba" or args.refine_intrinsics:
        raise CalibrationError("--solve-only re-solves poses with --method ba only, intrinsics held")
    prev, rig, R, t, entries = result_for(args.from_result, cap)
    if cap.wand is None or not len(cap.wand):
        raise CalibrationError(f"{args.capture}: has no wand blobs; --solve-only needs a fresh wand capture")
    options = {"reject_outliers": not args.keep_outliers, "loss": args.loss}
    return solve_only(rig, cap.wand, R, t, list(args.solve_only), prev.result.world, entries,
                      progress=progress, options=options)


def result_path(capture: Path, method: str) -> Path:
    """Where ``wandcal calibrate CAPTURE --method METHOD`` writes without ``--out``: ``result.json``
    for the default method, ``result-METHOD.json`` for the others (a cross-check never replaces
    the result that report, export and check read by default)."""
    return capture / (RESULT_FILE if method == DEFAULT_METHOD else f"result-{method}.json")


def _write_result(args, doc: dict) -> int:
    out = args.out or result_path(args.capture, args.method)
    replaced = _replaced(out)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(format_summary(doc))
    print(f"wrote {out}" + (f" (replacing the earlier {replaced})" if replaced else ""))
    return 0


def _replaced(out: Path) -> str | None:
    """What an existing ``out`` holds, said when it is replaced: "ba result" or "file"."""
    if not out.is_file():
        return None
    try:
        method = json.loads(out.read_text()).get("solver", {}).get("method")
    except (ValueError, OSError, AttributeError):
        method = None
    return f"{method} result" if isinstance(method, str) else "file"


def run_demo(args) -> int:
    sim = _simulate(args)
    print(
        f"simulated {args.cameras} cameras, {args.frames} wand frames, {args.noise} px noise, "
        f"{'an L-frame' if not args.no_static else 'no static object'}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        write_capture(folder, sim.rig, sim.wand, sim.static)
        (folder / TRUTH_FILE).write_text(json.dumps(sim.truth.to_json(sim.rig)) + "\n")
        cap = read_capture(folder)
        progress = ProgressLine(quiet=args.quiet)
        try:
            result = calibrate(cap.rig, cap.wand, cap.static, args.method, progress=progress)
        finally:
            progress.close()
        (folder / "result.json").write_text(json.dumps(result.to_json(), indent=2) + "\n")
    print(format_summary(result.to_json()))
    print(truth_table(result, sim))
    return 0


if __name__ == "__main__":
    sys.exit(0)
