"""Assemble synchronised frame sets from trigger pulses and camera frames.

Matching rule: the strobe box's first pulse after the cameras were armed exposes each camera's
frame 0, so pulse ``base + s`` belongs to camera frame sequence ``s`` (``base``: the counter of
the first pulse seen). Timestamps then check every match: the difference between a camera's
clock and the trigger's clock moves only slowly (crystal drift), so a jump of about one frame
period means the sequence numbers no longer line up (a lost frame that left no gap). Such a
camera is realigned by whole periods when the jump is clean, and reported as misaligned when
it is not. A camera that misses a pulse leaves its slot empty; the set is kept and marked
incomplete. Nothing here aborts.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from wandcal.drivers.camera import Frame

STALL_S = 2.0  # a camera silent this long no longer holds back sets: its missing slots are emitted empty
REALIGN_TOLERANCE = 0.25  # a jump within a quarter period of a whole number of periods is a clean shift
MAX_REPORTS = 5  # alignment messages per camera before they are only counted
PERIOD_WINDOW = 15  # pulse intervals in the running median of the trigger period
CLOCK_SMOOTHING = 0.05  # weight of a new sample in the running camera-to-trigger clock offset


@dataclass(frozen=True, eq=False)
class DetectedFrame:
    """A camera frame after detection in the capture loop.

    sequence, timestamp_us, camera_id: as the driver's :class:`~wandcal.drivers.camera.Frame`; uv: (K, 2)
    blob centres, pixels (origin top-left, y down); image: the frame, or None once it is known
    not to be written (centroid-only recording).
    """

    sequence: int
    timestamp_us: int
    camera_id: str
    uv: np.ndarray
    image: np.ndarray | None = None


@dataclass(eq=False)
class FrameSet:
    """The frames of one trigger pulse.

    counter: the trigger's pulse counter (the camera sequence number without a trigger);
    trigger_us: the pulse time on the trigger clock, None without a trigger or for a pulse whose
    line was lost; frames: one per camera (a :class:`DetectedFrame` in a capture), None where that
    camera missed the pulse.
    """

    counter: int
    trigger_us: int | None
    frames: list[Frame | DetectedFrame | None]

    @property
    def complete(self) -> bool:
        return all(f is not None for f in self.frames)

    def missing(self) -> list[int]:
        return [i for i, f in enumerate(self.frames) if f is None]


@dataclass
class CameraSync:
    """Per-camera matching state and counts."""

    shift: int = 0  # added to the sequence number after a realignment
    last_key: int = -1
    last_seen: float = 0.0
    ended: bool = False
    offset_us: float | None = None  # running camera-minus-trigger clock offset
    first_offset_us: float | None = None
    first_trigger_us: int | None = None
    last_trigger_us: int | None = None
    delivered: int = 0
    missed: int = 0
    lost: int = 0  # frames the driver reported as unreadable
    realigned: int = 0
    misaligned: int = 0

    def drift_ppm(self) -> float | None:
        """How fast the camera clock runs against the trigger clock, parts per million."""
        offset, first_offset = self.offset_us, self.first_offset_us
        first, last = self.first_trigger_us, self.last_trigger_us
        # the first figures are set with the first offset, so all four are there or none
        if offset is None or first_offset is None or first is None or last is None or last == first:
            return None
        return 1e6 * (offset - first_offset) / (last - first)


@dataclass(eq=False)
class _Slot:
    trigger_us: int | None = None
    pulsed: bool = False
    frames: dict[int, Frame] = field(default_factory=dict)


class Assembler:
    """Collects pulses and frames and hands out finished :class:`FrameSet` s in pulse order.

    Args:
        camera_ids: the cameras, in slot order.
        triggered: True with a trigger (sets are made by pulses); False for free-running
            cameras, whose sets are made by sequence number alone.
        clock: host seconds, for the stall rule (injected in tests).
        events: receives each drift, realignment and misalignment message as it happens.
    """

    def __init__(self, camera_ids: list[str], triggered: bool, clock: Callable[[], float] = time.monotonic,
                 events: Callable[[str], None] | None = None):
        self.camera_ids = list(camera_ids)
        self.triggered = triggered
        self.clock = clock
        self.report = events or (lambda message: None)
        self.cameras = [CameraSync(last_seen=clock()) for _ in camera_ids]
        self.base: int | None = None if triggered else 0
        self.next_key = 0  # the next key (pulse counter - base) to emit
        self.pulses_ended = not triggered
        self.period_us: float | None = None
        self._slots: dict[int, _Slot] = {}
        self._last_pulse: tuple[int, int] | None = None
        self.last_pulse_key = -1
        self._intervals: deque[float] = deque(maxlen=PERIOD_WINDOW)
        self.messages: list[str] = []

    # -- inputs
    def add_pulse(self, counter: int, t_us: int) -> None:
        if self.base is None:
            self.base = counter
        key = counter - self.base
        if self._last_pulse is not None:
            last_counter, last_us = self._last_pulse
            gap = counter - last_counter
            if gap > 0:
                # the median of recent intervals ignores the pause between the static and wand runs
                self._intervals.append((t_us - last_us) / gap)
                self.period_us = float(np.median(self._intervals))
            for missing in range(last_counter + 1, counter):
                self._slot(missing - self.base).pulsed = True  # its line was lost; the pulse still fired
        slot = self._slot(key)
        slot.pulsed, slot.trigger_us = True, t_us
        self._last_pulse = (counter, t_us)
        self.last_pulse_key = max(self.last_pulse_key, key)

    def add_frame(self, camera: int, frame: Frame) -> None:
        cam = self.cameras[camera]
        cam.last_seen = self.clock()
        key = frame.sequence + cam.shift
        if key < self.next_key:
            return  # too late: its set has gone out without it and counted it as missed
        self._slot(key).frames[camera] = frame
        cam.last_key = max(cam.last_key, key)
        cam.delivered += 1

    def add_lost(self, camera: int, sequence: int) -> None:
        """The driver could not read frame ``sequence`` (the slot stays empty; counted apart)."""
        cam = self.cameras[camera]
        cam.last_seen = self.clock()
        cam.lost += 1
        cam.last_key = max(cam.last_key, sequence + cam.shift)

    def end_camera(self, camera: int) -> None:
        self.cameras[camera].ended = True

    def end_pulses(self) -> None:
        """No more pulses will come (the run finished or the trigger port vanished)."""
        self.pulses_ended = True

    def resume_at(self, key: int) -> None:
        """Go on from set ``key`` after a free-running pause: sets before it are never made (their
        frames were shot during the pause, or before it past the static run), frames for them are
        ignored as late ones are, and every camera counts as just seen, so the pause's length
        does not make the first sets after it look stalled."""
        for k in [k for k in self._slots if k < key]:
            del self._slots[k]
        self.next_key = max(self.next_key, key)
        self.seen_now()
        for cam in self.cameras:
            cam.last_key = max(cam.last_key, self.next_key - 1)

    def seen_now(self) -> None:
        """Every camera counts as just seen: a wait that was no camera's fault (opening the
        devices, a pause) does not make the next sets look stalled (:data:`STALL_S`)."""
        now = self.clock()
        for cam in self.cameras:
            cam.last_seen = now

    # -- output
    def ready(self, flush: bool = False) -> list[FrameSet]:
        """Sets that can no longer change, in order; ``flush`` hands out everything pending."""
        out = []
        now = self.clock()
        while True:
            key = self.next_key
            slot = self._slots.get(key)
            if slot is None:
                if flush and self._slots and max(self._slots) > key:
                    slot = _Slot()  # a hole between pending sets: nothing arrived for it
                else:
                    break
            if not flush and not self._settled(key, slot, now):
                break
            if self.triggered and not slot.pulsed and not (flush or self.pulses_ended):
                break
            self._slots.pop(key, None)
            self.next_key += 1
            if self.triggered and not slot.pulsed:
                continue  # frames with no pulse behind them (after the trigger stopped): not a set
            out.append(self._finish(key, slot))
        return out

    def finished(self) -> bool:
        """The pulses have ended and every set they made has been handed out."""
        return self.pulses_ended and self.triggered and self.next_key > self.last_pulse_key

    def pending(self) -> int:
        return len(self._slots)

    def lead(self, camera: int) -> int:
        """How many sets camera ``camera`` is ahead of the next set to go out."""
        return self.cameras[camera].last_key - self.next_key

    def _settled(self, key: int, slot: _Slot, now: float) -> bool:
        for i, cam in enumerate(self.cameras):
            if i in slot.frames or cam.last_key > key or cam.ended:
                continue
            if now - cam.last_seen < STALL_S:
                return False
        return True

    def _finish(self, key: int, slot: _Slot) -> FrameSet:
        counter = key + (self.base or 0)
        frames: list[Frame | DetectedFrame | None] = [None] * len(self.cameras)
        for i, frame in slot.frames.items():
            frames[i] = frame if self._check_time(i, key, frame, slot.trigger_us) else None
        for i, f in enumerate(frames):
            if f is None:
                self.cameras[i].missed += 1
        return FrameSet(counter=counter, trigger_us=slot.trigger_us, frames=frames)

    def _check_time(self, camera: int, key: int, frame: Frame, trigger_us: int | None) -> bool:
        """Check a match against the clocks; realign the camera on a clean jump."""
        cam = self.cameras[camera]
        if trigger_us is None or not self.period_us:
            return True
        offset = frame.timestamp_us - trigger_us
        if cam.offset_us is None:
            cam.offset_us = cam.first_offset_us = float(offset)
            cam.first_trigger_us = cam.last_trigger_us = trigger_us
            return True
        jump = offset - cam.offset_us
        periods = round(jump / self.period_us)
        if abs(jump) <= REALIGN_TOLERANCE * self.period_us:
            cam.offset_us += CLOCK_SMOOTHING * jump
            cam.last_trigger_us = trigger_us
            return True
        name = self.camera_ids[camera]
        if periods != 0 and abs(jump - periods * self.period_us) <= REALIGN_TOLERANCE * self.period_us:
            # The frame belongs ``periods`` pulses later: the camera lost frames without a gap in
            # its sequence numbers. Move it and every pending frame of this camera along.
            self._shift_camera(camera, periods)
            if periods > 0:
                self._slot(key + periods).frames[camera] = frame
                cam.last_key = max(cam.last_key, key + periods)
            cam.realigned += 1
            self._say(camera, f"camera {name}: frame {frame.sequence} is {jump / 1000:.1f} ms off pulse "
                      f"{key + (self.base or 0)}; it lost {periods} frame(s) without a gap in its sequence "
                      "numbers; realigned by its timestamps")
            return False
        cam.misaligned += 1
        self._say(camera, f"camera {name}: frame {frame.sequence} is {jump / 1000:.1f} ms off pulse "
                  f"{key + (self.base or 0)}, not a whole number of frame periods ({self.period_us / 1000:.2f} ms); "
                  "its frames cannot be matched to the trigger and this one is left out. Check that the camera "
                  "is in external-trigger mode and wired to the strobe box")
        return False

    def _shift_camera(self, camera: int, periods: int) -> None:
        cam = self.cameras[camera]
        cam.shift += periods
        moved = [(k, slot.frames.pop(camera)) for k, slot in list(self._slots.items()) if camera in slot.frames]
        for k, frame in moved:
            if k + periods >= self.next_key:
                self._slot(k + periods).frames[camera] = frame
        cam.last_key += periods

    def _slot(self, key: int) -> _Slot:
        slot = self._slots.get(key)
        if slot is None:
            slot = self._slots[key] = _Slot()
        return slot

    def _say(self, camera: int, message: str) -> None:
        cam = self.cameras[camera]
        if cam.realigned + cam.misaligned > MAX_REPORTS:
            return  # a camera that keeps slipping would flood the log; the counts tell the rest
        if cam.realigned + cam.misaligned == MAX_REPORTS:
            message += " (further problems with this camera are only counted, in capture.json)"
        self.messages.append(message)
        self.report(message)
