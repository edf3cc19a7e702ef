"""``wandcal check RESULT CAPTURE``: did any camera of a result move? Each camera judged against a fresh
wand capture."""

from __future__ import annotations

import argparse
from pathlib import Path

EXIT_MOVED = 1  # wandcal check: a camera moved (named)
EXIT_UNJUDGED = 3  # wandcal check: some camera could not be judged, and none was seen to move


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("check", help="judge a result's cameras against a fresh wand capture: did any move?",
                       epilog="exit status: 0 every camera agrees; 1 a camera moved (named, with the command to re-solve "
                       "it); 2 bad input, or a capture of another rig; 3 no answer: some camera could not be judged, "
                       "or most cameras disagree (the rig was rebuilt: calibrate afresh)")
    p.set_defaults(run=run_check)
    if arguments:
        p.add_argument("result", type=Path, help="wandcal-result/1 file")
        p.add_argument("capture", type=Path, help="a fresh wand capture of the same rig")
        p.add_argument("--json", action="store_true", help='print {"cameras": [{"id", "moved", "rms_px", ...}]}')


def run_check(args) -> int:
    import json

    import numpy as np

    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.judge.evaluate import check_cameras
    from wandcal.calib.rig import camera_list
    from wandcal.capture.folder import read_capture
    from wandcal.service.cli.support.inputs import points_level, result_for
    from wandcal.service.cli.support.progress import ProgressLine

    folder = points_level(args.capture, ProgressLine(quiet=True))
    cap = read_capture(folder)
    if cap.wand is None or not len(cap.wand) or cap.rig.wand_length is None:
        raise CalibrationError(f"{args.capture}: has no wand blobs; 'wandcal check' needs a fresh wand capture")
    _, rig, R, t, entries = result_for(args.result, cap)
    expected = np.array([e.reprojection_rms_px or np.nan for e in entries], float)
    checks = check_cameras(rig, R, t, cap.wand, None if np.isnan(expected).any() else expected)
    moved = [c.id for c in checks if c.moved]
    unjudged = [c.id for c in checks if c.moved is None]
    rebuilt = len(moved) > len(checks) / 2  # a bump moves a camera or two; most of them is another rig
    if args.json:
        print(json.dumps({"cameras": [vars(c) for c in checks], "moved": moved, "unjudged": unjudged,
                          "rebuilt": rebuilt}, indent=2))
    else:
        for c in checks:
            mark = "MOVED" if c.moved else ("?" if c.moved is None else "ok")
            print(f"{c.id:<16} {mark:<6} {c.reason}")
        if rebuilt:
            print(f"most cameras disagree with the result ({camera_list(moved, len(checks))}): this is not a bumped camera but a "
                  f"rebuilt rig or a capture of another one; calibrate afresh: wandcal calibrate {args.capture}")
        elif moved:
            print(f"moved: {camera_list(moved, len(checks))}; recalibrate with: wandcal calibrate {args.capture} --from {args.result} "
                  f"--solve-only {','.join(moved)}")
        if unjudged:
            print(f"could not judge {camera_list(unjudged, len(checks))}: too few frames shared with two other cameras; record a longer "
                  "wand capture where every camera sees the wand with two others")
        elif not moved:
            print("every camera agrees with the others")
    return EXIT_UNJUDGED if rebuilt else EXIT_MOVED if moved else EXIT_UNJUDGED if unjudged else 0
