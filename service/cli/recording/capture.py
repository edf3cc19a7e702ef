"""``wandcal capture``: record a capture folder from cameras and a strobe trigger, with the wanding
guidance on the progress line."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from wandcal.service.cli.recording.detect import add_detect_options, config_from_args, mask_from_args
from wandcal.service.cli.recording.guidance import add_guidance_options
from wandcal.service.cli.support.args import arg_number, arg_whole
from wandcal.service.cli.support.exits import INTERRUPTED, NO_ANSWER, InputError

if TYPE_CHECKING:
    from wandcal.calib.rig import Rig
    from wandcal.drivers.camera import CameraDriver

# Bounds of the numeric options (exit 2 outside them): the service's own limits for a live capture
# (service/schemas.py) and a wand no lab builds.
MAX_FRAMES = 10_000_000
MAX_STATIC_FRAMES = 100_000
MAX_WAND_LENGTH_M = 10.0
STDIN_POLL_S = 0.2  # how long a Ctrl-C at the pause may wait to be acted on, at most


def register(sub: argparse._SubParsersAction, *, arguments: bool = True) -> None:
    p = sub.add_parser("capture", help="record synchronised frames from cameras and a strobe trigger",
                       description="Record a wandcal-capture/1 folder: every frame's blob centroids "
                                   "(the points level, written as it goes) and the images --images asks "
                                   "for, with the wanding guidance on the progress line.")
    p.set_defaults(run=run_capture)
    if arguments:
        _arguments(p)


def _arguments(p: argparse.ArgumentParser) -> None:
    from wandcal.capture.recording.camera_rig import DEFAULT_WAND_LENGTH_M
    from wandcal.drivers.trigger_protocol import MAX_RATE_HZ, MIN_RATE_HZ

    p.add_argument("--camera", action="append", required=True, metavar="URL",
                   help="camera URL (repeat): v4l2:///dev/video0, opencv:0, replay:///path, sim://?cameras=4")
    p.add_argument("--trigger", default="none", metavar="URL",
                   help="strobe trigger: serial:///dev/ttyACM0, a device path, or 'none' (default)")
    p.add_argument("--frames", type=arg_whole(1, MAX_FRAMES), required=True, metavar="N",
                   help=f"wand frame sets to record, 1 to {MAX_FRAMES}")
    p.add_argument("--static-frames", type=arg_whole(0, MAX_STATIC_FRAMES), default=0, metavar="K",
                   help=f"first record K frame sets of the static object (L-frame) alone, up to {MAX_STATIC_FRAMES} "
                        "(default 0)")
    p.add_argument("--rate", type=arg_number(MIN_RATE_HZ, MAX_RATE_HZ), default=100.0, metavar="HZ",
                   help=f"trigger / frame rate in Hz, {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} (default 100)")
    p.add_argument("--rig", type=Path, help="rig.json with the cameras' intrinsics (default: none; simulated and "
                   "replayed cameras bring their own)")
    p.add_argument("--wand-length", type=arg_number(0, MAX_WAND_LENGTH_M, low_open=True), default=None, metavar="M",
                   help="wand marker distance in metres, for cameras that do not bring a rig.json (default "
                        f"{DEFAULT_WAND_LENGTH_M:g})")
    p.add_argument("--out", type=Path, required=True,
                   help="new capture folder (one that holds a capture is refused, unless --overwrite)")
    p.add_argument("--overwrite", action="store_true",
                   help="record again into an --out that holds a capture, replacing its recording's files")
    p.add_argument("--no-pause", action="store_true",
                   help="record the wand right after the static sets, without waiting for Enter (default: pause "
                        "for the L-frame to leave the volume; free-running cameras are drained meanwhile, so "
                        "nothing shot during the pause is recorded)")
    p.add_argument("--images", type=_image_policy, default="all", metavar="WHICH",
                   help="images written beside the centroids: all (default), none, static (the static recording "
                        "only) or N (every N-th wand set); 'none' keeps up with 8 cameras at 100 fps")
    p.add_argument("--no-guidance", dest="guidance", action="store_false",
                   help="do not solve the wanding guidance while recording")
    p.add_argument("--stop-when-enough", action="store_true",
                   help="end the wand run, keeping it, as soon as the guidance says enough")
    p.add_argument("--quiet", action="store_true", help="no progress line (there is none when stderr is not a terminal)")
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
    from wandcal.calib.errors import CalibrationError

    if args.stop_when_enough and not args.guidance:
        raise CalibrationError("--stop-when-enough needs the guidance; drop --no-guidance")
    with _interruptible():
        try:
            _make_room(args.out, overwrite=args.overwrite)
            return _record(args)
        except KeyboardInterrupt:  # before the recording began (or after it ended): say what is there
            held = _held(args.out)
            print(f"\nwandcal capture: interrupted; {held}", file=sys.stderr)
            return INTERRUPTED


def _record(args) -> int:
    """Open the devices and record, with the guidance and the progress line."""
    import contextlib
    import json

    from wandcal.capture.recording.camera_rig import camera_rig, simulated_scene
    from wandcal.capture.recording.live_guidance import LiveGuidance
    from wandcal.capture.recording.session import INTERRUPTED as STOPPED_BY_USER
    from wandcal.capture.recording.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.service.cli.recording.guidance import settings_from
    from wandcal.service.cli.support.progress import ProgressLine

    config = config_from_args(args, live=True)
    cameras: list[CameraDriver] = [cam for url in args.camera for cam in open_cameras(url)]
    rig = camera_rig(cameras, args.rig, args.wand_length)
    detect = _live_detectors(args, rig, config)
    trigger = _open_trigger(args.trigger)
    guidance = LiveGuidance(rig, settings_from(args)) if args.guidance and rig.wand_length is not None else None
    until = (lambda: guidance.enough) if guidance is not None and args.stop_when_enough else None
    between = None if args.no_pause or not args.static_frames else _between
    with ProgressLine(quiet=args.quiet) as status, guidance or contextlib.nullcontext():
        result = record(cameras, trigger, args.out, rig, frames=args.frames, static_frames=args.static_frames,
                        rate_hz=args.rate, progress=_shown_on(status), between=between,
                        events=lambda m: _tell(f"\n{m}"), images=args.images, guidance=guidance,
                        until=until, detect=detect)
        interrupted = result.error == STOPPED_BY_USER
        final = _final_guidance(guidance) if guidance is not None else None
        scene = simulated_scene(cameras)
        if scene is not None and rig is scene.rig:
            # a simulated rig: keep its truth beside the capture, as 'wandcal simulate' does
            (args.out / "truth.json").write_text(json.dumps(scene.truth.to_json(rig)) + "\n")
        total = result.frame_sets + result.static_sets
        status.done(f"recorded {result.frame_sets} wand sets and {result.static_sets} static sets into "
                    f"{result.folder}; {result.complete_sets} of {total} have every camera's frame")
    return _print_recorded(result, final, interrupted=interrupted)


def _tell(line: str) -> None:
    """A line on stderr while recording. A terminal that hung up fails the write (EIO) before its
    SIGHUP reaches the handler: that is no error, the SIGHUP stops the capture with its files
    written (an OSError here had left no capture.json, the interrupt landing in the clean-up)."""
    with contextlib.suppress(OSError):
        print(line, file=sys.stderr)


def _final_guidance(guidance) -> dict:
    """The guidance on every recorded set (the same sets the summary counts), also after Ctrl-C:
    its solver process ignores the terminal's signals. A solver that died all the same leaves the
    last document it made, which says when it was made (``updated``)."""
    from concurrent.futures.process import BrokenProcessPool

    try:
        return guidance.update()
    except BrokenProcessPool:
        return guidance.latest()


def _open_trigger(url: str):
    """The trigger ``url`` names (None for 'none'); a device path that is not there is bad input."""
    from wandcal.drivers.trigger import open_trigger

    path = url[len("serial://"):] if url.startswith("serial://") else url
    if path.startswith("/") and not Path(path).exists():
        raise InputError(f"--trigger {url}: no such device; plug in the trigger board (ls /dev/ttyACM* /dev/ttyUSB*), "
                         "or run 'wandcal trigger-emulator' in another terminal and give the path it prints, or "
                         "give --trigger none for free-running cameras")
    return open_trigger(url)


def _make_room(out: Path, *, overwrite: bool) -> None:
    """Refuse an ``--out`` that holds a capture, unless --overwrite or it holds an interrupted
    recording with no wand sets (which nothing can calibrate): those are cleared first."""
    from wandcal.capture.recording.record import clear_recording, held_capture

    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} is a file, not a folder; give a new folder for the capture")
    held = held_capture(out)
    if held is None:
        return
    if not (overwrite or held.replaceable):
        raise InputError(f"{out} already holds {held.describe()}; calibrate it (wandcal calibrate {out}), choose a "
                         "new --out folder, or give --overwrite to record again into this one (its recording's "
                         "files are replaced; masks/, background/ and results stay)")
    print(f"wandcal capture: replacing {held.describe()} in {out}", file=sys.stderr)
    clear_recording(out)


def _held(out: Path) -> str:
    """What an interrupted capture left in ``out``, and how to go on."""
    from wandcal.capture.recording.record import held_capture

    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out} is a file, not a folder; give a new folder for the capture")
    held = held_capture(out)
    if held is None:
        return f"nothing was recorded into {out}"
    return f"{out} holds {held.describe()}; {_next_steps(out, held.wand_sets or 0)}"


def _next_steps(out: Path, wand_sets: int) -> str:
    again = f"record again into it with --out {out} --overwrite"
    if wand_sets:
        return f"calibrate it (wandcal calibrate {out}), or {again}"
    return f"no wand sets to calibrate: record again with the same --out {out} (it is replaced)"


@contextlib.contextmanager
def _interruptible():
    """Ctrl-C, a closed terminal (SIGHUP) and SIGTERM stop the capture as KeyboardInterrupt, once:
    a second Ctrl-C while the capture finishes its files is ignored. After a hang-up the terminal
    is gone, so what is left to say goes to /dev/null instead of failing on a dead descriptor."""
    stopping = [False]

    def stop(signum, frame) -> None:
        if signum == signal.SIGHUP:
            devnull = os.open(os.devnull, os.O_WRONLY)
            for fd in (1, 2):
                os.dup2(devnull, fd)
            os.close(devnull)
        if not stopping[0]:
            stopping[0] = True
            raise KeyboardInterrupt

    signals = (signal.SIGINT, signal.SIGHUP, signal.SIGTERM)
    previous = {s: signal.signal(s, stop) for s in signals}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def _shown_on(status):
    """The recording's progress callback: the phase, its bar, the rate, the drops and the guidance
    on the progress line; a new first piece of advice on a line of its own."""
    from wandcal.service.cli.recording.guidance import summary
    from wandcal.service.cli.support.progress import bar

    told = [None]  # the advice last printed

    def show(p) -> None:
        missed = " ".join(f"{cid}:{n}" for cid, n in p.missed.items())
        text = f"{p.phase} {bar(p.sets, p.total)} {p.fps:6.1f} sets/s  dropped {missed}"
        if p.guidance is not None and p.phase == "wand":
            text += "  |  " + summary(p.guidance)
            advice = p.guidance["advice"][0] if p.guidance["advice"] else "enough: you can stop"
            if advice != told[0] and p.guidance["frames"]:
                told[0] = advice
                _tell(f"\nguidance: {advice}")
        status.update(text)

    return show


def _between() -> None:
    """The pause after the static recording: Enter goes on; end of input stops the capture as
    Ctrl-C does (the static sets are kept). Without a terminal a line on stdin goes on."""
    prompt = "\nstatic object recorded; remove it from the volume, then press Enter to record the wand... "
    terminal = sys.stdin.isatty()
    print(prompt, end="" if terminal else "\n", file=sys.stderr, flush=True)
    if not _line_from_stdin():
        if not terminal:
            print("wandcal capture: end of input at the pause (stdin is no terminal): give --no-pause to record the "
                  "wand without waiting, or send a line on stdin when the L-frame is out", file=sys.stderr)
        raise KeyboardInterrupt  # end of input: nobody will press Enter


def _line_from_stdin() -> str:
    """A line from stdin ('' at its end). The wait polls, so that Ctrl-C is acted on however
    it falls: a signal that lands just before a blocking read (``input()`` under GNU readline
    included) is only seen when the read returns, which at a pause is never."""
    import select

    try:
        while not select.select([sys.stdin], [], [], STDIN_POLL_S)[0]:
            pass
        return sys.stdin.readline()
    except (OSError, ValueError):  # stdin closed or not selectable: as end of input
        return ""


def _print_recorded(result, final: dict | None, *, interrupted: bool = False) -> int:
    """Each camera's frames, the guidance on what was recorded; exit 3 when the recording stopped
    early, 130 when it was interrupted (saying what is kept and how to go on)."""
    from wandcal.service.cli.recording.guidance import guidance_lines

    for cid, s in result.per_camera.items():
        # frames delivered, whatever they show; the guidance's table counts those with both wand ends
        print(f"{cid}: {s['delivered']} frame{'s' * (s['delivered'] != 1)} delivered, {s['missed']} missed, "
              f"{s['unreadable']} unreadable"
              + (f", clock drift {s['clock_drift_ppm']:+.1f} ppm" if s["clock_drift_ppm"] is not None else ""))
    if final is not None:
        print("guidance on the recorded wand sets:")
        for line in guidance_lines(final):
            print(line)
    if interrupted:
        print(f"wandcal capture: interrupted; kept {result.frame_sets} wand sets and {result.static_sets} static sets "
              f"in {result.folder} (capture.json: partial); {_next_steps(result.folder, result.frame_sets)}",
              file=sys.stderr)
        return INTERRUPTED
    if result.error:
        print(f"wandcal capture: stopped early: {result.error}\nkept everything recorded until then in "
              f"{result.folder}", file=sys.stderr)
        return NO_ANSWER
    return 0


def _image_policy(text: str):
    from wandcal.capture.recording.record import ImagePolicy

    try:
        return ImagePolicy.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
