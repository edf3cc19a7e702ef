"""``wandcal watch RESULT TAKE``: each camera's health over an ordinary take, with the standing
calibration; a moved or drifting camera named (when, how much) and re-solved from the take's markers."""

from __future__ import annotations

import argparse
from pathlib import Path

EXIT_MOVED = 1  # a camera moved or drifts (named)
# Markers triangulated by two cameras that the others see: ~95% on a healthy rig (blobs dropped, views
# beside another marker's image left out); under half for most cameras is not a bumped camera but a
# result of another rig, or a rig rebuilt
MIN_MATCHED = 0.5


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("watch", help="watch a take with a standing result: each camera's health, any moved camera "
                       "named and re-solved without a wand",
                       epilog="exit status: 0 every camera healthy; 1 a camera moved or drifts (named); 2 bad input (a take "
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
    from wandcal.calib.watch.watch import watch_take

    with ProgressLine(quiet=args.json) as progress:
        report = watch_take(rig, R, t, take.blobs,
                            progress=lambda done, total: progress.update(f"watch: frame {done} of {total}"))
    _check_fit(report, args)
    doc = _report_json(report)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        _print_report(report, args)
    if args.write is not None:
        _write(args, standing, take, report)
    return EXIT_MOVED if report.moved else 0


def _check_fit(report, args) -> None:
    """Refuse a take that most cameras do not fit (another rig's, or a rebuilt one) as bad input."""
    import numpy as np

    from wandcal.calib.errors import CalibrationError

    matched = np.array([h.matched for h in report.cameras])
    if np.median(matched) < MIN_MATCHED:
        raise CalibrationError(f"{args.take}: the take does not fit {args.result}: its cameras find only "
                               f"{np.median(matched):.0%} of the markers the others triangulate (a healthy rig finds "
                               "~95%); the take is of another rig, or the rig was rebuilt: calibrate afresh")


def _report_json(report) -> dict:
    cameras = []
    for h in report.cameras:
        entry = {"id": h.id, "status": h.status, "residual_px": round(h.residual_px, 4), "matched": round(h.matched, 4)}
        if h.alarm is not None:
            entry |= {"moved_at_frame": h.moved_at, "detected_at_frame": h.alarm.detected_frame, "kind": h.kind,
                      "drift_frames": h.drift_frames, "before_take": h.before_take,
                      "statistic": round(h.alarm.statistic, 1)}
        if h.resolved is not None:
            entry |= {"rotation_deg": round(h.resolved.turned_deg, 4), "translation_mm": round(h.resolved.moved_mm, 3),
                      "center_std_mm": round(h.resolved.center_std_mm, 3),
                      "rotation_std_deg": round(h.resolved.rotation_std_deg, 4), "resolved_rms_px": round(h.resolved.rms_px, 4),
                      "resolved_points": h.resolved.points}
        cameras.append(entry)
    return {"frames": report.frames, "markers": report.tracks, "first_frame": report.first_frame,
            "last_frame": report.last_frame, "cameras": cameras, "moved": [h.id for h in report.moved]}


def _print_report(report, args) -> None:
    print(f"{report.frames} frames ({report.first_frame}-{report.last_frame}), {report.tracks} markers matched "
          f"({report.tracks / max(report.frames, 1):.1f} a frame)")
    print(f"{'camera':<16} {'status':<9} {'residual px':>11} {'matched':>8}")
    for h in report.cameras:
        print(f"{h.id:<16} {h.status:<9} {h.residual_px:>11.3f} {h.matched:>8.1%}")
    for h in report.moved:
        how = (f"drifting over {h.drift_frames} frames from frame {h.moved_at}" if h.kind == "drift"
               else f"moved before the take began (it disagrees with {args.result} from frame {h.moved_at})"
               if h.before_take else f"knocked at frame {h.moved_at}")
        print(f"{h.id}: {how}, named at frame {h.alarm.detected_frame}", end="")
        if h.resolved is not None:
            r = h.resolved
            print(f"; moved {r.moved_mm:.2f} mm (sigma {r.center_std_mm:.2f}) and turned {r.turned_deg:.3f} deg "
                  f"(sigma {r.rotation_std_deg:.3f}), re-solved from {r.points} markers at {r.rms_px:.2f} px")
        else:
            print("; too few markers after the move to re-solve it: record a longer take")
    if not report.moved:
        print("every camera agrees with the standing result")
    elif args.write is None:
        print(f"write the re-solved result with: wandcal watch {args.result} {args.take} --write OUT")


def _write(args, standing, take, report) -> None:
    import json

    from wandcal.capture.take_file import updated_result

    cameras = {}
    for h in report.moved:
        r = h.resolved
        if r is None:
            continue
        level = "good" if r.rms_px < 2 * max(h.residual_px, 0.1) else "poor"
        cameras[h.id] = {"R": r.R, "t": r.t, "center_std_mm": r.center_std_mm, "rotation_std_deg": r.rotation_std_deg,
                         "reprojection_rms_px": r.rms_px,
                         "verdict": {"level": level, "reasons": [f"re-solved from {r.points} markers of the take "
                                                                 f"{take.path} at {r.rms_px:.2f} px"]}}
    doc = updated_result(standing, take.path, cameras)
    args.write.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {args.write}: {', '.join(cameras) or 'no camera'} re-solved from the take")
