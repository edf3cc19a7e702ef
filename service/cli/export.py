"""``wandcal export``: a result file in another tool's format (docs/formats.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("export", help="write a result in another tool's format (anipose, OpenCV, DLT, Qualisys, Vicon)",
                       description="Formats and their conventions: docs/formats.md.")
    p.set_defaults(run=run_export)
    if arguments:
        _arguments(p)


def _arguments(p: argparse.ArgumentParser) -> None:
    from wandcal.capture.formats.export import BOTTOM_LEFT, FORMAT_NAMES, TOP_LEFT, UNITS

    p.add_argument("result", type=Path, help="wandcal-result/1 file written by 'wandcal calibrate'")
    p.add_argument("--format", required=True, choices=FORMAT_NAMES, help="the format to write")
    p.add_argument("--out", type=Path, help="file to write (default: standard output)")
    p.add_argument("--unit", choices=tuple(UNITS),
                   help="length unit of positions (default: the format's own; qca and xcp are always mm)")
    p.add_argument("--origin", choices=(BOTTOM_LEFT, TOP_LEFT),
                   help="dlt-csv: the pixel origin the coefficients expect (default bottom-left, y up, as DLTdv, "
                        "easyWand and Argus digitise)")


def run_export(args) -> int:
    from wandcal.capture.folder import CaptureFormatError
    from wandcal.capture.formats.export import export
    from wandcal.capture.result_file import read_result

    result = read_result(args.result)
    text = export(result.doc, args.format, result.rig, unit=args.unit, origin=args.origin)
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        args.out.write_text(text)
    except OSError as exc:
        raise CaptureFormatError(f"{args.out}: cannot write the {args.format} file ({exc.strerror or exc}); "
                                 "choose a path in a folder you can write to") from None
    print(f"wrote {args.out} ({args.format})")
    return 0
