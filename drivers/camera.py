"""The camera driver interface (ophyd-async / pymmcore-plus style).

A driver only fills frame buffers and reports frame metadata; threads, queues and the matching
of frames to trigger pulses belong to ``capture/``. Opening is a reentrant context manager: the
device opens on the first ``with`` and closes when the outermost one exits.
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from wandcal.calib.rig import Camera
from wandcal.drivers.errors import DriverError

# Frame rate assumed for sources that carry no timing (image sequences, folders without
# sync.csv): the usual motion-capture rate, so made-up timestamps still look plausible.
NOMINAL_FPS = 100.0


class TriggerMode(str, enum.Enum):
    """How a camera starts an exposure."""

    FREE_RUN = "free_run"  # the camera's own clock, at ``CameraSettings.fps``
    EXTERNAL = "external"  # one exposure per edge on the camera's trigger input (the strobe box)


class RunState(str, enum.Enum):
    CLOSED = "closed"
    OPEN = "open"


class CameraSettings(BaseModel):
    """Arming settings; validated and frozen, unknown fields are an error.

    ``exposure_us`` and ``gain`` of None keep the camera's current value; ``width``/``height`` of
    None keep its current resolution. ``fps`` is the free-run rate, or the expected pulse rate in
    external mode (a simulated camera uses it as its virtual trigger line's rate; None: as fast as
    it can render).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    trigger_mode: TriggerMode = TriggerMode.FREE_RUN
    exposure_us: float | None = Field(default=None, gt=0, le=1_000_000)
    gain: float | None = Field(default=None, ge=0)
    width: int | None = Field(default=None, gt=0)
    height: int | None = Field(default=None, gt=0)
    fps: float | None = Field(default=None, gt=0, le=10_000)


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame and its metadata.

    Args:
        image: (H, W) uint8 or uint16 grayscale.
        sequence: the camera's frame counter since the stream started; a gap means a lost frame.
        timestamp_us: device timestamp in microseconds (the camera's clock, arbitrary origin).
        camera_id: the camera that took it.
    """

    image: np.ndarray
    sequence: int
    timestamp_us: int
    camera_id: str


class CameraDriver:
    """Base class of camera drivers.

    Subclasses implement ``_open``, ``_close``, ``_apply(settings)`` and ``_read(timeout)``.
    ``read`` returns a :class:`Frame`, or None when a finite source (file, replay, simulation)
    has no more frames; it raises :class:`~wandcal.drivers.errors.FrameTimeout` when a live camera gave
    nothing within ``timeout`` seconds and :class:`~wandcal.drivers.errors.FrameError` for one lost frame.

    Attributes:
        camera_id: unique name, used as the folder name of its frames.
        url: the URL it was opened from, for messages.
        intrinsics: the camera's known :class:`wandcal.calib.rig.Camera`, when the source knows it.
        hardware_sequence: True when ``Frame.sequence`` counts exposures on the device (a gap is a
            lost frame); False when the driver counts the frames it received, so a lost frame
            shifts the count and only timestamps can match frames to pulses.
    """

    hardware_sequence = True

    def __init__(self, camera_id: str, url: str):
        self.camera_id = camera_id
        self.url = url
        self.intrinsics: Camera | None = None
        self.settings = CameraSettings()
        self._depth = 0
        self._lock = threading.RLock()

    @property
    def state(self) -> RunState:
        return RunState.OPEN if self._depth else RunState.CLOSED

    def open(self) -> CameraDriver:
        with self._lock:
            if self._depth == 0:
                self._open()
                self._apply(self.settings)
            self._depth += 1
        return self

    def close(self) -> None:
        with self._lock:
            if self._depth == 0:
                return
            self._depth -= 1
            if self._depth == 0:
                self._close()

    def __enter__(self) -> CameraDriver:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def configure(self, settings: CameraSettings | None = None, **changes) -> CameraSettings:
        """Apply ``settings`` (or the current ones with ``changes``); returns what is in force."""
        new = settings if settings is not None else self.settings.model_copy(update=changes)
        new = CameraSettings.model_validate(new.model_dump())  # model_copy skips validation
        with self._lock:
            if self._depth:
                self._apply(new)
            self.settings = new
        return new

    def read(self, timeout: float | None = None) -> Frame | None:
        if not self._depth:
            raise DriverError(f"camera {self.camera_id} ({self.url}) is not open; use it inside 'with camera:'")
        return self._read(timeout)

    def discard(self, timeout: float | None = None) -> int | None:
        """Grab a frame and throw it away: a free-running capture's pause drains its cameras so
        their buffers do not fill while nothing is recorded. Returns the sequence number of the
        last frame the camera has taken (-1: none yet), or None when a finite source has ended;
        raises as :meth:`read` does. A scripted source (the simulator) holds its script instead
        of spending it on a frame nobody keeps."""
        if not self._depth:
            raise DriverError(f"camera {self.camera_id} ({self.url}) is not open; use it inside 'with camera:'")
        return self._discard(timeout)

    # -- for subclasses
    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _apply(self, settings: CameraSettings) -> None:
        raise NotImplementedError

    def _read(self, timeout: float | None) -> Frame | None:
        raise NotImplementedError

    def _discard(self, timeout: float | None) -> int | None:
        frame = self._read(timeout)
        return None if frame is None else frame.sequence

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.camera_id} {self.url} {self.state.value}>"
