"""``wandcal calibrate CAPTURE``: calibrate a capture folder and write its wandcal-result/1 file. What
it reads beside the blobs is in :mod:`wandcal.service.cli.support.inputs`; what it prints,
:mod:`wandcal.service.cli.support.summary`."""

from __future__ import annotations

import argparse
from pathlib import Path

from wandcal.service.cli.support.args import arg_number, arg_whole

RESULT_FILE = "result.json"  # the default method's result; the others get their own (result_path)
BELOW_REQUIRED = 1  # exit status when the rig's verdict is below --require (the result is written all the same)
REQUIRE_LEVELS = ("excellent", "good")  # wandcal.calib.judge.verdict.LEVELS but the worst


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("calibrate", help="calibrate a capture folder and write wandcal-result/1 JSON")
    p.set_defaults(run=run_calibrate)
    if arguments:
        _arguments(p)


def _arguments(p: argparse.ArgumentParser) -> None:
    # the bounds (exit 2 outside them) are the ones CalibrationOptions.check holds
    from wandcal.calib.run.options import (
        DEFAULT_METHOD,
        MAX_LP_SECONDS,
        MAX_PAPER_ROUNDS,
        MAX_SYNC_OFFSET,
        METHODS,
        CalibrationOptions,
    )
    from wandcal.calib.solve.ba import DEFAULT_LOSS, LOSSES
    from wandcal.calib.solve.paper import MAX_ROUNDS
    from wandcal.calib.solve.reprojection import INTRINSICS
    from wandcal.calib.solve.sync import DEFAULT_SYNC, SYNC_MODES

    p.add_argument("capture", type=Path, help="capture folder (points level, or image level: detected first)")
    p.add_argument("--out", type=Path, help="result file (default: CAPTURE/result.json for ba, "
                   "CAPTURE/result-lp.json and CAPTURE/result-paper.json for the others, so that no method's "
                   "result replaces another's)")
    # each option's dest is its CalibrationOptions field (tests/service/test_options_drift.py)
    p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD, help=f"refinement method (default {DEFAULT_METHOD})")
    p.add_argument("--max-rounds", type=arg_whole(1, MAX_PAPER_ROUNDS), default=None, metavar="N",
                   help=f"paper: most rotation/LP rounds, 1 to {MAX_PAPER_ROUNDS} (default {MAX_ROUNDS})")
    p.add_argument("--lp-time-limit", dest="time_limit", type=arg_number(0, MAX_LP_SECONDS, low_open=True), default=None,
                   metavar="S", help="lp and paper: seconds allowed for each LP solve (default: no limit)")
    p.add_argument("--keep-outliers", dest="reject_outliers", action="store_false",
                   help="do not drop gross-outlier camera-frames")
    p.add_argument("--loss", choices=LOSSES, default=DEFAULT_LOSS,
                   help=f"ba: robust loss (default {DEFAULT_LOSS}; 'linear' is plain least squares)")
    p.add_argument("--refine-intrinsics", type=_intrinsics_list, default=(), metavar="LIST",
                   help=f"ba: also refine these per camera, comma-separated from {','.join(INTRINSICS)} (default: none)")
    p.add_argument("--sync", choices=SYNC_MODES, default=DEFAULT_SYNC,
                   help="auto: find each camera's time offset from the wand, for cameras without a trigger "
                        f"(docs/sync.md); none: the frames as recorded (default {DEFAULT_SYNC})")
    p.add_argument("--sync-max-offset", type=arg_whole(1, MAX_SYNC_OFFSET), default=None, metavar="FRAMES",
                   help=f"with --sync auto: frames searched either side, 1 to {MAX_SYNC_OFFSET} "
                        f"(default {CalibrationOptions.sync_max_offset})")
    p.add_argument("--sync-drift", action="store_true", help="with --sync auto: also each camera's rate difference")
    p.add_argument("--require", choices=REQUIRE_LEVELS, default=None, metavar="LEVEL",
                   help=f"for scripts: exit {BELOW_REQUIRED} when the rig's verdict is below LEVEL "
                        f"({' or '.join(REQUIRE_LEVELS)}); the result is written all the same (default: none, exit 0 "
                        f"whatever the verdict). Exit status: 0 written (and at LEVEL or above), {BELOW_REQUIRED} below "
                        "LEVEL, 2 bad input (nothing written)")
    p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")
    p.add_argument("--from", dest="from_result", type=Path, metavar="RESULT",
                   help="start from this result: with --solve-only, every other camera keeps its pose exactly "
                        "(default: none, a fresh solve)")
    p.add_argument("--solve-only", type=_id_list, metavar="CAM[,CAM]",
                   help="with --from: re-solve only these cameras (e.g. the ones 'wandcal check' names; default: all)")


def _intrinsics_list(text: str) -> tuple[str, ...]:
    from wandcal.calib.solve.reprojection import INTRINSICS

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


def run_calibrate(args) -> int:
    from threadpoolctl import threadpool_limits

    from wandcal.service.cli.support.progress import ProgressLine

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
    from dataclasses import replace

    from wandcal.calib.run.calibrate import calibrate
    from wandcal.calib.run.options import options_from
    from wandcal.capture.folder import read_capture
    from wandcal.capture.recording.stamps import capture_rate, timestamp_start
    from wandcal.service.cli.support.inputs import points_level

    folder = points_level(args.capture, progress)
    cap = read_capture(folder)
    rate = capture_rate(folder)
    options = options_from(vars(args) | {"frame_rate_hz": rate})  # the flags by their fields' names
    options.check()  # before the timestamps are read or a camera is re-solved
    if args.from_result is not None or args.solve_only:
        return _solve_only(args, cap, options, progress)
    if options.sync == "auto":
        start = timestamp_start(folder, cap.rig, rate)
        options = replace(options, sync_start=tuple(int(s) for s in start) if start is not None else None)
    return calibrate(cap.rig, cap.wand, cap.static, options=options, progress=progress, points=cap.points, axis=cap.axis,
                     vertical=cap.vertical)


def _solve_only(args, cap, options, progress):
    """``--from RESULT --solve-only CAM[,CAM]`` with the checked ``options`` (a CalibrationOptions;
    :func:`wandcal.calib.run.resolve.solve_only` refuses a method other than ba)."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.capture.result_file import read_result
    from wandcal.service.standing_result import solve_only_capture

    if args.from_result is None or not args.solve_only:
        raise CalibrationError("--from RESULT and --solve-only CAM[,CAM] go together: name the result to start from "
                               "and the cameras to re-solve")
    return solve_only_capture(read_result(args.from_result), cap, list(args.solve_only), options,
                              source=str(args.from_result), capture_name=str(args.capture), progress=progress)


def result_path(capture: Path, method: str) -> Path:
    """Where ``wandcal calibrate CAPTURE --method METHOD`` writes without ``--out``: ``result.json``
    for the default method, ``result-METHOD.json`` for the others (a cross-check never replaces
    the result that report, export and check read by default)."""
    from wandcal.calib.run.options import DEFAULT_METHOD

    return capture / (RESULT_FILE if method == DEFAULT_METHOD else f"result-{method}.json")


def _write_result(args, doc: dict) -> int:
    import json

    from wandcal.service.cli.support.summary import format_summary

    out = args.out or result_path(args.capture, args.method)
    replaced = _replaced(out)
    out.write_text(json.dumps(doc, indent=2) + "\n")
    print(format_summary(doc))
    print(f"wrote {out}" + (f" (replacing the earlier {replaced})" if replaced else ""))
    return _required(getattr(args, "require", None), (doc.get("verdict") or {}).get("level"))


def _required(require: str | None, level: str | None) -> int:
    """0, or :data:`BELOW_REQUIRED` (said on stderr) when ``level`` is below ``require``."""
    import sys

    from wandcal.calib.judge.verdict import LEVELS

    if require is None or level in LEVELS[: LEVELS.index(require) + 1]:
        return 0
    print(f"the rig's verdict is {level or 'missing'}, below --require {require}: exit {BELOW_REQUIRED}", file=sys.stderr)
    return BELOW_REQUIRED


def _replaced(out: Path) -> str | None:
    """What an existing ``out`` holds, said when it is replaced: "ba result" or "file"."""
    import json

    if not out.is_file():
        return None
    try:
        method = json.loads(out.read_text()).get("solver", {}).get("method")
    except (ValueError, OSError, AttributeError):
        method = None
    return f"{method} result" if isinstance(method, str) else "file"
