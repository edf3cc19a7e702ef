"""``wandcal detect CAPTURE``: blob detection over an image-level capture; and the blob detector's
options, which ``wandcal capture`` shares.

Every option maps onto one field of :class:`wandcal.calib.detect.config.DetectConfig`, whose defaults
the help texts quote; ``--background`` and ``--mask`` also name where a camera's empty-volume
recording and masks come from (docs/capture-format.md, "Detection inputs").
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from wandcal.service.cli.support.args import arg_number, arg_whole

if TYPE_CHECKING:
    from wandcal.calib.detect.config import Background, DetectConfig

MAX_WORKERS = 256


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("detect", help="detect blobs in an image-level capture and write wand.csv",
                       description="Run blob detection over frames/ and static/ of a capture folder.")
    p.set_defaults(run=run_detect)
    if arguments:
        p.add_argument("capture", type=Path, help="image-level capture folder")
        p.add_argument("--workers", type=arg_whole(1, MAX_WORKERS), default=None, metavar="N",
                       help=f"threads that decode and detect images, 1 to {MAX_WORKERS} (default: every core)")
        p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")
        add_detect_options(p)


def run_detect(args) -> int:
    from wandcal.capture.folder import read_rig
    from wandcal.capture.images import detect_capture
    from wandcal.drivers.capture_files import WAND_FILE
    from wandcal.service.cli.support.progress import ProgressLine, bar

    config = config_from_args(args)
    with ProgressLine(quiet=args.quiet) as status:
        reports = detect_capture(args.capture, config, workers=args.workers,
                                 progress=lambda p: status.update(f"detect {bar(p['done'], p['total'])}"),
                                 mask=mask_from_args(args), empty=args.background.folder)
        status.done(f"detect: done, wrote {args.capture / WAND_FILE} ({config.describe()})")
    rig = read_rig(args.capture)
    expected = None if rig.static_markers is None else len(rig.static_markers)
    for r in reports:
        if r.setup is not None and (r.setup.mask_source or r.setup.empty_frames):
            print(r.setup.line())
        print(r.line(expected))
    return 0


MAX_GREY = 65_535  # the brightest level of a 16-bit frame: a threshold above it finds nothing


@dataclass(frozen=True)
class BackgroundChoice:
    """A parsed ``--background``: the model, its parameter, and an empty-volume folder."""

    model: str
    value: float | None = None
    folder: Path | None = None


def parse_background(text: str) -> BackgroundChoice:
    """``auto``, ``none``, ``highpass[:PX]``, ``running[:FRAMES]`` or ``empty[:FOLDER]``."""
    model, _, rest = text.partition(":")
    if model in ("auto", "none") and not rest:
        return BackgroundChoice(model)
    if model == "empty":
        return BackgroundChoice(model, folder=Path(rest) if rest else None)
    if model in ("highpass", "running"):
        if not rest:
            return BackgroundChoice(model)
        try:
            value = float(rest)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}: {rest!r} is not a number") from None
        if model == "highpass" and not (value.is_integer() and value >= 1):
            raise argparse.ArgumentTypeError(f"{text!r}: the high-pass half-width is a whole number of pixels >= 1")
        if model == "running" and not 1 < value < float("inf"):
            raise argparse.ArgumentTypeError(f"{text!r}: the running average's time constant is a number of "
                                             "frames > 1")
        return BackgroundChoice(model, value)
    raise argparse.ArgumentTypeError(f"{text!r}: choose auto, none, highpass[:PX], running[:FRAMES] or "
                                     "empty[:FOLDER]")


def _threshold(text: str) -> int | None:
    if text == "auto":
        return None
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: give a whole grey level >= 0, or 'auto'") from None
    if not 0 <= value <= MAX_GREY:
        raise argparse.ArgumentTypeError(f"{text!r}: give a whole grey level from 0 to {MAX_GREY}, or 'auto'")
    return value


def _roundness(text: str) -> float | None:
    if text == "auto":
        return None
    return arg_number(0.0, 1.0)(text)


def add_detect_options(p: argparse.ArgumentParser, live: bool = False) -> None:
    """The detector's options; ``live`` leaves out the per-camera ones (masks, empty volume)."""
    from wandcal.calib.detect.config import CLUTTER_MIN_ROUNDNESS, DEFAULT_CONFIG, MARKER_MIN_ROUNDNESS

    d = DEFAULT_CONFIG
    g = p.add_argument_group("blob detection", "settings of the marker detector (docs/capture-format.md, "
                                               "'Detection'); defaults work on dark IR frames and on frames with glare")
    g.add_argument("--threshold", type=_threshold, default=d.threshold, metavar="GREY",
                   help="grey level a blob pixel must exceed, after the background is subtracted, or 'auto' "
                        "(default: auto, 6 noise sigmas above the background)")
    g.add_argument("--seed-ratio", type=arg_number(1.0), default=d.seed_ratio, metavar="R",
                   help="each 4-connected piece of a blob must reach R x threshold (hysteresis; OpenPTV uses 2; "
                        f"default {d.seed_ratio:g}: off)")
    g.add_argument("--min-area", type=arg_whole(1), default=d.min_area_px, metavar="PX",
                   help=f"smallest blob in pixels (default {d.min_area_px})")
    g.add_argument("--max-area", type=arg_whole(1), default=d.max_area_px, metavar="PX",
                   help=f"largest blob in pixels (default {d.max_area_px})")
    g.add_argument("--min-roundness", type=_roundness, default=d.min_roundness, metavar="R",
                   help=f"smallest minor/major axis ratio, 0-1, or 'auto' (default: auto, {MARKER_MIN_ROUNDNESS:g} "
                        f"on a flat background, {CLUTTER_MIN_ROUNDNESS:g} where the high-pass is used; 0 keeps "
                        "streaks)")
    g.add_argument("--connectivity", type=int, choices=(4, 8), default=d.connectivity,
                   help=f"pixels touching at a corner join a blob with 8 (default {d.connectivity})")
    g.add_argument("--weights", choices=("excess", "signal"), default=d.weights,
                   help="centroid weights: grey level above the threshold (excess, default) or the grey level "
                        "itself (signal, as OpenPTV)")
    empty = "empty:FOLDER (a recording of the empty volume)" if live else "empty[:FOLDER]"
    g.add_argument("--background", type=parse_background, default=BackgroundChoice(d.background), metavar="MODEL",
                   help=f"what to subtract before thresholding: auto, none, highpass[:PX], running[:FRAMES] or "
                        f"{empty} (default {d.background}: a high-pass where the background is uneven; PX: "
                        f"half-width, default {d.highpass_px})")
    if live:
        g.add_argument("--mask", default="none", metavar="none|DIR",
                       help="pixels to ignore per camera: DIR/<camera>.png (black = ignored; make them from a "
                            "recording of the empty volume with 'wandcal detect EMPTY --mask auto', then give "
                            "EMPTY/masks) or 'none' (default)")
    else:
        g.add_argument("--mask", default="folder", metavar="auto|none|DIR",
                       help="pixels to ignore per camera: DIR/<camera>.png (black = ignored), 'auto' (block what "
                            "is bright in the empty-volume recording, saved to masks/) or 'none' (default: the "
                            "capture's masks/ where present)")


def config_from_args(args, live: bool = False) -> DetectConfig:
    """The :class:`DetectConfig` the options ask for (a bad combination raises CalibrationError)."""
    from wandcal.calib.detect.config import DetectConfig
    from wandcal.calib.errors import CalibrationError

    choice: BackgroundChoice = args.background
    if live and choice.model == "empty" and choice.folder is None:
        raise CalibrationError("--background empty: a live capture has no empty-volume recording of its own yet; "
                               "record one first (no markers in view) and give its folder: --background empty:FOLDER")
    if live and args.mask == "auto":
        raise CalibrationError("--mask auto: a live capture has no empty-volume recording of its own; record one, run "
                               "'wandcal detect EMPTY --mask auto' on it, then capture with --mask EMPTY/masks")
    extra: dict[str, Any] = {}
    if choice.model == "highpass" and choice.value is not None:
        extra["highpass_px"] = int(choice.value)
    if choice.model == "running" and choice.value is not None:
        extra["running_frames"] = choice.value
    return DetectConfig(threshold=args.threshold, seed_ratio=args.seed_ratio, min_area_px=args.min_area,
                        max_area_px=args.max_area, min_roundness=args.min_roundness,
                        connectivity=args.connectivity, weights=args.weights, background=cast("Background", choice.model),
                        **extra)


def mask_from_args(args) -> str | Path:
    """``--mask`` as :func:`wandcal.capture.detect_setup.camera_detectors` takes it."""
    from wandcal.capture.detect_setup import MASK_AUTO, MASK_FOLDER, MASK_NONE

    return args.mask if args.mask in (MASK_FOLDER, MASK_NONE, MASK_AUTO) else Path(args.mask)
