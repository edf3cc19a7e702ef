"""Run a capture: camera reader threads, the trigger, frame-set assembly and the recorder.

Each reader thread detects the blobs of its camera's frames as they arrive (0.3 ms a frame, in
parallel across cameras), so the recorder writes centroids at the cameras' rate and images only
as its :class:`~wandcal.capture.recording.record.ImagePolicy` asks; a frame whose image will not be written
drops it at once.

Memory bound (docs/capture-format.md, "Image-level capture"): frames wait in three places,
each bounded in time at the trigger rate: the inbox from the reader threads
(:data:`INBOX_SECONDS`), the assembler, which a camera may lead by at most :data:`LEAD_SECONDS`
before its reader waits, and the writer queue (:data:`WRITE_SECONDS`): 2 s of frames in all,
and never more than :data:`MEMORY_BUDGET_BYTES` (shared in the same proportions) at high rates
or with large frames. See :func:`buffer_frames`.
"""

from __future__ import annotations

import contextlib
import queue
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from wandcal.calib.detect import CameraDetector, DetectConfig
from wandcal.calib.rig import Rig
from wandcal.capture.recording.framesets import Assembler, FrameSet
from wandcal.capture.recording.missed import missed_advice
from wandcal.capture.recording.readers import END, FrameDetector, Readers
from wandcal.capture.recording.record import ImagePolicy, Recorder
from wandcal.capture.recording.writer import ImageWriter
from wandcal.drivers.camera import CameraDriver, TriggerMode
from wandcal.drivers.errors import CameraUrlError, DriverError, FrameError
from wandcal.drivers.trigger import SerialTrigger, TriggerLost

INBOX_SECONDS = 0.25
LEAD_SECONDS = 0.5
WRITE_SECONDS = 1.25
TOTAL_SECONDS = INBOX_SECONDS + LEAD_SECONDS + WRITE_SECONDS
# 1 GiB: what a capture PC with 8 GB can spare next to the OS and the cameras' own buffers;
# at 8 cameras, 100 fps, 1280x1024 8-bit the 2 s above would be 2.1 GB, so this cap applies.
MEMORY_BUDGET_BYTES = 1 << 30
MIN_BUFFER_FRAMES = 2  # per camera: a slow rate still buffers a frame while the last one is written
BYTES_PER_PIXEL = 2  # sized for 16-bit frames, so 8-bit ones stay well inside the budget
# Camera and trigger crystals are within +-50 ppm of nominal, so two of them differ by <= 100 ppm.
DRIFT_WARN_PPM = 100.0
INTERRUPTED = "interrupted by the user"  # CaptureResult.error after Ctrl-C, end of input or a closed terminal


def buffer_frames(rate_hz: float, cameras: int, seconds: float, frame_bytes: int = 0) -> int:
    """Size of a buffer holding ``seconds`` of frames at ``rate_hz`` from ``cameras`` cameras,
    capped at its share ``seconds / TOTAL_SECONDS`` of :data:`MEMORY_BUDGET_BYTES` for frames of
    ``frame_bytes`` bytes (0: no cap), and at least :data:`MIN_BUFFER_FRAMES` per camera."""
    frames = seconds * rate_hz * cameras
    if frame_bytes > 0:
        frames = min(frames, MEMORY_BUDGET_BYTES * seconds / TOTAL_SECONDS / frame_bytes)
    return max(MIN_BUFFER_FRAMES * cameras, int(frames))


@dataclass
class CaptureResult:
    """What a capture recorded. ``error`` is the fault that ended it early (None when complete;
    :data:`INTERRUPTED` after Ctrl-C); ``capture.json`` says ``"state": "complete"`` or ``"partial"``."""

    folder: Path
    static_sets: int
    frame_sets: int
    complete_sets: int
    per_camera: dict[str, dict] = field(default_factory=dict)
    messages: list[str] = field(default_factory=list)
    error: str | None = None
    writer_high_water: int = 0
    writer_bound: int = 0


@dataclass
class Progress:
    """A snapshot for a progress display. ``fps``: frame sets per second in the current phase
    (static or wand), so the pause between them does not count."""

    phase: str
    sets: int
    total: int
    fps: float
    missed: dict[str, int]
    guidance: dict | None = None  # the latest live guidance document, when the capture has one


def record(cameras: list[CameraDriver], trigger: SerialTrigger | None, out: Path, rig: Rig, *, frames: int,
           static_frames: int = 0, rate_hz: float = 100.0, progress: Callable[[Progress], None] | None = None,
           between: Callable[[], None] | None = None, events: Callable[[str], None] | None = None,
           clock: Callable[[], float] = time.monotonic, images: ImagePolicy | None = None,
           detect: DetectConfig | list[CameraDetector] | None = None, guidance=None, until: Callable[[], bool] | None = None) -> CaptureResult:
    """Record ``static_frames`` sets of the static object, then ``frames`` wand sets, into ``out``:
    centroids always, images as ``images`` says.

    Args:
        cameras: drivers in the order of ``rig.cameras`` (ids must match).
        trigger: the strobe box, or None for free-running cameras matched by sequence number.
        rate_hz: trigger rate; also the free-run rate asked of the cameras.
        progress: called a few times a second with a :class:`Progress`.
        between: called after the static recording, before the wand run (e.g. "remove the
            L-frame, then press Enter"); it may raise KeyboardInterrupt or DriverError to end
            the capture there. With a trigger the pulses stop meanwhile; free-running cameras
            are drained (grab and discard), and the wand run starts with their first frames
            after it.
        events: receives drift / realignment / fault messages as they happen.
        images: which images to write beside the centroids (None: all).
        detect: the blob detector's settings (None: its defaults), or one
            :class:`wandcal.calib.detect.CameraDetector` per camera (with its mask or background).
        guidance: a :class:`wandcal.capture.recording.live_guidance.LiveGuidance` told of every wand pair (the caller
            starts and closes it); its latest document rides on each :class:`Progress`.
        until: asked after each batch of wand sets; True ends the capture there, complete (e.g.
            when the guidance says enough).

    Returns:
        :class:`CaptureResult`; a vanished trigger port or a failed camera ends the capture
        early with ``error`` set and everything recorded until then kept on disk.
    """
    ids = _matching_ids(cameras, rig, static_frames, frames)
    n = len(cameras)
    # made first: settings that cannot work (an empty-volume model without its recording) stop here
    detectors = detect if isinstance(detect, list) else [CameraDetector(detect, camera=i) for i in ids]
    frame_bytes = max(c.width * c.height for c in rig.cameras) * BYTES_PER_PIXEL
    messages: list[str] = []

    def say(message: str) -> None:
        messages.append(message)
        if events:
            events(message)

    assembler = Assembler(ids, triggered=trigger is not None, clock=clock, events=say)
    inbox: queue.Queue = queue.Queue(maxsize=buffer_frames(rate_hz, n, INBOX_SECONDS, frame_bytes))
    error: str | None = None
    with contextlib.ExitStack() as stack:
        # devices first: a camera or trigger that cannot be set up leaves no half-made folder
        _open_devices(stack, cameras, trigger, rate_hz)
        assembler.seen_now()  # opening took a while (a simulated camera renders its noise): no camera stalled
        recorder = Recorder(out, rig, ImageWriter(buffer_frames(rate_hz, n, WRITE_SECONDS, frame_bytes)),
                            triggered=trigger is not None, images=images, listener=guidance)
        writer = recorder.writer
        # free-running cameras pause by draining: their readers stop keeping frames after the static run
        pause_after = static_frames if between is not None and trigger is None else 0
        readers = Readers(cameras, inbox, assembler, buffer_frames(rate_hz, n, LEAD_SECONDS, frame_bytes) // n,
                           [FrameDetector(d, images or ImagePolicy(), static_frames) for d in detectors], pause_after)
        loop = _Loop(assembler, recorder, trigger, cameras, inbox, static_frames, static_frames + frames, say, clock)
        loop.guidance, loop.until, loop.readers = guidance, until, readers
        try:
            if trigger is not None:
                trigger.start(static_frames or frames)
            error = loop.run(progress, between, frames)
        except KeyboardInterrupt:
            error = INTERRUPTED
            loop.flush()
        except DriverError as exc:  # e.g. the trigger refusing START: keep what exists, say why
            error = str(exc)
        finally:
            readers.join()
            per_camera = _per_camera(assembler, ids, say)
            for line in missed_advice(per_camera, recorder.static_sets + recorder.frame_sets):
                say(line)  # kept in capture.json, told as it ends (the CLI's stderr, the service's live status)
            result = CaptureResult(out, recorder.static_sets, recorder.frame_sets, loop.complete, per_camera,
                                   messages, error, writer.high_water, writer.max_queued)
            recorder.close({"state": "partial" if error else "complete", "static_sets": result.static_sets,
                            "frame_sets": result.frame_sets, "complete_sets": result.complete_sets, "cameras": per_camera,
                            "messages": messages, "error": error, "rate_hz": rate_hz,
                            "writer_queue": {"bound": writer.max_queued, "high_water": writer.high_water}})
    return result


def _matching_ids(cameras: list[CameraDriver], rig: Rig, static_frames: int, frames: int) -> list[str]:
    """The cameras' ids, checked against the rig's; a simulated camera is given the capture's script."""
    ids = [c.camera_id for c in cameras]
    if ids != rig.ids:
        # bad input, not a device's fault (CameraUrlError: the command line exits 2)
        raise CameraUrlError(f"the cameras ({', '.join(ids)}) do not match rig.json ({', '.join(rig.ids)}); give the "
                             "rig.json of these cameras (--rig), or one --camera per rig camera, in the same order, "
                             "with matching ids (?id=...)")
    for cam in cameras:
        # a simulated camera plays the capture's script (the L-frame for the static sets, then the
        # wand), as the operator does for a real rig; a count it cannot play stops here
        script = getattr(cam, "script", None)
        if script is not None:
            script(static_frames, frames)
    return ids


def _open_devices(stack: contextlib.ExitStack, cameras: list[CameraDriver], trigger: SerialTrigger | None,
                  rate_hz: float) -> None:
    """Open and configure every camera, then the trigger, on ``stack`` (closed with it)."""
    for cam in cameras:
        stack.enter_context(cam)
        cam.configure(trigger_mode=TriggerMode.EXTERNAL if trigger else TriggerMode.FREE_RUN, fps=rate_hz)
    if trigger is not None:
        stack.enter_context(trigger)
        trigger.set_rate(rate_hz)


def _per_camera(assembler: Assembler, ids: list[str], say: Callable[[str], None]) -> dict[str, dict]:
    """Each camera's delivery figures (:func:`_camera_stats`); a clock drifting past
    ``DRIFT_WARN_PPM`` against the trigger's is said."""
    per_camera = {cid: _camera_stats(assembler, i) for i, cid in enumerate(ids)}
    for cid, stats in per_camera.items():
        drift = stats["clock_drift_ppm"]
        if drift is not None and abs(drift) > DRIFT_WARN_PPM:
            say(f"camera {cid}: its clock ran {drift:+.0f} ppm against the trigger's, more than clock "
                "crystals drift; its timestamps may not be exposure times (check its timestamp source)")
    return per_camera


def _camera_stats(assembler: Assembler, i: int) -> dict:
    cam = assembler.cameras[i]
    drift = cam.drift_ppm()
    return {"delivered": cam.delivered, "missed": cam.missed, "unreadable": cam.lost, "realigned": cam.realigned,
            "misaligned": cam.misaligned, "clock_drift_ppm": None if drift is None else round(drift, 2)}


class _Loop:
    """The capture's main loop: pulses and frames in, finished sets to the recorder."""

    def __init__(self, assembler: Assembler, recorder: Recorder, trigger: SerialTrigger | None,
                 cameras: list[CameraDriver], inbox: queue.Queue, static_frames: int, total: int, say, clock):
        self.asm, self.rec, self.trigger, self.inbox = assembler, recorder, trigger, inbox
        self.static_frames, self.total, self.say, self.clock = static_frames, total, say, clock
        self.done = 0
        self.complete = 0
        # Simulated cameras have a software trigger input; the pulses reach it here, as the
        # cable from the strobe box reaches a real camera's trigger input.
        self.wired = [c for c in cameras if hasattr(c, "trigger_input")] if trigger is not None else []
        self.failed: list[str] = []
        self.guidance = None
        self.until: Callable[[], bool] | None = None
        self.readers: Readers | None = None
        self.paused = False  # in ``between``: nothing pending is a set (free-running frames past the static run)

    def run(self, progress, between, frames: int) -> str | None:
        started, base = self.clock(), 0  # the rate counts from the start of the current phase
        error = None
        while self.done < self.total:
            if self.trigger is not None and not self.asm.pulses_ended:
                error = self._take_pulses(self.trigger) or error
            self._take_frames()
            before = self.done
            self._emit(self.asm.ready())
            if before < self.static_frames <= self.done and error is None and self._pause(between, frames):
                started, base = self.clock(), self.done
            if all(c.ended for c in self.asm.cameras):
                self.flush()
                if self.done < self.total and error is None:
                    error = f"the cameras ran out of frames after {self.done} of {self.total} sets"
                break
            if self.asm.finished():
                break
            if self.until is not None and self.done > before and self.done > self.static_frames and self.until():
                # pending sets are left out rather than flushed: their late frames would count as missed
                self.say(f"stopped after {self.done - self.static_frames} wand sets: the guidance says enough")
                break
            if progress:
                elapsed = max(self.clock() - started, 1e-9)
                phase = "static" if self.done < self.static_frames else "wand"
                progress(Progress(phase, self.done, self.total, (self.done - base) / elapsed,
                                  {cid: c.missed + c.lost for cid, c in zip(self.asm.camera_ids, self.asm.cameras)},
                                  self.guidance.latest() if self.guidance is not None else None))
        if self.failed:
            error = error or "; ".join(self.failed)
        return error

    def _pause(self, between, frames: int) -> bool:
        """Between the static run and the wand: with a trigger, ``between`` while the pulses stop,
        then the wand's pulses; free-running, ``between`` while the readers drain the cameras,
        then the sets from the first frame every camera takes after it. False: no pause."""
        if self.trigger is not None:
            if between:
                between()
                self.asm.resume_at(self.asm.next_key)  # a long pause is not a stalled camera
            self.trigger.start(frames)
            return True
        if between is None or self.readers is None or not self.readers.pause_after:
            return False
        self.paused = True
        between()
        self.asm.resume_at(self.readers.resume())
        self.paused = False
        return True

    def _take_pulses(self, trigger: SerialTrigger) -> str | None:
        try:
            while (pulse := trigger.next_pulse(timeout=0)) is not None:
                self.asm.add_pulse(pulse.counter, pulse.t_us)
                for cam in self.wired:
                    cam.trigger_input(pulse.counter, pulse.t_us)
        except TriggerLost as exc:
            self.asm.end_pulses()
            self.say(str(exc))
            return str(exc)
        return None

    def _take_frames(self) -> None:
        try:
            item = self.inbox.get(timeout=0.01)
        except queue.Empty:
            return
        while True:
            i, payload = item
            if payload is END:
                self.asm.end_camera(i)
            elif isinstance(payload, FrameError):
                self.asm.add_lost(i, payload.sequence)
                self.say(str(payload))
            elif isinstance(payload, DriverError):
                self.asm.end_camera(i)
                self.failed.append(str(payload))
                self.say(str(payload))
            else:
                self.asm.add_frame(i, payload)
            try:
                item = self.inbox.get_nowait()
            except queue.Empty:
                return

    def flush(self) -> None:
        if self.paused:
            return  # interrupted in the pause: the static run is whole, and nothing since is a set
        self._take_frames()
        self._emit(self.asm.ready(flush=True))

    def _emit(self, sets: list[FrameSet]) -> None:
        for fs in sets:
            if self.done >= self.total:
                return
            if self.done < self.static_frames:
                self.rec.add_static(fs)
            else:
                self.rec.add_frames(fs)
            self.complete += fs.complete
            self.done += 1
