"""``wandcal capture``, ``wandcal detect`` and ``wandcal trigger-emulator``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from calib.rig import Rig
from capture.folder import read_rig
from capture.progress import StatusLine, bar
from drivers.camera import CameraDriver
from drivers.errors import DriverError

DEFAULT_WAND_LENGTH_M = 0.5


def register(subparsers) -> None:
    p = subparsers.add_parser("capture", help="record synchronised frames from cameras and a strobe trigger",
                              description="Record an image-level wandcal-capture/1 folder.")
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
    p.set_defaults(run=run_capture)

    p = subparsers.add_parser("detect", help="detect blobs in an image-level capture and write wand.csv",
                              description="Run blob detection over frames/ and static/ of a capture folder.")
    p.add_argument("capture", type=Path, help="image-level capture folder")
    p.add_argument("--workers", type=_count(1), default=None,
                   help="threads that decode and detect images (default: every core)")
    p.set_defaults(run=run_detect)

    p = subparsers.add_parser("trigger-emulator", help="emulate the strobe trigger on a pseudo-terminal",
                              description="Speak wandcal-trigger/1 on a new pseudo-terminal; prints its path.")
    p.add_argument("--vanish-after", type=int, default=None, metavar="N",
                   help="close the terminal after N pulses, as if the board were unplugged")
    p.add_argument("--start-us", type=int, default=0, help="device clock at start (near 4294967295 tests the wrap)")
    p.set_defaults(run=run_emulator)


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
    from drivers.trigger_emulator import serve_pty

    return serve_pty(vanish_after=args.vanish_after, start_us=args.start_us)


def run_detect(args) -> int:
    from capture.images import detect_capture

    status = StatusLine()
    reports = detect_capture(args.capture, workers=args.workers,
                             progress=lambda p: status.update(f"detect {bar(p['done'], p['total'])}"))
    status.done(f"detect: done, wrote {args.capture / 'wand.csv'}")
    rig = read_rig(args.capture)
    expected = None if rig.static_markers is None else len(rig.static_markers)
    for r in reports:
        print(r.line(expected))
    return 0


def run_capture(args) -> int:
    from capture.session import record
    from drivers.registry import open_cameras
    from drivers.trigger import open_trigger

    cameras: list[CameraDriver] = [cam for url in args.camera for cam in open_cameras(url)]
    rig = _rig(args, cameras)
    trigger = open_trigger(args.trigger)
    status = StatusLine()

    def show(p) -> None:
        missed = " ".join(f"{cid}:{n}" for cid, n in p.missed.items())
        status.update(f"{p.phase} {bar(p.sets, p.total)} {p.fps:6.1f} sets/s  dropped {missed}")

    def between() -> None:
        if sys.stdin.isatty():
            input("\nstatic object recorded; remove it, then press Enter to record the wand... ")

    result = record(cameras, trigger, args.out, rig, frames=args.frames, static_frames=args.static_frames,
                    rate_hz=args.rate, progress=show, between=between,
                    events=lambda m: print(f"\n{m}", file=sys.stderr))
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
    if result.error:
        print(f"wandcal capture: stopped early: {result.error}\nkept everything recorded until then in "
              f"{result.folder}", file=sys.stderr)
        return 3
    return 0


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
    from capture.folder import rig_from_json

    try:
        return rig_from_json(json.loads(path.read_text()), str(path))
    except (OSError, ValueError) as exc:
        raise DriverError(f"{path}: cannot read the rig ({exc})") from None
