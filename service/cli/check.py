"""``wandcal check RESULT CAPTURE``: did any camera of a result move? Each camera judged against a fresh
capture: the wand (any kind) and the point tracks (calib/judge/bumps.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

EXIT_MOVED = 1  # wandcal check: a camera moved (named)
EXIT_UNJUDGED = 3  # wandcal check: some camera could not be judged, and none was seen to move


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("check", help="judge a result's cameras against a fresh capture (wand or points): did any move?",
                       epilog="exit status: 0 every camera agrees; 1 a camera moved (named, with the command to re-solve "
                       "it); 2 bad input, or a capture of another rig; 3 no answer: some camera could not be judged, "
                       "or no knock explains the disagreement: most cameras disagree, or a camera placed again lies farther from "
                       "its pose than a knock moves one (another rig or rebuilt: calibrate afresh)")
    p.set_defaults(run=run_check)
    if arguments:
        p.add_argument("result", type=Path, help="wandcal-result/1 file")
        p.add_argument("capture", type=Path, help="a fresh capture of the same rig: the wand, points.csv, or both")
        p.add_argument("--json", action="store_true", help='print {"cameras": [{"id", "moved", "rms_px", ...}]}')


def run_check(args) -> int:
    import json

    import numpy as np

    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.judge.bumps import check_rig
    from wandcal.capture.folder import read_capture
    from wandcal.service.cli.support.inputs import points_level, result_for
    from wandcal.service.cli.support.progress import ProgressLine

    folder = points_level(args.capture, ProgressLine(quiet=True))
    cap = read_capture(folder)
    has_wand = cap.wand is not None and len(cap.wand) > 0 and cap.rig.wand_length is not None
    if not has_wand and (cap.points is None or not len(cap.points)):
        raise CalibrationError(f"{args.capture}: has no wand blobs and no point tracks (points.csv); 'wandcal check' needs "
                               "a fresh capture of the wand or of points seen by several cameras at once")
    _, rig, R, t, entries = result_for(args.result, cap)
    expected = np.array([e.reprojection_rms_px or np.nan for e in entries], float)
    found = check_rig(rig, R, t, cap.wand if has_wand else None, None if np.isnan(expected).any() else expected,
                      cap.points)
    checks = found.cameras
    moved = [c.id for c in checks if c.moved]
    unjudged = [c.id for c in checks if c.moved is None]
    if args.json:
        print(json.dumps({"cameras": [vars(c) for c in checks], "moved": moved, "unjudged": unjudged,
                          "rebuilt": found.rebuilt, "rebuilt_why": found.why}, indent=2))
    else:
        _print(args, checks, found, moved, unjudged)
    return EXIT_UNJUDGED if found.rebuilt else EXIT_MOVED if moved else EXIT_UNJUDGED if unjudged else 0


def _print(args, checks, found, moved: list[str], unjudged: list[str]) -> None:
    """The human answer: each camera, then what to do."""
    from wandcal.calib.rig import camera_list

    for c in checks:
        mark = ("OFF" if found.rebuilt else "MOVED") if c.moved else ("?" if c.moved is None else "ok")
        print(f"{c.id:<16} {mark:<6} {c.reason}")
    if found.rebuilt:
        print(f"no knock explains this ({'; '.join(found.why)}): this is not a bumped camera but a rebuilt rig or a "
              f"capture of another one; calibrate afresh: wandcal calibrate {args.capture}")
    elif moved:
        print(f"moved: {camera_list(moved, len(checks))}; recalibrate with: wandcal calibrate {args.capture} --from {args.result} "
              f"--solve-only {','.join(moved)}")
    if unjudged and not found.rebuilt:
        print(f"could not judge {camera_list(unjudged, len(checks))}: too few frames shared with two other cameras; record a longer "
              "wand capture where every camera sees the wand with two others")
    elif not moved and not unjudged:
        print("every camera agrees with the others")
