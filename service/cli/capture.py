"""``wandcal capture``: record a capture folder from cameras and a strobe trigger, with the wanding
guidance on the status line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from wandcal.service.cli.detect import add_detect_options, config_from_args, mask_from_args
from wandcal.service.cli.guidance import add_guidance_options
from wandcal.service.cli.support.args import number, whole

if TYPE_CHECKING:
    from wandcal.calib.rig import Rig
    from wandcal.drivers.camera import CameraDriver

DEFAULT_WAND_LENGTH_M = 0.5
# Bounds of the numeric options (exit 2 outside them): the service's own limits for a live capture
# (service/schemas.py) and a wand no lab builds.
MAX_FRAMES = 10_000_000
MAX_STATIC_FRAMES = 100_000
MAX_WAND_LENGTH_M = 10.0


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("capture", help="record synchronised frames from cameras and a strobe trigger",
                       description="Record a wandcal-capture/1 folder: every frame's blob centroids "
                                   "(the points level, written as it goes) and the images --images asks "
                                   "for, with the wanding guidance on the status line.")
    p.set_defaults(run=run_capture)
    if arguments:
        _arguments(p)


def _arguments(p: argparse.ArgumentParser) -> None:
    from wandcal.drivers.trigger_protocol import MAX_RATE_HZ, MIN_RATE_HZ

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


def _live_detectors(args, rig: Rig, config):
    """The capture loop's detectors: one config for every camera, or, with masks or a per-camera
    background model (an empty-volume recording, a running average), one detector per camera."""
    from wandcal.calib.detect import STATEFUL
    from wandcal.capture.detect_setup import MASK_NONE, camera_detectors

    mask = mask_from_args(args)
    if mask == MASK_NONE and config.background not in STATEFUL:
        return config
    detectors, setups = camera_detectors(args.out, rig, config, mask=mask, empty=args.background.folder)
    for setup in setups:
        print(setup.line(), file=sys.stderr)
    return [detectors[cid] for cid in rig.ids]


def run_capture(args) -> int:
    import contextlib

    from wandcal.calib.errors import CalibrationError
    from wandcal.capture.recording.live_guidance import LiveGuidance
    from wandcal.capture.recording.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import open_trigger
    from wandcal.service.cli.guidance import guidance_lines, settings_from, summary
    from wandcal.service.cli.support.status_line import StatusLine, bar

    if args.stop_when_enough and not args.guidance:
        raise CalibrationError("--stop-when-enough needs the guidance; drop --no-guidance")
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
    from wandcal.calib.rig import Rig
    from wandcal.capture.folder import read_rig
    from wandcal.drivers.errors import DriverError

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
    from wandcal.drivers.errors import DriverError

    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DriverError(f"{path}: cannot read the rig ({exc})") from None
    return rig_from_json(load_json(data, str(path)), str(path))
