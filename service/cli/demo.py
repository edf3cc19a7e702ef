"""``wandcal demo``: simulate a rig, calibrate it and compare the result with the simulator's truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from wandcal.service.cli.simulate import sim_args, simulated, write_simulated


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("demo", help="simulate a rig, calibrate it and compare with the truth")
    p.set_defaults(run=run_demo)
    if arguments:
        from wandcal.calib.run.options import DEFAULT_METHOD, METHODS

        sim_args(p, cameras=6, frames=800)
        p.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                       help=f"the calibration method (default {DEFAULT_METHOD})")
        p.add_argument("--keep", type=Path,
                       help="also keep the simulated capture and result in this folder (default: a temporary one)")
        p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")


def run_demo(args) -> int:
    import json
    import tempfile

    from wandcal.calib.run.calibrate import calibrate
    from wandcal.calib.run.options import CalibrationOptions
    from wandcal.capture.folder import read_capture
    from wandcal.service.cli.support.progress import ProgressLine
    from wandcal.service.cli.support.summary import format_summary, truth_table

    sim = simulated(args)
    print(
        f"simulated {args.cameras} cameras, {args.frames} wand frames, {args.noise} px noise, "
        f"{'an L-frame' if not args.no_static else 'no static object'}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        write_simulated(folder, sim)
        cap = read_capture(folder)
        progress = ProgressLine(quiet=args.quiet)
        try:
            result = calibrate(cap.rig, cap.wand, cap.static, options=CalibrationOptions(method=args.method),
                               progress=progress)
        finally:
            progress.close()
        (folder / "result.json").write_text(json.dumps(result.to_json(), indent=2) + "\n")
    print(format_summary(result.to_json()))
    print(truth_table(result, sim))
    return 0
