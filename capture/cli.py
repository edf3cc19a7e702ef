"""``wandcal capture``, ``wandcal detect``, ``wandcal import`` and ``wandcal trigger-emulator``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from wandcal.calib.rig import Rig
from wandcal.capture.detect_cli import add_detect_options
from wandcal.capture.folder import read_rig
from wandcal.capture.guidance_cli import add_guidance_options, positive_number
from wandcal.capture.progress import StatusLine, bar
from wandcal.drivers.camera import CameraDriver
from wandcal.drivers.errors import DriverError

DEFAULT_WAND_LENGTH_M = 0.5


def register(subparsers) -> None:
    p = subparsers.add_parser("capture", help="record synchronised frames from cameras and a strobe trigger",
                              description="Record a wandcal-capture/1 folder: every frame's blob centroids "
                                          "(the points level, written as it goes) and the images --images asks "
                                          "for, with the wanding guidance on the status line.")
    p.add_argument("--camera", action="append", required=True, metavar="URL",
                   help="camera URL (repeat): v4l2:///dev/video0, opencv:0, replay:///path, sim://?cameras=4")
    p.add_argument("--trigger", default="none", metavar="URL",
                   help="strobe trigger: serial:///dev/ttyACM0, a device path, or 'none' (default)")
    p.add_argument("--frames", type=_count(1), required=True, help="wand frame sets to record")
    p.add_argument("--static-frames", type=_count(0), default=0, metavar="K",
                   help="first record K frame sets of the static object (L-frame) alone")
    p.add_argument("--rate", type=float, default=100.0, help="trigger / frame rate in Hz (default 100)")
    p.add_argument("--rig", type=Path, help="rig.json with the cameras' intrinsics (simulated and replayed "
                   "cameras bring their own)")
    p.add_argument("--wand-length", type=float, default=None, help="wand marker distance in metres")
    p.add_argument("--out", type=Path, required=True, help="new capture folder")
    p.add_argument("--images", type=_image_policy, default="all", metavar="WHICH",
                   help="images written beside the centroids: all (default), none, static (the static recording "
                        "only) or N (every N-th wand set); 'none' keeps up with 8 cameras at 100 fps")
    p.add_argument("--no-guidance", dest="guidance", action="store_false",
                   help="do not solve the wanding guidance while recording")
    p.add_argument("--stop-when-enough", action="store_true",
                   help="end the wand run, keeping it, as soon as the guidance says enough")
    add_guidance_options(p)
    add_detect_options(p, live=True)
    p.set_defaults(run=run_capture)

    p = subparsers.add_parser("detect", help="detect blobs in an image-level capture and write wand.csv",
                              description="Run blob detection over frames/ and static/ of a capture folder.")
    p.add_argument("capture", type=Path, help="image-level capture folder")
    p.add_argument("--workers", type=_count(1), default=None,
                   help="threads that decode and detect images (default: every core)")
    add_detect_options(p)
    p.set_defaults(run=run_detect)

    _register_import(subparsers)

    p = subparsers.add_parser("trigger-emulator", help="emulate the strobe trigger on a pseudo-terminal",
                              description="Speak wandcal-trigger/1 on a new pseudo-terminal; prints its path.")
    p.add_argument("--vanish-after", type=int, default=None, metavar="N",
                   help="close the terminal after N pulses, as if the board were unplugged")
    p.add_argument("--start-us", type=int, default=0, help="device clock at start (near 4294967295 tests the wrap)")
    p.set_defaults(run=run_emulator)


def _register_import(subparsers) -> None:
    from wandcal.capture.formats.cameras_in import CAMERA_FORMATS

    p = subparsers.add_parser("import", help="convert an easyWand, Argus, MultiCamSelfCal or anipose session, or a "
                              "camera file, to a capture folder",
                              description="Write a points-level wandcal-capture/1 folder from another tool's session "
                                          "and print what it found (docs/import.md).")
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
    e.add_argument("--wand-length", type=positive_number, metavar="M", help="wand marker distance in metres, with --wand")
    e.add_argument("--background", type=Path, metavar="CSV", help="background (unpaired) points, with --wand")
    e.add_argument("--axis", type=Path, metavar="CSV", help="axis points (1-4 rows), with --wand")
    _common(e)
    e.set_defaults(run=run_import_easywand)

    a = formats.add_parser("argus", help="Argus Wand's -xypts.csv files and camera profile",
                           description="wandcal import argus PAIRED-xypts.csv --profile TXT --wand-length M "
                                       "[--unpaired CSV] [--reference CSV] --out CAPTURE")
    a.add_argument("source", type=Path, metavar="PAIRED-xypts.csv", help="the wand's two tracks")
    a.add_argument("--profile", type=Path, required=True, metavar="TXT", help="Argus camera profile, a row per camera")
    a.add_argument("--wand-length", type=positive_number, required=True, metavar="M", help="wand marker distance, metres")
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
    n.add_argument("--min-likelihood", type=float, default=None, metavar="P",
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
    c.add_argument("--wand-length", type=positive_number, metavar="M", help="write the wand into rig.json, metres")
    c.add_argument("--out", type=Path, required=True, help="new folder for rig.json and poses.json")
    c.set_defaults(run=run_import_cameras)

    s = formats.add_parser("svoboda", help="a MultiCamSelfCal folder (points.dat, IdMat.dat, Res.dat)",
                           description="wandcal import svoboda FOLDER --out CAPTURE [--focal-px F]")
    s.add_argument("source", type=Path, metavar="FOLDER", help="the MultiCamSelfCal data folder")
    s.add_argument("--focal-px", type=positive_number, metavar="F",
                   help="focal length for cameras without a .rad file (centred principal point, no distortion)")
    s.add_argument("--out", type=Path, required=True, help="new capture folder")
    s.set_defaults(run=run_import_svoboda)


def _live_detectors(args, rig: Rig, config):
    """The capture loop's detectors: one config for every camera, or, with masks or a per-camera
    background model (an empty-volume recording, a running average), one detector per camera."""
    from wandcal.calib.detect import STATEFUL
    from wandcal.capture.detect_cli import mask_from_args
    from wandcal.capture.detect_setup import MASK_NONE, camera_detectors

    mask = mask_from_args(args)
    if mask == MASK_NONE and config.background not in STATEFUL:
        return config
    detectors, setups = camera_detectors(args.out, rig, config, mask=mask, empty=args.background.folder)
    for setup in setups:
        print(setup.line(), file=sys.stderr)
    return [detectors[cid] for cid in rig.ids]


def _common(p) -> None:
    p.add_argument("--height", type=_count(1), metavar="H",
                   help="image height in pixels of every camera, when the session's is wrong")
    p.add_argument("--out", type=Path, required=True, help="new capture folder")


def run_import_easywand(args) -> int:
    from wandcal.capture.folder import CaptureFormatError
    from wandcal.capture.formats.easywand import read_easywand_files, read_easywand_mat

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
    from wandcal.capture.formats.argus import read_argus

    return _write_import(read_argus(args.source, args.profile, args.wand_length, args.unpaired, args.reference,
                                    args.height), args.out)


def run_import_anipose(args) -> int:
    from wandcal.capture.formats.anipose import read_anipose
    from wandcal.capture.formats.cameras_in import write_poses
    from wandcal.capture.formats.deeplabcut import DEFAULT_MIN_LIKELIHOOD

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
    print(f"wrote {out / 'rig.json'} and {out / POSES_FILE}")
    return 0


def _size(text: str) -> tuple[int, int]:
    w, sep, h = text.lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = (0, 0)
    if not sep or min(size) <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT in pixels, e.g. 1920x1080")
    return size


def run_import_svoboda(args) -> int:
    from wandcal.capture.formats.svoboda import read_svoboda

    return _write_import(read_svoboda(args.source, args.focal_px), args.out)


def _write_import(imported, out: Path) -> int:
    from wandcal.capture.folder import CAPTURE_FORMAT, CaptureFormatError, save_capture
    from wandcal.capture.formats import summary_lines

    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise CaptureFormatError(f"{out}: already exists and is not an empty folder; choose a new --out folder")
    save_capture(out, imported.capture)
    for line in summary_lines(imported):
        print(line)
    print(f"wrote {out} ({CAPTURE_FORMAT})")
    return 0


def _count(low: int):
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {value}")
        return value

    return parse


def run_emulator(args) -> int:
    from wandcal.drivers.trigger_emulator import serve_pty

    return serve_pty(vanish_after=args.vanish_after, start_us=args.start_us)


def run_detect(args) -> int:
    from wandcal.capture.detect_cli import config_from_args, mask_from_args
    from wandcal.capture.images import detect_capture

    config = config_from_args(args)
    status = StatusLine()
    reports = detect_capture(args.capture, config, workers=args.workers,
                             progress=lambda p: status.update(f"detect {bar(p['done'], p['total'])}"),
                             mask=mask_from_args(args), empty=args.background.folder)
    status.done(f"detect: done, wrote {args.capture / 'wand.csv'} ({config.describe()})")
    rig = read_rig(args.capture)
    expected = None if rig.static_markers is None else len(rig.static_markers)
    for r in reports:
        if r.setup is not None and (r.setup.mask_source or r.setup.empty_frames):
            print(r.setup.line())
        print(r.line(expected))
    return 0


def run_capture(args) -> int:
    import contextlib

    from wandcal.calib.errors import CalibrationError
    from wandcal.capture.guidance import LiveGuidance
    from wandcal.capture.guidance_cli import guidance_lines, settings_from, summary
    from wandcal.capture.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import open_trigger

    if args.stop_when_enough and not args.guidance:
        raise CalibrationError("--stop-when-enough needs the guidance; drop --no-guidance")
    from wandcal.capture.detect_cli import config_from_args

    config = config_from_args(args, live=True)
    cameras: list[CameraDriver] = [cam for url in args.camera for cam in open_cameras(url)]
    rig = _rig(args, cameras)
    detect = _live_detectors(args, rig, config)
    trigger = open_trigger(args.trigger)
    status = StatusLine()
    guidance = LiveGuidance(rig, settings_from(args)) if args.guidance and rig.wand_length is not None else None
    told = [None]  # the advice last printed: a new first item gets its own line

    def show(p) -> None:
        missed = " ".join(f"{cid}:{n}" for cid, n in p.missed.items())
        text = f"{p.phase} {bar(p.sets, p.total)} {p.fps:6.1f} sets/s  dropped {missed}"
        if p.guidance is not None and p.phase == "wand":
            text += "  |  " + summary(p.guidance)
            advice = p.guidance["advice"][0] if p.guidance["advice"] else "enough: you can stop"
            if advice != told[0] and p.guidance["frames"]:
                told[0] = advice
                print(f"\nguidance: {advice}", file=sys.stderr)
        status.update(text)

    def between() -> None:
        if sys.stdin.isatty():
            input("\nstatic object recorded; remove it, then press Enter to record the wand... ")

    until = (lambda: guidance.enough) if guidance is not None and args.stop_when_enough else None
    with guidance or contextlib.nullcontext():
        result = record(cameras, trigger, args.out, rig, frames=args.frames, static_frames=args.static_frames,
                        rate_hz=args.rate, progress=show, between=between,
                        events=lambda m: print(f"\n{m}", file=sys.stderr), images=args.images, guidance=guidance,
                        until=until, detect=detect)
        final = guidance.update() if guidance is not None else None
    scene = _sim_scene(cameras)
    if scene is not None and rig is scene.rig:
        # a simulated rig: keep its truth beside the capture, as 'wandcal simulate' does
        (args.out / "truth.json").write_text(json.dumps(scene.truth.to_json(rig)) + "\n")
    total = result.frame_sets + result.static_sets
    status.done(f"recorded {result.frame_sets} wand sets and {result.static_sets} static sets into {result.folder}; "
                f"{result.complete_sets} of {total} have every camera's frame")
    for cid, s in result.per_camera.items():
        print(f"{cid}: {s['delivered']} frames, {s['missed']} missed, {s['unreadable']} unreadable"
              + (f", clock drift {s['clock_drift_ppm']:+.1f} ppm" if s["clock_drift_ppm"] is not None else ""))
    if final is not None:
        print("guidance on the recorded wand sets:")
        for line in guidance_lines(final):
            print(line)
    if result.error:
        print(f"wandcal capture: stopped early: {result.error}\nkept everything recorded until then in "
              f"{result.folder}", file=sys.stderr)
        return 3
    return 0


def _image_policy(text: str):
    from wandcal.capture.record import ImagePolicy

    try:
        return ImagePolicy.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _rig(args, cameras: list[CameraDriver]) -> Rig:
    """rig.json from --rig, else the simulated scene's rig or the drivers' own intrinsics."""
    if args.rig:
        return _read_rig_file(args.rig)
    scene = _sim_scene(cameras)
    if scene is not None:
        return scene.rig
    missing = [c.camera_id for c in cameras if c.intrinsics is None]
    if missing:
        raise DriverError(f"no intrinsics for camera(s) {', '.join(missing)}; give --rig rig.json "
                          "(docs/capture-format.md) with every camera's K and dist")
    folders = {getattr(c, "folder", None) for c in cameras} - {None}
    if len(folders) == 1 and args.wand_length is None:
        return read_rig(next(iter(folders)))
    return Rig(cameras=tuple(c.intrinsics for c in cameras), wand_length=args.wand_length or DEFAULT_WAND_LENGTH_M)


def _sim_scene(cameras: list[CameraDriver]):
    """The simulated scene when every camera comes from the same one (one sim:// URL), else None."""
    scenes = {id(c.scene): c.scene for c in cameras if hasattr(c, "scene")}
    if len(scenes) == 1 and len(cameras) == len(next(iter(scenes.values())).rig.cameras):
        return next(iter(scenes.values()))
    return None


def _read_rig_file(path: Path) -> Rig:
    from wandcal.capture.folder import load_json, rig_from_json

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DriverError(f"{path}: cannot read the rig ({exc})") from None
    return rig_from_json(load_json(data, str(path)), str(path))
