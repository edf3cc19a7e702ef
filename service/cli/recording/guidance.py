"""``wandcal guidance CAPTURE``, and the guidance lines ``wandcal capture`` prints as it records."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from wandcal.service.cli.support.args import arg_number, arg_positive

if TYPE_CHECKING:
    from wandcal.calib.run.guidance import GuidanceSettings

COVERED, EMPTY = "#", "."  # a coverage grid cell with / without wand samples, in the printed grids


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("guidance", help="judge a capture's wanding: per camera coverage, links and "
                       "predicted centre 1-sigma; enough?",
                       description="Print the wanding guidance of a points-level capture (docs/api.md, "
                                   "'Guidance'): where each camera still needs the wand, and whether the "
                                   "capture is enough.")
    p.set_defaults(run=run_guidance)
    if arguments:
        p.add_argument("capture", type=Path, help="points-level capture folder (rig.json, wand.csv)")
        add_guidance_options(p)
        p.add_argument("--grid", action="store_true", help="also draw each camera's coverage grid")
        p.add_argument("--json", action="store_true", help="print the wandcal-guidance/1 document instead")


def add_guidance_options(p: argparse.ArgumentParser) -> None:
    """The guidance's goal, shared by ``wandcal guidance`` and ``wandcal capture``."""
    from wandcal.calib.run.guidance import DEFAULT_MIN_COVERAGE, DEFAULT_TARGET_STD_MM

    p.add_argument("--target-mm", type=arg_positive, default=DEFAULT_TARGET_STD_MM, metavar="MM",
                   help=f"enough when every camera's predicted centre 1-sigma is below this (default "
                        f"{DEFAULT_TARGET_STD_MM:g} mm)")
    p.add_argument("--min-coverage", type=arg_number(0, 1), default=DEFAULT_MIN_COVERAGE, metavar="SHARE",
                   help=f"... and its image grid is covered at least this much, 0-1 (default {DEFAULT_MIN_COVERAGE:g})")
    p.add_argument("--sync", choices=("none", "auto"), default="none",
                   help="auto: cameras without a trigger, judged with their frames realigned by the offsets found "
                        "from the wand, as calibrate --sync auto does (default none: a camera out of time is a fault)")


def settings_from(args) -> GuidanceSettings:
    from wandcal.calib.run.guidance import GuidanceSettings

    return GuidanceSettings(target_std_mm=args.target_mm, min_coverage=args.min_coverage, sync=args.sync)


def run_guidance(args) -> int:
    import json

    from wandcal.calib.run.guidance import wanding_guidance
    from wandcal.capture.folder import read_capture

    capture = read_capture(args.capture)
    points_only = capture.rig.wand_length is None and capture.points is not None and len(capture.points) > 0
    if not points_only and (capture.rig.wand_length is None or capture.wand is None or not len(capture.wand)):
        from wandcal.calib.errors import CalibrationError

        raise CalibrationError(f"{args.capture}: has no wand (rig.json gives no wand, or wand.csv has no blobs), "
                               "and the guidance counts wand samples (or, on a rig without a wand, points.csv's points); "
                               f"calibrate a point-track session directly with 'wandcal calibrate {args.capture}'")
    document = wanding_guidance(capture.rig, capture.wand, capture.static, settings_from(args),
                                points=capture.points if points_only else None).document
    if args.json:
        print(json.dumps(document, indent=2))
        return 0
    for line in guidance_lines(document, grids=args.grid):
        print(line)
    return 0


def _sigma(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def summary(document: dict) -> str:
    """One line for a status display: the worst sigma and coverage, and the verdict."""
    cams = document["cameras"]
    solved = [(c["center_std_mm"], c["id"]) for c in cams if c["center_std_mm"] is not None]
    worst = max(solved) if solved else None
    sigma = f"worst σ {worst[0]:.2f} mm ({worst[1]})" if worst else "σ: not solved yet"
    cov, cid = min((c["coverage"], c["id"]) for c in cams)
    needing = sum(1 for c in cams if c.get("advice"))  # a camera's own advice; the rig-wide kind is no camera's
    if document["enough"]:
        verdict = "ENOUGH: you can stop"
    elif needing:
        verdict = f"{needing} of {len(cams)} camera(s) need more"
    else:
        verdict = "not enough yet (the rig's advice is above)"
    return f"{sigma} · least covered {cov:.0%} ({cid}) · {verdict}"


def guidance_lines(document: dict, grids: bool = False) -> list[str]:
    """The per-camera table, the verdict and the advice, worst first."""
    target = document["target"]
    # frames: in which the camera saw both wand ends (a capture's "frames delivered" counts every frame)
    lines = [f"{'camera':<10} {'both ends':>9} {'shared':>7} {'coverage':>9} {'centre σ mm':>12}  linked most with"]
    for c in document["cameras"]:
        best = sorted(c["linked"].items(), key=lambda kv: -kv[1])[:2]
        links = ", ".join(f"{d} {n}" for d, n in best)
        lines.append(f"{c['id']:<10} {c['frames']:>9} {c['shared_frames']:>7} {c['coverage']:>9.0%} "
                     f"{_sigma(c['center_std_mm']):>12}  {links}")
        if grids:
            lines += [f"{'':<10} {''.join(COVERED if n else EMPTY for n in row)}" for row in c["grid"]]
    solve = document["solve"]
    if not solve["ok"]:
        lines.append(f"fast solve: {solve['message']}")
    goal = f"every camera's centre σ below {target['center_std_mm']:g} mm and coverage at least {target['coverage']:.0%}"
    if document["enough"]:
        lines.append(f"enough: yes, you can stop waving ({goal})")
    else:
        lines.append(f"enough: not yet ({goal}); what to do, worst first:")
        lines += [f"  {k}. {a}" for k, a in enumerate(document["advice"], 1)]
    return lines
