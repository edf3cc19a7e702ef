"""``wandcal watch RESULT TAKE``: each camera's health over an ordinary take, with the standing
calibration; a moved or drifting camera named (when, how much) and re-solved from the take's markers."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

EXIT_MOVED = 1  # a camera moved or drifts (named)
EXIT_UNJUDGED = 3  # the take is too short to judge any camera (as check's "could not judge")


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("watch", help="watch a take with a standing result: each camera's health, any moved camera "
                       "named and re-solved without a wand",
                       epilog="exit status: 0 every camera healthy; 1 a camera moved or drifts (named), or one of several moved (status one_of: the take cannot tell which); 3 the take is too short to judge; 2 bad input (a take "
                       "with no blobs, blobs in fewer than three cameras, a take of another rig)")
    p.set_defaults(run=run_watch)
    if arguments:
        p.add_argument("result", type=Path, help="the standing wandcal-result/1 file")
        p.add_argument("take", type=Path, help="a take folder: rig.json and take.csv (docs/capture-format.md)")
        p.add_argument("--write", type=Path, default=None, metavar="OUT",
                       help="write the result with the moved cameras re-solved from the take (default: none, nothing written)")
        p.add_argument("--json", action="store_true", help="print the cameras' health as JSON")


def run_watch(args) -> int:
    import json

    from wandcal.capture.take_file import read_take
    from wandcal.service.cli.support.inputs import result_for
    from wandcal.service.cli.support.progress import ProgressLine

    take = read_take(args.take)
    if args.write is not None and args.write.resolve() == args.result.resolve():
        from wandcal.calib.errors import CalibrationError

        raise CalibrationError(f"--write {args.write}: is the standing result; write the updated result to another file")
    standing, rig, R, t, _ = result_for(args.result, take)
    from wandcal.calib.watch.stream import watch_take

    with ProgressLine(quiet=args.json) as progress:
        report = watch_take(rig, R, t, take.blobs,
                            progress=lambda done, total: progress.update(f"watch: frame {done} of {total}"))
    from wandcal.capture.watch_report import check_fit, report_json

    check_fit(report, str(args.take), str(args.result))
    doc = report_json(report)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        _print_report(report, args)
    if args.write is not None:
        _write(args, standing, take, report)
    return EXIT_MOVED if report.moved else 0 if report.judged else EXIT_UNJUDGED


def _print_report(report, args) -> None:
    print(f"{report.frames} frames ({report.first_frame}-{report.last_frame}), {report.tracks} markers matched "
          f"({report.tracks / max(report.frames, 1):.1f} a frame)")
    print(f"{'camera':<16} {'status':<9} {'residual px':>11} {'matched':>8} {'sees turns of':>13}")
    for h in report.cameras:
        sees = f"{h.detectable_turn_deg:.2f} deg" if math.isfinite(h.detectable_turn_deg) else "-"
        print(f"{h.id:<16} {h.status:<9} {h.residual_px:>11.3f} {h.matched:>8.1%} {sees:>13}")
    told: set[str] = set()
    for h in report.moved:
        if h.one_of:  # a move the take cannot pin on one camera: said once for them all, none re-solved
            if h.id not in told:
                print(h.message.replace("RESULT", str(args.result)))
                told.update([h.id, *h.one_of])
            continue
        how = (f"drifting over {h.drift_frames} frames from frame {h.moved_at}" if h.kind == "drift"
               else f"moved before the take began (it disagrees with {args.result} from frame {h.moved_at})"
               if h.before_take else f"knocked at frame {h.moved_at}")
        print(f"{h.id}: {how}, named at frame {h.alarm.detected_frame}", end="")
        if h.lost:
            print("; too far to follow (its blobs are no longer near the markers the others triangulate)", end="")
        if h.resolved is not None:
            r = h.resolved
            print(f"; moved {r.moved_mm:.2f} mm (sigma {r.center_std_mm:.2f}) and turned {r.turned_deg:.3f} deg "
                  f"(sigma {r.rotation_std_deg:.3f}), re-solved from {r.points} markers at {r.rms_px:.2f} px")
        elif h.not_resolved:
            print(f"; not re-solved: {h.not_resolved}; or re-solve it from a wand capture: wandcal calibrate CAPTURE "
                  f"--from {args.result} --solve-only {h.id}")
        else:
            print(f"; not re-solved: re-solve it from a wand capture: wandcal calibrate CAPTURE --from {args.result} "
                  f"--solve-only {h.id}")
    if not report.judged:
        from wandcal.calib.watch.report import BASELINE_FRAMES, MIN_JUDGED_FRAMES

        print(f"too short to judge: the take holds {report.frames} frames with markers, and the test needs "
              f"{MIN_JUDGED_FRAMES} (its first {BASELINE_FRAMES} learn each camera's baseline); record a longer take")
    elif not report.moved:
        print("every camera agrees with the standing result")
    elif args.write is None:
        print(f"write the re-solved result with: wandcal watch {args.result} {args.take} --write OUT")


def _write(args, standing, take, report) -> None:
    import json

    from wandcal.capture.take_file import updated_result
    from wandcal.capture.watch_report import resolved_cameras

    cameras = resolved_cameras(report, str(take.path))
    doc = updated_result(standing, take.path, cameras)
    args.write.write_text(json.dumps(doc, indent=2) + "\n")
    # with --json the standard output is the report alone (a script parses it): the note goes to stderr
    print(f"wrote {args.write}: {', '.join(cameras) or 'no camera'} re-solved from the take",
          file=sys.stderr if args.json else sys.stdout)
