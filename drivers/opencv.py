"""Cameras and files through ``cv2.VideoCapture``: V4L2 devices, camera indices, video files
and image sequences.

URLs: ``v4l2:///dev/video0``, ``opencv:0``, ``opencv:/path/video.avi``,
``opencv:/path/frame_%06d.png``. Options in the query: ``id=`` (camera id), and for V4L2
``trigger=NAME=VALUE``, the device control that puts the camera in external-trigger mode
(docs/drivers.md lists common ones), or ``trigger=preset`` when it is already set.
"""

from __future__ import annotations

import shutil
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np

from wandcal.drivers.camera import NOMINAL_FPS, CameraDriver, CameraSettings, Frame, TriggerMode
from wandcal.drivers.errors import DriverError, FrameTimeout

V4L2_CTL = "v4l2-ctl"  # from v4l-utils; sets named device controls OpenCV cannot reach
US_PER_MS = 1000.0


class OpenCVCamera(CameraDriver):
    """A ``cv2.VideoCapture`` source.

    Args:
        camera_id: its name in the capture.
        url: for messages.
        source: a device index, a device path, a video file or an image-sequence pattern.
        api: a ``cv2.CAP_*`` backend (``cv2.CAP_V4L2`` for ``v4l2://``), or ``cv2.CAP_ANY``.
        trigger_control: ``"NAME=VALUE"`` for external-trigger mode, ``"preset"``, or None.
    """

    # OpenCV returns the frames it received; the device's own frame counter is not exposed, so
    # a frame lost in transfer does not leave a gap and capture/ matches frames by timestamp.
    hardware_sequence = False

    def __init__(self, camera_id: str, url: str, source: int | str, api: int = cv2.CAP_ANY,
                 trigger_control: str | None = None):
        super().__init__(camera_id, url)
        self.source = source
        self.api = api
        self.trigger_control = trigger_control
        self._cap: cv2.VideoCapture | None = None
        self._sequence = 0
        self._is_file = isinstance(source, str) and not source.startswith("/dev/")

    def _open(self) -> None:
        source = self.source
        if self._is_file and isinstance(source, str) and "%" not in source and not Path(source).is_file():
            raise DriverError(f"camera {self.camera_id}: {self.source} does not exist; check the path in {self.url}")
        cap = cv2.VideoCapture(self.source, self.api)
        if not cap.isOpened():
            cap.release()
            hint = ("check that the file is a readable video or that the pattern (e.g. frame_%06d.png) matches "
                    "files numbered from 0" if self._is_file else
                    "check that the camera is plugged in, not used by another program, and readable "
                    "by you (v4l2-ctl --list-devices; group 'video')")
            raise DriverError(f"camera {self.camera_id}: OpenCV could not open {self.url}; {hint}")
        self._cap = cap
        self._sequence = 0

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    @property
    def _capture(self) -> cv2.VideoCapture:
        """The open capture: the base class applies settings and reads only between _open and _close."""
        if self._cap is None:
            raise DriverError(f"camera {self.camera_id}: {self.url} is not open; open it first")
        return self._cap

    def _apply(self, settings: CameraSettings) -> None:
        if self._is_file:
            if settings.trigger_mode is TriggerMode.EXTERNAL:
                raise DriverError(f"camera {self.camera_id}: {self.url} is a file and cannot be triggered; "
                                  "use trigger mode free_run (or 'none' as the trigger URL)")
            return
        cap = self._capture
        wanted = [(cv2.CAP_PROP_EXPOSURE, settings.exposure_us, "exposure"),
                  (cv2.CAP_PROP_GAIN, settings.gain, "gain"),
                  (cv2.CAP_PROP_FRAME_WIDTH, settings.width, "width"),
                  (cv2.CAP_PROP_FRAME_HEIGHT, settings.height, "height"),
                  (cv2.CAP_PROP_FPS, settings.fps, "fps")]
        for prop, value, name in wanted:
            if value is not None and not cap.set(prop, float(value)):
                raise DriverError(f"camera {self.camera_id}: {self.url} refused {name}={value}; "
                                  f"list what it supports with 'v4l2-ctl -d {self.source} --all'")
        if settings.trigger_mode is TriggerMode.EXTERNAL:
            self._set_external_trigger()

    def _set_external_trigger(self) -> None:
        if self.trigger_control == "preset":
            return
        if self.trigger_control:
            set_v4l2_control(str(self.source), self.trigger_control, self.camera_id)
            return
        # Some OpenCV backends map CAP_PROP_TRIGGER to the device's trigger control; V4L2/UVC
        # devices mostly do not, so a refusal is the common case and gets the explicit advice.
        if not self._capture.set(cv2.CAP_PROP_TRIGGER, 1.0):
            raise DriverError(
                f"camera {self.camera_id}: {self.url} has no trigger control that OpenCV can set. Find the "
                f"camera's control with 'v4l2-ctl -d {self.source} --list-ctrls' (docs/drivers.md lists common "
                "ones) and add it to the URL, e.g. '?trigger=trigger_mode=1', or '?trigger=preset' if you set "
                "it yourself; a camera without a trigger input cannot be synchronised by the strobe box")

    def _read(self, timeout: float | None) -> Frame | None:
        start = time.monotonic()
        while not self._capture.grab():
            if self._is_file:
                return None  # end of the file or of the image sequence
            if timeout is not None and time.monotonic() - start >= timeout:
                raise FrameTimeout(f"camera {self.camera_id}: no frame from {self.url} within {timeout:.2f} s")
        ok, image = self._capture.retrieve()
        if not ok or image is None:
            return None if self._is_file else self._read(timeout)
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        seq = self._sequence
        self._sequence += 1
        return Frame(image=np.ascontiguousarray(image), sequence=seq, timestamp_us=self._timestamp_us(seq),
                     camera_id=self.camera_id)

    def _timestamp_us(self, seq: int) -> int:
        # V4L2 reports the buffer's capture time and files their presentation time in
        # CAP_PROP_POS_MSEC; image sequences report nothing, so fall back to the nominal rate.
        msec = self._capture.get(cv2.CAP_PROP_POS_MSEC)
        if msec and msec > 0:
            return int(round(msec * US_PER_MS))
        fps = self._capture.get(cv2.CAP_PROP_FPS)
        fps = fps if fps > 0 else (self.settings.fps or NOMINAL_FPS)
        return int(round(seq * 1e6 / fps))


def set_v4l2_control(device: str, assignment: str, camera_id: str) -> None:
    """Set one named V4L2 control (``"trigger_mode=1"``) on ``device`` with ``v4l2-ctl``."""
    tool = shutil.which(V4L2_CTL)
    if tool is None:
        raise DriverError(f"camera {camera_id}: setting '{assignment}' needs {V4L2_CTL}; install the "
                          "v4l-utils package (apt-get install v4l-utils)")
    done = subprocess.run([tool, "-d", device, "-c", assignment], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise DriverError(f"camera {camera_id}: {device} refused control '{assignment}': "
                          f"{done.stderr.strip() or done.stdout.strip()}; see 'v4l2-ctl -d {device} --list-ctrls'")
