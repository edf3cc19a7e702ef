"""``wandcal report RESULT [--capture CAPTURE] --out DIR``: the illustrated report of a calibration."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("report", help="draw an illustrated report of a result: index.html and PNG figures")
    p.set_defaults(run=run_report)
    if arguments:
        p.add_argument("result", type=Path, help="a wandcal-result/1 file written by 'wandcal calibrate'")
        p.add_argument("--capture", type=Path, help="the capture folder the result came from (residuals, coverage, wand; default: "
                       "none, the result's own figures only)")
        p.add_argument("--out", type=Path, required=True, help="folder to write index.html and the figures into")


def run_report(args) -> int:
    from wandcal.capture.folder import read_capture
    from wandcal.capture.result_file import read_result
    from wandcal.service.report import ReportUnavailable, require_matplotlib, write_report

    try:
        require_matplotlib()
    except ReportUnavailable as exc:
        print(f"wandcal report: error: {exc}", file=sys.stderr)
        return 2
    result = read_result(args.result)
    capture = read_capture(args.capture) if args.capture is not None else None
    files = write_report(result, capture, args.out)
    print(f"wrote {files[0]} and {len(files) - 1} figure(s); open it in a web browser")
    return 0
