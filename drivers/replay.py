"""Replays the image level of a capture folder as cameras: ``replay:///path/to/capture``.

Query options: ``rate=max`` (default, as fast as possible) or ``rate=recorded`` (paced by the
recorded timestamps), ``phase=frames`` (default) or ``phase=static``, ``cameras=cam1,cam2``.
The frame number is the sequence number, so a frame missing from the recording is a gap.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import cv2

from wandcal.calib.rig import Camera
from wandcal.drivers.camera import NOMINAL_FPS, CameraDriver, CameraSettings, Frame, TriggerMode
from wandcal.drivers.capture_files import FRAMES_DIR, RIG_FILE, STATIC_DIR, SYNC_FILE
from wandcal.drivers.errors import DriverError, FrameError
from wandcal.drivers.imagefolder import (
    image_path,
    listed_cameras,
    listed_indices,
    read_sync,
)


class ReplayCamera(CameraDriver):
    """One camera of a recorded capture.

    Args:
        frames: (frame number, timestamp_us) of every image to replay, in order.
        paced: sleep so frames come at their recorded rate.
        clock, sleep: injected so tests can run pacing without waiting.
    """

    def __init__(self, camera_id: str, url: str, folder: Path, phase: str, frames: list[tuple[int, int]],
                 paced: bool = False, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        super().__init__(camera_id, url)
        self.folder = Path(folder)
        self.phase = phase
        self.frames = frames
        self.paced = paced
        self._clock, self._sleep = clock, sleep
        self._next = 0
        self._start: tuple[float, int] | None = None

    def _open(self) -> None:
        root = self.folder / self.phase / self.camera_id
        if not root.is_dir():
            raise DriverError(f"camera {self.camera_id}: {root} is missing; is {self.folder} an image-level capture?")
        self._next = 0
        self._start = None

    def _close(self) -> None:
        pass

    def _apply(self, settings: CameraSettings) -> None:
        if settings.trigger_mode is TriggerMode.EXTERNAL:
            raise DriverError(f"camera {self.camera_id}: a replay cannot be triggered; replay with trigger 'none'")

    def _read(self, timeout: float | None) -> Frame | None:
        if self._next >= len(self.frames):
            return None
        index, ts = self.frames[self._next]
        self._next += 1
        if self.paced:
            self._wait_until(ts)
        path = image_path(self.folder, self.phase, self.camera_id, index)
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise FrameError(f"camera {self.camera_id}: frame file {path} is missing or not a readable PNG; "
                             "that frame is skipped and the rest of the capture is replayed", sequence=index)
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        return Frame(image=image, sequence=index, timestamp_us=ts, camera_id=self.camera_id)

    def _discard(self, timeout: float | None) -> int | None:
        """A grab the capture throws away (its pause after the static sets): a recording holds, as
        the simulator's script does, so none of its frames is spent on the pause; a nominal frame
        period passes."""
        if self._next >= len(self.frames):
            return None
        self._sleep(1.0 / NOMINAL_FPS)
        if self._start is not None:
            self._start = (self._start[0] + 1.0 / NOMINAL_FPS, self._start[1])
        return self.frames[self._next - 1][0] if self._next else -1

    def _wait_until(self, ts: int) -> None:
        if self._start is None:
            self._start = (self._clock(), ts)
            return
        due = self._start[0] + (ts - self._start[1]) / 1e6
        delay = due - self._clock()
        if delay > 0:
            self._sleep(delay)


def open_replay(url: str, path: str, query: dict[str, str]) -> list[ReplayCamera]:
    folder = Path(path)
    if not folder.is_dir():
        raise DriverError(f"{url}: {folder} is not a folder; give the path of an image-level capture folder")
    for name in (SYNC_FILE, RIG_FILE):  # text whose cells an error message may quote
        if (folder / name).exists() and not (folder / name).resolve().is_relative_to(folder.resolve()):
            raise DriverError(f"{url}: {name} is a link leading outside {folder}; copy the file into the folder")
    phase = query.get("phase", FRAMES_DIR)
    if phase not in (FRAMES_DIR, STATIC_DIR):
        raise DriverError(f"{url}: phase must be '{FRAMES_DIR}' or '{STATIC_DIR}', not {phase!r}")
    rate = query.get("rate", "max")
    if rate not in ("max", "recorded"):
        raise DriverError(f"{url}: rate must be 'max' or 'recorded', not {rate!r}")
    ids = query["cameras"].split(",") if "cameras" in query else listed_cameras(folder, phase)
    if not ids:
        raise DriverError(f"{url}: {folder / phase} holds no camera folders; nothing to replay")
    try:
        sync = read_sync(folder) if phase == FRAMES_DIR else None
    except ValueError as exc:
        raise DriverError(f"{url}: {exc}") from None
    intrinsics = _intrinsics(folder)
    cams = []
    for cid in ids:
        present = listed_indices(folder, phase, cid)
        if sync is not None:
            have = set(present)
            stamped = [(r.frame, r.camera_us.get(cid)) for r in sync if r.frame in have]
            frames = [(n, ts if ts is not None else _nominal_us(n)) for n, ts in stamped]
        else:
            frames = [(n, _nominal_us(n)) for n in present]
        cam = ReplayCamera(cid, url, folder, phase, frames, paced=rate == "recorded")
        cam.intrinsics = intrinsics.get(cid)
        cams.append(cam)
    return cams


def _nominal_us(index: int) -> int:
    return int(round(index * 1e6 / NOMINAL_FPS))


def _intrinsics(folder: Path) -> dict[str, Camera]:
    # rig.json is optional for a replay; the capture layer reads it properly (capture/folder.py)
    path = folder / RIG_FILE
    try:
        doc = json.loads(path.read_text())
        return {c["id"]: Camera(id=c["id"], width=c["width"], height=c["height"], K=c["K"], dist=c["dist"],
                                model=c.get("model", "pinhole")) for c in doc["cameras"]}
    except (OSError, ValueError, KeyError, TypeError):
        return {}
