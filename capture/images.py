"""Detection over the image level of a capture folder: writes its points level.

``wandcal detect CAPTURE`` and :func:`ensure_points_level` (used by ``wandcal calibrate``) run
:mod:`wandcal.calib.detect` over ``frames/`` and ``static/`` and write ``wand.csv`` and ``static.csv``
next to the images (docs/capture-format.md). Each camera has its own
:class:`wandcal.calib.detect.CameraDetector`, with the mask and empty-volume background that
:mod:`wandcal.capture.detect_setup` finds for it.

Decoding a 1280x1024 PNG costs ~6 ms and detecting its blobs ~0.3 ms, so a worker thread takes
whole files: it decodes *and* detects, and hands back only the small blob arrays. ``cv2.imread``
and the detector's OpenCV/NumPy calls release the GIL, so two threads decode two files at once
(docs/decisions/0006-parallel-detection.md). A running background needs a camera's frames in
order, so with it the threads only decode and the detection runs in order as the images come back.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Generator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, field
from itertools import islice
from pathlib import Path

import cv2
import numpy as np

from wandcal.calib.detect import (
    Blobs,
    CameraDetector,
    DetectConfig,
    static_markers_from_frames,
    wand_frames,
)
from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import StaticObservations, WandObservations
from wandcal.capture.detect_setup import MASK_FOLDER, CameraSetup, camera_detectors
from wandcal.capture.folder import CaptureFormatError, read_rig, write_capture
from wandcal.drivers.capture_files import FRAMES_DIR, STATIC_DIR, WAND_FILE
from wandcal.drivers.imagefolder import image_path, listed_indices

# Files queued per worker thread. A queued file is only a path and a finished one a few blob
# arrays; each worker holds one decoded image at a time, so memory stays at ``workers`` frames
# (1.3 MB each at 8 bits) whatever the capture's length, and the queue never runs dry.
QUEUED_PER_WORKER = 4

# Images between progress reports: ~0.1 s of detection on two cores, so a bar moves smoothly
# without writing a service job's progress row hundreds of times a second.
PROGRESS_EVERY = 32


@dataclass
class CameraDetection:
    """One camera's detection counts."""

    camera_id: str
    images: int = 0
    wand_frames: int = 0
    too_few: int = 0
    too_many: int = 0
    still_markers: int = 0
    static_images: int = 0
    static_markers: int = 0
    unreadable: list[str] = field(default_factory=list)
    highpass_images: int = 0  # images whose background was not flat ("auto" used the high-pass)
    setup: CameraSetup | None = None  # its mask and empty-volume background

    def line(self, expected_static: int | None) -> str:
        text = (f"{self.camera_id}: {self.wand_frames} wand frames of {self.images} images; dropped "
                f"{self.too_few} with 0-1 blobs, {self.too_many} with more than 2")
        if not self.images:
            text += (f"; no images: {FRAMES_DIR}/{self.camera_id}/ is missing or empty (copy that camera's images "
                     "there and detect again, or remove the camera from rig.json)")
        if self.highpass_images:
            text += f"; glare or an uneven background in {self.highpass_images} image(s): high-pass applied"
        if self.still_markers:
            text += f", ignored {self.still_markers} still marker(s)"
        if self.unreadable:
            text += f", {len(self.unreadable)} unreadable image(s) (first: {self.unreadable[0]})"
        if self.static_images:
            text += f"; static object: {self.static_markers} markers in {self.static_images} images"
            if expected_static is not None and self.static_markers != expected_static:
                text += f" (rig.json lists {expected_static}: check that the whole L-frame is in view)"
        return text


def _decode(path: Path) -> np.ndarray | None:
    """One image as (H, W) grey, or None when the file cannot be decoded."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is not None and image.ndim == 3 and image.shape[2] in (3, 4):
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return image


def _detect_image(path: Path, image: np.ndarray, detector: CameraDetector) -> Blobs:
    try:
        return detector.detect(image)
    except (CalibrationError, cv2.error) as exc:
        raise CaptureFormatError(f"{path}: cannot detect blobs in this image ({exc}); store the camera's "
                                 "raw frames as 8- or 16-bit grey PNGs") from None


def _detect_file(path: Path, detector: CameraDetector) -> Blobs | np.ndarray | None:
    """Decode one image and detect its blobs (None: undecodable). A detector with a running
    background gets the decoded image back instead, to detect in order."""
    image = _decode(path)
    if image is None or detector.running is not None:
        return image
    return _detect_image(path, image, detector)


def _detect_files(paths: list[Path], detectors: list[CameraDetector], workers: int) -> Generator[Blobs | None, None, None]:
    """Blobs per file, in the order given (None for a file that cannot be decoded).

    With ``workers`` > 1 each file is decoded (and, without a running background, detected) by
    one thread of a pool, at most ``QUEUED_PER_WORKER * workers`` files ahead of the consumer.
    Close the iterator to stop early.
    """
    def finish(path: Path, detector: CameraDetector, out) -> Blobs | None:
        return _detect_image(path, out, detector) if isinstance(out, np.ndarray) else out

    if workers <= 1:
        yield from (finish(p, d, _detect_file(p, d)) for p, d in zip(paths, detectors))
        return
    pool = ThreadPoolExecutor(workers, thread_name_prefix="wandcal-detect")
    pending: deque[tuple[Path, CameraDetector, Future]] = deque()
    try:
        for p, d in zip(paths, detectors):
            pending.append((p, d, pool.submit(_detect_file, p, d)))
            if len(pending) >= QUEUED_PER_WORKER * workers:
                path, detector, future = pending.popleft()
                yield finish(path, detector, future.result())
        while pending:
            path, detector, future = pending.popleft()
            yield finish(path, detector, future.result())
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def detect_capture(folder: str | Path, config: DetectConfig | None = None, workers: int | None = None,
                   progress: Callable[[dict], None] | None = None,
                   static_only_ok: bool = False, mask: str | Path = MASK_FOLDER,
                   empty: Path | None = None) -> list[CameraDetection]:
    """Detect blobs in every image of an image-level capture and write wand.csv / static.csv.

    Args:
        folder: the capture folder (rig.json, frames/<camera_id>/*.png, optional static/).
        config: the detection settings (None: the defaults).
        workers: threads that each decode and detect whole images (None: every core; 1: this thread).
        progress: called with ``{"stage": "detect", "done", "total", "message"}`` as images are done.
        static_only_ok: accept a folder with static images but no wand frames (a live capture
            stopped before its wand run): it gets an empty wand.csv.
        mask: the cameras' masks: ``"folder"`` (the capture's ``masks/``, where present),
            ``"none"``, ``"auto"`` or a folder (:func:`wandcal.capture.detect_setup.camera_detectors`).
        empty: where the empty-volume recording is, for ``background="empty"`` and ``mask="auto"``
            (None: the capture's own ``background/``).

    Returns:
        one :class:`CameraDetection` per rig camera. An unreadable image is skipped and counted.
    """
    folder = Path(folder)
    rig = read_rig(folder)
    frames = {cid: listed_indices(folder, FRAMES_DIR, cid) for cid in rig.ids}
    statics = {cid: listed_indices(folder, STATIC_DIR, cid) for cid in rig.ids}
    if not any(frames.values()) and not (static_only_ok and any(statics.values())):
        raise CaptureFormatError(f"{folder / FRAMES_DIR}: no images; record with 'wandcal capture' first, or give "
                                 "a points-level folder with wand.csv")
    workers = _cores() if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be at least 1 (or None for every core), got {workers}")
    detectors, setups = camera_detectors(folder, rig, config or DetectConfig(), mask, empty)
    # One stream of files over every camera, frames then static images: the workers never wait at
    # the end of one camera for the next to start.
    paths = [image_path(folder, phase, cid, i) for cid in rig.ids
             for phase, listed in ((FRAMES_DIR, frames), (STATIC_DIR, statics)) for i in listed[cid]]
    owners = [detectors[cid] for cid in rig.ids
              for phase, listed in ((FRAMES_DIR, frames), (STATIC_DIR, statics)) for _ in listed[cid]]
    reports = []
    rows_f, rows_c, rows_uv, st_c, st_uv = [], [], [], [], []
    with closing(_detect_files(paths, owners, workers)) as found:
        take = _Found(zip(paths, found), len(paths), detectors, progress).take
        for c, cid in enumerate(rig.ids):
            report = CameraDetection(cid, images=len(frames[cid]), static_images=len(statics[cid]), setup=setups[c])
            blobs = take(len(frames[cid]), report)
            readable = [(i, b) for i, b in zip(frames[cid], blobs) if b is not None]
            kept = wand_frames([b for _, b in readable])
            report.wand_frames, report.too_few, report.too_many = len(kept), kept.too_few, kept.too_many
            report.still_markers = len(kept.still_uv)
            for k, uv in zip(kept.frame, kept.uv):
                rows_f += [readable[k][0]] * 2
                rows_c += [c, c]
                rows_uv += [uv[0], uv[1]]
            if statics[cid]:
                markers = static_markers_from_frames([b for b in take(len(statics[cid]), report) if b is not None])
                report.static_markers = len(markers)
                st_c += [c] * len(markers)
                st_uv += list(markers)
            reports.append(report)
    wand = WandObservations(frame=np.array(rows_f, dtype=np.int64), camera=np.array(rows_c, dtype=np.int64),
                            uv=np.array(rows_uv).reshape(-1, 2))
    static = None
    if any(statics.values()) and rig.static_markers is not None:
        static = StaticObservations(camera=np.array(st_c, dtype=np.int64), uv=np.array(st_uv).reshape(-1, 2))
    write_capture(folder, rig, wand, static)
    return reports


class _Found:
    """The detected files, in the order of the stream, handed out camera by camera; reports
    progress as they are taken."""

    def __init__(self, files, total: int, detectors: dict, progress: Callable[[dict], None] | None):
        self.files, self.total, self.detectors, self.progress = files, total, detectors, progress
        self.done = 0

    def take(self, count: int, report: CameraDetection) -> list[Blobs | None]:
        """The next ``count`` files' blobs; names the unreadable ones in ``report``."""
        out = []
        for path, blobs in islice(self.files, count):
            if blobs is None:
                report.unreadable.append(str(path))
            elif blobs.background == "highpass" and self.detectors[report.camera_id].config.background == "auto":
                report.highpass_images += 1
            out.append(blobs)
            self.done += 1
            if self.progress and (self.done % PROGRESS_EVERY == 0 or self.done == self.total):
                self.progress({"stage": "detect", "done": self.done, "total": self.total,
                               "message": f"detecting blobs ({report.camera_id})"})
        return out


def ensure_points_level(folder: str | Path, progress: Callable[[dict], None] | None = None) -> Path:
    """Return ``folder`` with a points level, running detection first if wand.csv is missing."""
    folder = Path(folder)
    if not (folder / WAND_FILE).is_file():
        detect_capture(folder, progress=progress)
    return folder
