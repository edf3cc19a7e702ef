"""The capture's reader threads: one per camera, each detecting the blobs of its camera's frames
as they arrive and feeding them to the capture loop's inbox (:mod:`wandcal.capture.recording.session`);
during a free-running capture's pause they drain their cameras instead (grab and discard)."""

from __future__ import annotations

import queue
import threading
import time

from wandcal.calib.detect import CameraDetector
from wandcal.calib.errors import CalibrationError
from wandcal.capture.recording.framesets import Assembler, DetectedFrame
from wandcal.capture.recording.record import ImagePolicy
from wandcal.drivers.camera import CameraDriver, Frame
from wandcal.drivers.errors import DriverError, FrameError, FrameTimeout

READ_TIMEOUT_S = 0.2  # how soon a reader thread notices the stop flag while its camera waits for a pulse
END = object()  # a reader's last item: its camera has no more frames


class FrameDetector:
    """Turns one camera's frames into :class:`DetectedFrame` s, in the reader thread that read
    them (in time order, as a running background needs)."""

    def __init__(self, detector: CameraDetector, images: ImagePolicy, static_frames: int):
        self.detector, self.images, self.static_frames = detector, images, static_frames

    def __call__(self, frame: Frame) -> DetectedFrame:
        try:
            uv = self.detector.detect(frame.image).uv
        except CalibrationError as exc:  # the camera delivers frames the detector cannot read
            raise DriverError(f"camera {frame.camera_id}: cannot detect blobs in frame {frame.sequence} ({exc}); "
                              "set the camera to 8- or 16-bit grey output") from None
        keep = self.images.keeps(frame.sequence, self.static_frames)
        return DetectedFrame(frame.sequence, frame.timestamp_us, frame.camera_id, uv, frame.image if keep else None)


class Readers:
    """One thread per camera feeding ``(camera, DetectedFrame | FrameError | END)`` into the inbox.

    With ``pause_after`` K (a free-running capture that pauses after its K static sets), a reader
    whose camera has taken frame K - 1 no longer reads but drains (grabs and discards,
    :meth:`CameraDriver.discard`) until :meth:`resume`: the driver's buffers do not fill, and no
    frame shot while the L-frame leaves the volume reaches a set.
    """

    def __init__(self, cameras: list[CameraDriver], inbox: queue.Queue, assembler: Assembler, max_lead: int,
                 detectors: list[FrameDetector], pause_after: int = 0):
        self.stop = threading.Event()
        self.holding = threading.Event()
        if pause_after:
            self.holding.set()
        self.pause_after = pause_after
        self.taken = [-1] * len(cameras)  # each camera's last sequence number taken (read or discarded)
        self.resumed = [threading.Event() for _ in cameras]
        self.resumed_after = [-1] * len(cameras)  # each camera's last frame taken before the pause ended
        self.threads = [threading.Thread(target=self._run, args=(i, cam, inbox, assembler, max_lead, detectors[i]),
                                         name=f"read-{cam.camera_id}", daemon=True) for i, cam in enumerate(cameras)]
        for t in self.threads:
            t.start()

    def _run(self, i: int, cam: CameraDriver, inbox: queue.Queue, assembler: Assembler, max_lead: int,
             detect: FrameDetector) -> None:
        try:
            self._read_all(i, cam, inbox, assembler, max_lead, detect)
        finally:
            self.resumed[i].set()  # an ended camera does not hold the pause's end back

    def _read_all(self, i: int, cam: CameraDriver, inbox: queue.Queue, assembler: Assembler, max_lead: int,
                  detect: FrameDetector) -> None:
        while not self.stop.is_set():
            if self.holding.is_set() and self.taken[i] >= self.pause_after - 1:
                if not self._drain(i, cam, inbox):
                    return
                continue
            if not self.resumed[i].is_set() and not self.holding.is_set():
                self.resumed_after[i] = self.taken[i]
                self.resumed[i].set()
            if assembler.lead(i) > max_lead:
                time.sleep(0.002)  # the others are behind: wait instead of piling frames up
                continue
            item: Frame | DetectedFrame | DriverError | None
            try:
                item = cam.read(timeout=READ_TIMEOUT_S)
                if item is not None:
                    self.taken[i] = max(self.taken[i], item.sequence)
                    item = detect(item)
            except FrameTimeout:
                continue
            except DriverError as exc:
                item = exc
                if isinstance(exc, FrameError):
                    self.taken[i] = max(self.taken[i], exc.sequence)
            self._put(inbox, (i, END if item is None else item))
            if item is None or (isinstance(item, DriverError) and not isinstance(item, FrameError)):
                return

    def _drain(self, i: int, cam: CameraDriver, inbox: queue.Queue) -> bool:
        """One grab thrown away during the pause; False when the camera ended or failed (said
        in the inbox, as a read would)."""
        try:
            taken = cam.discard(timeout=READ_TIMEOUT_S)
        except FrameTimeout:
            return True
        except FrameError as exc:
            taken = exc.sequence
        except DriverError as exc:
            self._put(inbox, (i, exc))
            return False
        if taken is None:
            self._put(inbox, (i, END))
            return False
        self.taken[i] = max(self.taken[i], taken)
        return True

    def resume(self) -> int:
        """End the pause; the first set every camera can fill after it (frames up to the last one
        a camera discarded were shot during the pause, or past the static run before it)."""
        self.holding.clear()
        for done in self.resumed:
            while not done.wait(0.05) and not self.stop.is_set():
                pass
        return max(self.pause_after, max(self.resumed_after) + 1)

    def _put(self, inbox: queue.Queue, item) -> None:
        while not self.stop.is_set():
            try:
                inbox.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def join(self) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(timeout=2.0)
