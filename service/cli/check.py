"""``wandcal check RESULT CAPTURE``: did any camera of a result move? Each camera judged against a fresh
capture: the wand (any kind) and the point tracks (calib/judge/bumps.py)."""

from __future__ import annotations

import argparse
from pathlib import Path

# the exit statuses (0 agrees, 1 moved, 3 no answer) are wandcal.service.standing_result's, which the
# HTTP check answers with too; imported when the command runs (--help loads no numerical package)


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

    from wandcal.capture.folder import read_capture
    from wandcal.capture.result_file import read_result
    from wandcal.service.cli.support.inputs import points_level
    from wandcal.service.cli.support.progress import ProgressLine
    from wandcal.service.standing_result import check_capture, checkable

    folder = points_level(args.capture, ProgressLine(quiet=True))
    cap = read_capture(folder)
    checkable(cap, str(args.capture))  # before the result is read, as always
    answer = check_capture(read_result(args.result), cap, str(args.result), str(args.capture))
    if args.json:
        print(json.dumps(answer.document(), indent=2))
    else:
        _print(args, answer.found.cameras, answer.found, answer.moved, answer.unjudged)
    return answer.exit_code


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
