"""``wandcal import``: other tools' sessions and camera files as capture folders (docs/import.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from wandcal.service.cli.support.args import arg_number, arg_positive, arg_whole

MAX_IMAGE_HEIGHT = 65_535  # the largest image side any camera format here can hold (16-bit)


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("import", help="convert an easyWand, Argus, MultiCamSelfCal or anipose session, or a "
                       "camera file, to a capture folder",
                       description="Write a points-level wandcal-capture/1 folder from another tool's session "
                                   "and print what it found (docs/import.md).")
    if arguments:
        _formats(p)


def _formats(p: argparse.ArgumentParser) -> None:
    from wandcal.capture.formats.cameras_in import CAMERA_FORMATS

    formats = p.add_subparsers(dest="format", required=True, metavar="FORMAT")

    e = formats.add_parser("easywand", help="an easyWand session (*_easyWandData.mat) or its input files",
                           description="wandcal import easywand SESSION.mat --out CAPTURE, or wandcal import easywand "
                                       "--wand CSV --profile TXT --wand-length M [--background CSV] [--axis CSV] "
                                       "--out CAPTURE")
    e.add_argument("source", nargs="?", type=Path, metavar="SESSION.mat", help="easyWand's saved session")
    e.add_argument("--intrinsics", choices=("optimised", "profile"), default="optimised",
                   help="with a .mat: the intrinsics easyWand's result used (default) or the profile's estimates")
    e.add_argument("--wand", type=Path, metavar="CSV",
                   help="wand points (2 tracks, y-up pixels) instead of a .mat; leave out for background points only")
    e.add_argument("--profile", type=Path, metavar="TXT", help="camera profile, with --wand")
    e.add_argument("--wand-length", type=arg_positive, metavar="M", help="wand marker distance in metres, with --wand")
    e.add_argument("--background", type=Path, metavar="CSV", help="background (unpaired) points, with --wand")
    e.add_argument("--axis", type=Path, metavar="CSV", help="axis points (1-4 rows), with --wand")
    _common(e)
    e.set_defaults(run=run_import_easywand)

    a = formats.add_parser("argus", help="Argus Wand's -xypts.csv files and camera profile",
                           description="wandcal import argus PAIRED-xypts.csv --profile TXT --wand-length M "
                                       "[--unpaired CSV] [--reference CSV] --out CAPTURE")
    a.add_argument("source", type=Path, metavar="PAIRED-xypts.csv", help="the wand's two tracks")
    a.add_argument("--profile", type=Path, required=True, metavar="TXT", help="Argus camera profile, a row per camera")
    a.add_argument("--wand-length", type=arg_positive, required=True, metavar="M", help="wand marker distance, metres")
    a.add_argument("--unpaired", type=Path, metavar="CSV", help="unpaired points -xypts.csv (written to points.csv)")
    a.add_argument("--reference", type=Path, metavar="CSV", help="reference points -xypts.csv (1-4 axis points)")
    _common(a)
    a.set_defaults(run=run_import_argus)

    n = formats.add_parser("anipose", help="an anipose / aniposelib / Pose2Sim calibration.toml and 2D keypoints",
                           description="wandcal import anipose calibration.toml --points FILE [--points FILE ...] "
                                       "--out CAPTURE: the cameras from the TOML, labelled points from DeepLabCut "
                                       "CSVs (one per camera) or aniposelib's points array (.npy)")
    n.add_argument("source", type=Path, metavar="calibration.toml", help="the cameras ([cam_0], [cam_1], ...)")
    n.add_argument("--points", action="append", metavar="[CAMERA=]FILE",
                   help="2D keypoints: a DeepLabCut CSV per camera (repeat; matched by the camera name in the file "
                        "name, or CAMERA=FILE), or one aniposelib .npy array (cameras, frames, joints, 2)")
    n.add_argument("--unit", choices=("m", "mm"), default="m",
                   help="the TOML's translation unit (default m, as Pose2Sim; anipose uses its board's, often mm)")
    n.add_argument("--min-likelihood", type=arg_number(0.0, 1.0), default=None, metavar="P",
                   help="leave out DeepLabCut keypoints below this likelihood (default: DeepLabCut's pcutoff, 0.6)")
    n.add_argument("--out", type=Path, required=True, help="new capture folder")
    n.set_defaults(run=run_import_anipose)

    c = formats.add_parser("cameras", help="a camera file wandcal export writes, back as rig.json and poses.json",
                           description="wandcal import cameras FILE [--format F] --out FOLDER: rig.json (intrinsics) "
                                       "and poses.json (a wandcal-result/1 document) from an anipose TOML, OpenCV "
                                       "YAML, DLT CSV, Qualisys .qca or Vicon .xcp")
    c.add_argument("source", type=Path, metavar="FILE", help="the camera file")
    c.add_argument("--format", dest="camera_format", choices=CAMERA_FORMATS, default=None,
                   help="the file's format (default: from its extension)")
    c.add_argument("--unit", choices=("m", "mm"), default=None, help="anipose-toml and dlt-csv: length unit (default m)")
    c.add_argument("--origin", choices=("bottom-left", "top-left"), default="bottom-left",
                   help="dlt-csv: pixel origin the coefficients use (default bottom-left, DLTdv's)")
    c.add_argument("--size", action="append", type=_size, metavar="WxH",
                   help="dlt-csv: image size in pixels, once for all cameras or once per camera (repeat)")
    c.add_argument("--wand-length", type=arg_positive, metavar="M", help="write the wand into rig.json, metres")
    c.add_argument("--out", type=Path, required=True, help="new folder for rig.json and poses.json")
    c.set_defaults(run=run_import_cameras)

    s = formats.add_parser("svoboda", help="a MultiCamSelfCal folder (points.dat, IdMat.dat, Res.dat)",
                           description="wandcal import svoboda FOLDER --out CAPTURE [--focal-px F]")
    s.add_argument("source", type=Path, metavar="FOLDER", help="the MultiCamSelfCal data folder")
    s.add_argument("--focal-px", type=arg_positive, metavar="F",
                   help="focal length for cameras without a .rad file (centred principal point, no distortion)")
    s.add_argument("--out", type=Path, required=True, help="new capture folder")
    s.set_defaults(run=run_import_svoboda)


def _common(p) -> None:
    p.add_argument("--height", type=arg_whole(1, MAX_IMAGE_HEIGHT), metavar="H",
                   help="image height in pixels of every camera, when the session's is wrong")
    p.add_argument("--out", type=Path, required=True, help="new capture folder")


def run_import_easywand(args) -> int:
    from wandcal.capture.folder import CaptureFormatError
    from wandcal.capture.importers.easywand import read_easywand_files, read_easywand_mat

    files = {"--wand": args.wand, "--profile": args.profile, "--wand-length": args.wand_length,
             "--background": args.background, "--axis": args.axis}
    # a background-only session (no wand points) needs neither --wand nor --wand-length
    needed = ("--wand", "--profile", "--wand-length") if args.background is None or args.wand else ("--profile",)
    if args.source is not None:
        given = [k for k, v in files.items() if v is not None]
        if given:
            raise CaptureFormatError(f"{args.source}: a .mat session brings its own points and cameras; drop "
                                     f"{', '.join(given)} (or drop the .mat to import files)")
        imported = read_easywand_mat(args.source, args.intrinsics, args.height)
    else:
        missing = [k for k in needed if files[k] is None]
        if missing:
            raise CaptureFormatError(f"give an easyWand session (SESSION.mat), or its files: {', '.join(missing)} "
                                     "missing (a background-only session: --profile and --background)")
        if args.wand is None and args.wand_length is not None:
            raise CaptureFormatError("--wand-length without --wand: a background-only session has no wand; drop "
                                     "--wand-length or give the wand points")
        imported = read_easywand_files(args.wand, args.profile, args.wand_length, args.background, args.axis,
                                       args.height)
    return _write_import(imported, args.out)


def run_import_argus(args) -> int:
    from wandcal.capture.importers.argus import read_argus

    return _write_import(read_argus(args.source, args.profile, args.wand_length, args.unpaired, args.reference,
                                    args.height), args.out)


def run_import_anipose(args) -> int:
    from wandcal.capture.formats.cameras_in import write_poses
    from wandcal.capture.importers.anipose import read_anipose
    from wandcal.capture.importers.deeplabcut import DEFAULT_MIN_LIKELIHOOD

    likelihood = DEFAULT_MIN_LIKELIHOOD if args.min_likelihood is None else args.min_likelihood
    imported, posed = read_anipose(args.source, args.points, args.unit, likelihood)
    if imported.capture.points is None:
        from wandcal.capture.folder import CaptureFormatError

        raise CaptureFormatError(f"{args.source}: no --points given; give the 2D keypoints (a DeepLabCut CSV per "
                                 "camera, or aniposelib's .npy), or use 'wandcal import cameras' for the cameras alone")
    code = _write_import(imported, args.out)
    write_poses(args.out, posed, str(args.source))
    return code


def run_import_cameras(args) -> int:
    from wandcal.capture.folder import CaptureFormatError
    from wandcal.capture.formats.cameras_in import POSES_FILE, read_camera_file, write_cameras
    from wandcal.drivers.capture_files import RIG_FILE

    out = args.out
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CaptureFormatError(f"{out}: already exists and is not an empty folder; choose a new --out folder")
    posed = read_camera_file(args.source, args.camera_format, args.unit, args.origin, args.size)
    rig = write_cameras(out, posed, str(args.source), args.wand_length)
    print(f"read {args.source}")
    print(f"cameras: {len(rig.cameras)}")
    for cam, C in zip(rig.cameras, posed.centers):
        print(f"  {cam.id}: {cam.width}x{cam.height} px, f = {cam.K[0, 0]:.1f} px, centre "
              f"({C[0]:.4f}, {C[1]:.4f}, {C[2]:.4f}) m")
    print(f"wrote {out / RIG_FILE} and {out / POSES_FILE}")
    return 0


def _size(text: str) -> tuple[int, int]:
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or min(size) <= 0 or max(size) > MAX_IMAGE_HEIGHT:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT in pixels (1 to {MAX_IMAGE_HEIGHT}), e.g. 1920x1080")
    return size


def run_import_svoboda(args) -> int:
    from wandcal.capture.importers.svoboda import read_svoboda

    return _write_import(read_svoboda(args.source, args.focal_px), args.out)


def _write_import(imported, out: Path) -> int:
    from wandcal.capture.folder import CaptureFormatError, save_capture
    from wandcal.capture.importers import summary_lines
    from wandcal.capture.rig_file import CAPTURE_FORMAT

    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CaptureFormatError(f"{out}: already exists and is not an empty folder; choose a new --out folder")
    save_capture(out, imported.capture)
    for line in summary_lines(imported):
        print(line)
    print(f"wrote {out} ({CAPTURE_FORMAT})")
    return 0

