"""``wandcal capture``, ``wandcal detect`` and ``wandcal trigger-emulator`` (``wandcal import``: service/cli/import_.py)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from wandcal.calib.rig import Rig
from wandcal.capture.folder import read_rig
from wandcal.drivers.camera import CameraDriver
from wandcal.drivers.errors import DriverError
from wandcal.drivers.trigger_protocol import MAX_RATE_HZ, MIN_RATE_HZ
from wandcal.service.cli.args import number, whole
from wandcal.service.cli.detect import add_detect_options
from wandcal.service.cli.guidance import add_guidance_options
from wandcal.service.cli.status_line import StatusLine, bar

DEFAULT_WAND_LENGTH_M = 0.5
# Bounds of the numeric options (exit 2 outside them): the service's own limits for a live capture
# (service/schemas.py), a wand no lab builds, a sensor taller than any camera's, the trigger's clock.
MAX_FRAMES = 10_000_000
MAX_STATIC_FRAMES = 100_000
MAX_WAND_LENGTH_M = 10.0
MAX_WORKERS = 256
MAX_DEVICE_US = 2**32 - 1  # the trigger's microsecond counter is 32 bits and wraps


def register(subparsers) -> None:
    p = subparsers.add_parser("capture", help="record synchronised frames from cameras and a strobe trigger",
                              description="Record a wandcal-capture/1 folder: every frame's blob centroids "
                                          "(the points level, written as it goes) and the images --images asks "
                                          "for, with the wanding guidance on the status line.")
    p.add_argument("--camera", action="append", required=True, metavar="URL",
                   help="camera URL (repeat): v4l2:///dev/video0, opencv:0, replay:///path, sim://?cameras=4")
    p.add_argument("--trigger", default="none", metavar="URL",
                   help="strobe trigger: serial:///dev/ttyACM0, a device path, or 'none' (default)")
    p.add_argument("--frames", type=whole(1, MAX_FRAMES), required=True, metavar="N",
                   help=f"wand frame sets to record, 1 to {MAX_FRAMES}")
    p.add_argument("--static-frames", type=whole(0, MAX_STATIC_FRAMES), default=0, metavar="K",
                   help=f"first record K frame sets of the static object (L-frame) alone, up to {MAX_STATIC_FRAMES} "
                        "(default 0)")
    p.add_argument("--rate", type=number(MIN_RATE_HZ, MAX_RATE_HZ), default=100.0, metavar="HZ",
                   help=f"trigger / frame rate in Hz, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} (default 100)")
    p.add_argument("--rig", type=Path, help="rig.json with the cameras' intrinsics (simulated and replayed "
                   "cameras bring their own)")
    p.add_argument("--wand-length", type=number(0, MAX_WAND_LENGTH_M, low_open=True), default=None, metavar="M",
                   help="wand marker distance in metres, for cameras that do not bring a rig.json (default "
                        f"{DEFAULT_WAND_LENGTH_M:g})")
    p.add_argument("--out", type=Path, required=True, help="new capture folder")
    p.add_argument("--images", type=_image_policy, default="all", metavar="WHICH",
                   help="images written beside the centroids: all (default), none, static (the static recording "
                        "only) or N (every N-th wand set); 'none' keeps up with 8 cameras at 100 fps")
    p.add_argument("--no-guidance", dest="guidance", action="store_false",
                   help="do not solve the wanding guidance while recording")
    p.add_argument("--stop-when-enough", action="store_true",
                   help="end the wand run, keeping it, as soon as the guidance says enough")
    p.add_argument("--quiet", action="store_true", help="no status line (there is none when stderr is not a terminal)")
    add_guidance_options(p)
    add_detect_options(p, live=True)
    p.set_defaults(run=run_capture)

    p = subparsers.add_parser("detect", help="detect blobs in an image-level capture and write wand.csv",
                              description="Run blob detection over frames/ and static/ of a capture folder.")
    p.add_argument("capture", type=Path, help="image-level capture folder")
    p.add_argument("--workers", type=whole(1, MAX_WORKERS), default=None, metavar="N",
                   help=f"threads that decode and detect images, 1 to {MAX_WORKERS} (default: every core)")
    p.add_argument("--quiet", action="store_true", help="no status line (there is none when stderr is not a terminal)")
    add_detect_options(p)
    p.set_defaults(run=run_detect)

    p = subparsers.add_parser("trigger-emulator", help="emulate the strobe trigger on a pseudo-terminal",
                              description="Speak wandcal-trigger/1 on a new pseudo-terminal; prints its path.")
    p.add_argument("--vanish-after", type=whole(0), default=None, metavar="N",
                   help="close the terminal after N pulses, as if the board were unplugged (default: never)")
    p.add_argument("--start-us", type=whole(0, MAX_DEVICE_US), default=0, metavar="US",
                   help=f"device clock at start, 0 to {MAX_DEVICE_US} (near the top tests the wrap; default 0)")
    p.set_defaults(run=run_emulator)


def _live_detectors(args, rig: Rig, config):
    """The capture loop's detectors: one config for every camera, or, with masks or a per-camera
    background model (an empty-volume recording, a running average), one detector per camera."""
    from wandcal.calib.detect import STATEFUL
    from wandcal.capture.detect_setup import MASK_NONE, camera_detectors
    from wandcal.service.cli.detect import mask_from_args

    mask = mask_from_args(args)
    if mask == MASK_NONE and config.background not in STATEFUL:
        return config
    detectors, setups = camera_detectors(args.out, rig, config, mask=mask, empty=args.background.folder)
    for setup in setups:
        print(setup.line(), file=sys.stderr)
    return [detectors[cid] for cid in rig.ids]



def run_emulator(args) -> int:
    from wandcal.drivers.trigger_emulator import serve_pty

    return serve_pty(vanish_after=args.vanish_after, start_us=args.start_us)


def run_detect(args) -> int:
    from wandcal.capture.images import detect_capture
    from wandcal.service.cli.detect import config_from_args, mask_from_args

    config = config_from_args(args)
    status = StatusLine(quiet=args.quiet)
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
    from wandcal.capture.recording.live_guidance import LiveGuidance
    from wandcal.capture.recording.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import open_trigger
    from wandcal.service.cli.guidance import guidance_lines, settings_from, summary

    if args.stop_when_enough and not args.guidance:
        raise CalibrationError("--stop-when-enough needs the guidance; drop --no-guidance")
    from wandcal.service.cli.detect import config_from_args

    config = config_from_args(args, live=True)
    cameras: list[CameraDriver] = [cam for url in args.camera for cam in open_cameras(url)]
    rig = _rig(args, cameras)
    detect = _live_detectors(args, rig, config)
    trigger = open_trigger(args.trigger)
    status = StatusLine(quiet=args.quiet)
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
        print(f"{cid}: {s['delivered']} frame{'s' * (s['delivered'] != 1)}, {s['missed']} missed, "
              f"{s['unreadable']} unreadable"
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
    from wandcal.capture.recording.record import ImagePolicy

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
    from wandcal.capture.rig_file import load_json, rig_from_json

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DriverError(f"{path}: cannot read the rig ({exc})") from None
    return rig_from_json(load_json(data, str(path)), str(path))
