"""Live capture: ``wandcal capture`` driven over HTTP, one at a time, into the data directory. The
state machine (:class:`LiveCapture`) is here; its routes are in ``service/api/routes/live_capture.py``.

A capture records into a staging folder ``captures/.<capture id>.partial`` (kept by the next start
if the server dies mid-capture, and moved to ``recovered/<capture id>`` if the recording fails
before it becomes a capture: service/datafolder/recovery.py), detecting every frame as it arrives and writing the points
level as it goes (images as the start request asks); then the folder becomes the stored capture
``<capture id>``, ready for ``POST /jobs``. While it records, its wanding guidance is kept up to
date (``GET /captures/<capture id>/guidance``), and it may stop itself once that says enough.

With static frames, the capture pauses after the static recording in state ``waiting_for_wand``
(the lab's "remove the L-frame, take the wand" step) until ``POST /capture/continue``: a trigger
stops its pulses meanwhile, free-running cameras are drained (grab and discard), so nothing shot
during the pause is recorded. ``POST /capture/stop`` or the settings' timeout end it there,
keeping the static recording as a capture of its own.
"""

from __future__ import annotations

import contextlib
import functools
import threading
import time
import uuid
from collections import deque
from pathlib import Path

from fastapi import HTTPException

from wandcal.capture.folder import CaptureFormatError, read_capture
from wandcal.capture.recording.camera_rig import camera_rig
from wandcal.capture.recording.live_guidance import LiveGuidance
from wandcal.capture.recording.record import ImagePolicy
from wandcal.capture.recording.session import Progress, record
from wandcal.capture.rig_file import rig_from_json
from wandcal.drivers.errors import DriverError
from wandcal.service.datafolder.recovery import keep_failed_recording
from wandcal.service.guidance_cache import guidance_settings
from wandcal.service.schemas import (
    LiveCaptureCreate,
    LiveCapturePublic,
    LiveCaptureState,
)
from wandcal.service.settings import DEFAULT_CONTINUE_TIMEOUT_S, GuidanceConfig
from wandcal.service.storage import CaptureStore

SOURCE = "live"
KEPT_MESSAGES = 20  # the latest events are what an operator acts on; the full list is in capture.json
BUSY = (LiveCaptureState.running, LiveCaptureState.waiting_for_wand, LiveCaptureState.stopping)


class _StopRequested(KeyboardInterrupt):
    """Raised from the progress callback: :func:`wandcal.capture.recording.session.record` ends on an interrupt
    exactly as on Ctrl-C in ``wandcal capture``, keeping every set recorded so far."""


class _NoContinue(DriverError):
    """Raised from ``between`` when nobody continued in time. :func:`wandcal.capture.recording.session.record` ends
    on a :class:`DriverError` as on a device that stops: everything recorded is kept, and the
    message becomes the capture's error in ``capture.json``."""


class LiveCapture:
    """The one live capture of a server: its background thread and a snapshot of its status."""

    def __init__(self, store: CaptureStore, continue_timeout_s: float = DEFAULT_CONTINUE_TIMEOUT_S):
        self.store = store
        self.continue_timeout_s = continue_timeout_s
        self._lock = threading.Lock()
        self._status = LiveCapturePublic(state=LiveCaptureState.idle)
        self._stop = threading.Event()
        self._resume = threading.Event()  # set by continue (and by stop, to end the wait)
        self._messages: deque[str] = deque(maxlen=KEPT_MESSAGES)
        self._guidance: LiveGuidance | None = None

    def status(self) -> LiveCapturePublic:
        with self._lock:
            guidance = self._guidance
            status = self._status.model_copy(update={"messages": list(self._messages)})
        if guidance is not None:
            status.enough = guidance.enough
        return status

    def guidance_for(self, capture_id: str) -> dict | None:
        """The live guidance of ``capture_id`` while it is the capture being recorded, else None."""
        with self._lock:
            live = self._status.capture_id == capture_id and self._busy() and self._guidance is not None
            guidance = self._guidance
        return guidance.latest() | {"live": True} if live and guidance is not None else None

    def _update(self, **fields) -> None:
        with self._lock:
            self._status = self._status.model_copy(update=fields)

    def _busy(self) -> bool:
        return self._status.state in BUSY

    def start(self, body: LiveCaptureCreate, config: GuidanceConfig | None = None) -> LiveCapturePublic:
        """Open the devices (a driver that cannot open raises here, before anything is recorded),
        then record in a background thread, with guidance as ``config`` says."""
        config = config or GuidanceConfig()
        if body.stop_when_enough and not body.guidance:
            raise HTTPException(422, "stop_when_enough needs the guidance; send guidance: true (the default)")
        images = ImagePolicy.parse(body.images)
        with self._lock:
            if self._busy():
                s = self._status
                raise HTTPException(409, f"live capture {s.id} is {s.state.value} (capture {s.capture_id}, "
                                         f"{s.frames_recorded}/{s.frames_total} sets); stop it with "
                                         "POST /api/v1/capture/stop or wait until it is done")
            # claimed before the devices open, so two starts at once cannot both go ahead
            previous = self._status
            self._status = LiveCapturePublic(state=LiveCaptureState.running, phase="open", id=uuid.uuid4().hex,
                                             capture_id=uuid.uuid4().hex, started=time.time(),
                                             frames_total=body.frames + body.static_frames, images=str(images),
                                             stop_when_enough=body.stop_when_enough)
            self._messages.clear()
            previous_guidance, self._guidance = self._guidance, None
            self._stop.clear()
            self._resume.clear()
        stack = contextlib.ExitStack()
        try:
            cameras, trigger, rig = _open_devices(body, stack, self.store)
            guidance = None
            if body.guidance and rig.wand_length is not None:
                guidance = LiveGuidance(rig, guidance_settings(config), config.update_interval_s)
        except BaseException as exc:
            stack.close()
            with self._lock:
                self._status, self._guidance = previous, previous_guidance  # a refused start changes nothing
            if isinstance(exc, (OSError, ValueError)):  # DriverError, a bad URL or rig.json
                raise HTTPException(422, str(exc)) from None
            raise
        with self._lock:
            self._guidance = guidance
        self._update(cameras=[c.camera_id for c in cameras], phase="static" if body.static_frames else "wand")
        run = self.status()
        pause = body.static_frames and body.pause_after_static
        between = functools.partial(self._wait_for_wand, body.static_frames) if pause else None
        threading.Thread(target=self._run, args=(body, stack, cameras, trigger, rig, run, between, images, guidance),
                         name=f"live-capture-{(run.id or '')[:8]}", daemon=True).start()
        return run

    def stop(self) -> LiveCapturePublic:
        with self._lock:
            if not self._busy():
                raise HTTPException(409, f"no live capture is running (the last one is {self._status.state.value}); "
                                         "start one with POST /api/v1/capture/start")
            self._stop.set()
            self._resume.set()  # a capture waiting for the wand ends now, keeping its static recording
            if self._status.state in (LiveCaptureState.running, LiveCaptureState.waiting_for_wand):
                self._status = self._status.model_copy(
                    update={"state": LiveCaptureState.stopping, "prompt": None, "wait_deadline": None})
        return self.status()

    def set_stop_when_enough(self, enabled: bool) -> LiveCapturePublic:
        """Switch the automatic stop on or off while the capture records."""
        with self._lock:
            if not self._busy():
                raise HTTPException(409, f"no live capture is running (the last one is {self._status.state.value}); "
                                         "stop_when_enough applies to a capture that records")
            if enabled and self._guidance is None:
                raise HTTPException(409, "this capture records without guidance, so it cannot stop when enough")
            self._status = self._status.model_copy(update={"stop_when_enough": enabled})
        return self.status()

    def resume(self) -> LiveCapturePublic:
        """Start the wand run of a capture waiting after its static recording."""
        with self._lock:
            if self._status.state != LiveCaptureState.waiting_for_wand:
                raise HTTPException(409, f"no live capture is waiting for the wand (the live capture is "
                                         f"{self._status.state.value}); continue applies after the static "
                                         "recording of a capture started with static_frames (and "
                                         "pause_after_static: true, the default)")
            self._status = self._status.model_copy(update={"state": LiveCaptureState.running, "phase": "wand",
                                                           "prompt": None, "wait_deadline": None})
            self._resume.set()
        return self.status()

    # -- the background thread -----------------------------------------------------------------
    def _progress(self, p: Progress) -> None:
        if self._stop.is_set():
            self._update(stopped=True)
            raise _StopRequested()
        self._update(phase=p.phase, frames_recorded=p.sets, fps=round(p.fps, 2), dropped=dict(p.missed))

    def _wait_for_wand(self, static_sets: int) -> None:
        """``record``'s ``between``: wait for continue, stop or the timeout, with the trigger idle
        (free-running cameras are drained meanwhile by ``record``)."""
        timeout = self.continue_timeout_s
        with self._lock:
            if self._stop.is_set():  # stopped during the static recording
                self._status = self._status.model_copy(update={"stopped": True})
                raise _StopRequested()
            self._status = self._status.model_copy(update={
                "state": LiveCaptureState.waiting_for_wand, "phase": "waiting",
                "frames_recorded": static_sets, "wait_deadline": time.time() + timeout,
                # for the operator at the rig (the page shows it above Continue); the API is in docs/api.md
                "prompt": "The L-frame is recorded. Now remove the L-frame from the volume and pick up the wand, "
                          "then press Continue to record the wand. Stop keeps only the L-frame recording. "
                          f"Without Continue, the capture stops after {_duration(timeout)}.",
            })
        self._resume.wait(timeout)
        with self._lock:  # continue and stop set their state with the event, under this lock
            if self._stop.is_set():
                self._status = self._status.model_copy(update={"stopped": True})
                raise _StopRequested()
            if not self._resume.is_set():
                self._status = self._status.model_copy(update={"state": LiveCaptureState.stopping, "prompt": None,
                                                               "wait_deadline": None})
                raise _NoContinue(f"nobody sent POST /api/v1/capture/continue within {timeout:g} s of the static "
                                  "recording (settings: capture_continue_timeout_s)")

    def _event(self, message: str) -> None:
        with self._lock:
            self._messages.append(message)

    def _run(self, body: LiveCaptureCreate, stack: contextlib.ExitStack, cameras, trigger, rig,
             run: LiveCapturePublic, between, images: ImagePolicy, guidance: LiveGuidance | None) -> None:
        capture_id = run.capture_id
        assert capture_id is not None  # start() announces it before the thread runs
        staging = self.store.root / f".{capture_id}.partial"
        registered = False
        # read at every batch of sets, so PATCH /capture can switch it on or off while recording
        until = (lambda: self._status.stop_when_enough and guidance.enough) if guidance is not None else None
        try:
            with stack, (guidance or contextlib.nullcontext()):
                result = record(cameras, trigger, staging, rig, frames=body.frames, static_frames=body.static_frames,
                                rate_hz=body.rate_hz, progress=self._progress, between=between, events=self._event,
                                images=images, guidance=guidance, until=until)
                if guidance is not None:
                    guidance.update()  # the last sets too
            stopped = self.status().stopped
            self._update(frames_recorded=result.static_sets + result.frame_sets,
                         dropped={cid: s["missed"] + s["unreadable"] for cid, s in result.per_camera.items()})
            if result.frame_sets + result.static_sets == 0:
                raise CaptureFormatError("no frame sets were recorded" + (" before the stop" if stopped else "")
                                         + "; nothing was stored")
            self._update(phase="register")
            _register(self.store, capture_id, staging, "live: " + " ".join(body.cameras))
            registered = True
            error = None if stopped else result.error
            if not result.frame_sets:
                kept = (f"only the static object was recorded: it is stored as capture {run.capture_id} (check the "
                        f"L-frame with POST /api/v1/captures/{run.capture_id}/static); it has no wand sets to "
                        "calibrate, so start a new capture for the wand")
                if error:
                    error += "; " + kept
                else:
                    self._event(kept)
            self._update(state=LiveCaptureState.failed if error else LiveCaptureState.done, error=error,
                         phase=None, finished=time.time())
        except Exception as exc:  # the thread's end: the status is where the failure is reported
            error = str(exc) or type(exc).__name__
            if not registered:
                recovered = _keep(self.store, staging, capture_id)
                if recovered is not None:
                    error += (f"; the recorded sets are kept in {recovered}: run 'wandcal detect {recovered}' (with other "
                              "detection settings if no wand was found) and upload its points level")
            self._update(state=LiveCaptureState.failed, error=error, phase=None,
                         finished=time.time(), capture_id=run.capture_id if registered else None)


def _keep(store: CaptureStore, staging: Path, capture_id: str) -> Path | None:
    """The failed recording's sets moved to ``recovered/<id>``; when even that fails (a full disk
    can refuse the new folder), the staging folder stays for the next start's recovery."""
    try:
        return keep_failed_recording(store, staging, capture_id)
    except OSError:
        return None


def _open_devices(body: LiveCaptureCreate, stack: contextlib.ExitStack, store: CaptureStore):
    """Cameras, trigger and rig of ``body``, opened in ``stack`` (record re-enters them)."""
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import open_trigger

    port = _local_port(body.trigger)
    cameras = [cam for url in body.cameras for cam in open_cameras(_allowed_camera_url(url, store))]
    if body.rig is not None:
        rig = rig_from_json(body.rig, "rig")
    else:
        rig = camera_rig(cameras, wand_length=body.wand_length_m)
    for cam in cameras:
        stack.enter_context(cam)
    trigger = open_trigger(port)
    if trigger is not None:
        stack.enter_context(trigger)
    return cameras, trigger, rig


def _allowed_camera_url(url: str, store: CaptureStore) -> str:
    """The camera URL if it names a device, a simulated rig, or a replay folder under the replay
    root. File paths and network addresses elsewhere would let a request make the server read
    outside its directories (opencv: opens files and rtsp:// or http:// streams)."""
    scheme, _, rest = url.partition(":")
    if scheme == "sim":
        return url
    if scheme == "v4l2" and rest.removeprefix("//").startswith("/dev/"):
        return url
    if scheme == "opencv" and rest.strip().isdigit():
        return url
    if scheme == "replay":
        path = Path(rest.removeprefix("//"))
        root = store.replay_root
        if root is not None and path.resolve().is_relative_to(root):
            return url
        raise DriverError(
            f"camera {url!r}: a replay folder must lie under the server's replay root "
            f"({root if root else 'none is set: WANDCAL_REPLAY_ROOT'})"
        )
    raise DriverError(
        f"camera {url!r}: the service records only from devices (v4l2:///dev/videoN, opencv:N), "
        "simulated rigs (sim://?...) or replay folders under its replay root"
    )


def _local_port(url: str | None) -> str | None:
    """The trigger URL if it names a local serial device. pyserial also opens network URLs
    (socket://, rfc2217://), which would let a request make the server connect anywhere."""
    if url is None or url.strip().lower() in ("", "none"):
        return None
    path = url[len("serial://"):] if url.startswith("serial://") else url
    if not path.startswith("/"):
        raise DriverError(f"trigger {url!r}: give a local serial device, e.g. serial:///dev/ttyACM0 or /dev/ttyACM0")
    return url


def _register(store: CaptureStore, capture_id: str, staging: Path, name: str) -> None:
    """Make the detected staging folder the stored capture ``capture_id`` (images kept beside
    the points level), under the id announced when the capture started."""
    store.adopt(staging, capture_id, read_capture(staging), SOURCE, name)


def _duration(seconds: float) -> str:
    """'10 minutes', '1 minute 30 seconds', '45 seconds': a wait in words for the operator."""
    minutes, rest = divmod(round(seconds), 60)
    parts = [f"{minutes} minute{'s' * (minutes != 1)}"] if minutes else []
    if rest or not minutes:
        parts.append(f"{rest} second{'s' * (rest != 1)}")
    return " ".join(parts)
