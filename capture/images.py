"""Detection over the image level of a capture folder: writes its points level.

``wandcal detect CAPTURE`` and :func:`ensure_points_level` (used by ``wandcal calibrate``) run
:mod:`calib.detect` over ``frames/`` and ``static/`` and write ``wand.csv`` and ``static.csv``
next to the images (docs/capture-format.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calib.detect import Blobs, DetectConfig, detect_many, static_markers_from_frames, wand_frames
from calib.rig import StaticObservations, WandObservations
from capture.folder import WAND_FILE, CaptureFormatError, read_rig, write_capture
from drivers.imagefolder import FRAMES_DIR, STATIC_DIR, image_path, listed_indices

CHUNK = 64  # images read and detected at a time: bounds memory (~80 MB at 1.3 Mpx) and feeds both cores


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

    def line(self, expected_static: int | None) -> str:
        text = (f"{self.camera_id}: {self.wand_frames} wand frames of {self.images} images; dropped "
                f"{self.too_few} with 0-1 blobs, {self.too_many} with more than 2")
        if self.still_markers:
            text += f", ignored {self.still_markers} still marker(s)"
        if self.unreadable:
            text += f", {len(self.unreadable)} unreadable image(s) (first: {self.unreadable[0]})"
        if self.static_images:
            text += f"; static object: {self.static_markers} markers in {self.static_images} images"
            if expected_static is not None and self.static_markers != expected_static:
                text += f" (rig.json lists {expected_static}: check that the whole L-frame is in view)"
        return text


def _detect_files(paths: list[Path], config: DetectConfig | None, workers: int | None,
                  report: CameraDetection, tick: Callable[[int], None]) -> list[Blobs | None]:
    """Blobs per file, None for a file that cannot be read (named in ``report.unreadable``)."""
    out: list[Blobs | None] = []
    for start in range(0, len(paths), CHUNK):
        chunk = paths[start:start + CHUNK]
        images = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in chunk]
        for p, im in zip(chunk, images):
            if im is None:
                report.unreadable.append(str(p))
        good = [im if im.ndim == 2 else cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in images if im is not None]
        found = iter(detect_many(good, config, workers) if good else [])
        out.extend(next(found) if im is not None else None for im in images)
        tick(len(chunk))
    return out


def detect_capture(folder: str | Path, config: DetectConfig | None = None, workers: int | None = None,
                   progress: Callable[[dict], None] | None = None) -> list[CameraDetection]:
    """Detect blobs in every image of an image-level capture and write wand.csv / static.csv.

    Args:
        folder: the capture folder (rig.json, frames/<camera_id>/*.png, optional static/).
        workers: detection threads (None: every core).
        progress: called with ``{"stage": "detect", "done", "total", "message"}`` as images are done.

    Returns:
        one :class:`CameraDetection` per rig camera. An unreadable image is skipped and counted.
    """
    folder = Path(folder)
    rig = read_rig(folder)
    frames = {cid: listed_indices(folder, FRAMES_DIR, cid) for cid in rig.ids}
    statics = {cid: listed_indices(folder, STATIC_DIR, cid) for cid in rig.ids}
    if not any(frames.values()):
        raise CaptureFormatError(f"{folder / FRAMES_DIR}: no images; record with 'wandcal capture' first, or give "
                                 "a points-level folder with wand.csv")
    total = sum(map(len, frames.values())) + sum(map(len, statics.values()))
    done = 0
    reports = []
    rows_f, rows_c, rows_uv, st_c, st_uv = [], [], [], [], []
    for c, cid in enumerate(rig.ids):
        report = CameraDetection(cid, images=len(frames[cid]), static_images=len(statics[cid]))

        def tick(n: int, cid=cid) -> None:
            nonlocal done
            done += n
            if progress:
                progress({"stage": "detect", "done": done, "total": total, "message": f"detecting blobs ({cid})"})

        paths = [image_path(folder, FRAMES_DIR, cid, i) for i in frames[cid]]
        blobs = _detect_files(paths, config, workers, report, tick)
        readable = [(i, b) for i, b in zip(frames[cid], blobs) if b is not None]
        kept = wand_frames([b for _, b in readable])
        report.wand_frames, report.too_few, report.too_many = len(kept), kept.too_few, kept.too_many
        report.still_markers = len(kept.still_uv)
        for k, uv in zip(kept.frame, kept.uv):
            rows_f += [readable[k][0]] * 2
            rows_c += [c, c]
            rows_uv += [uv[0], uv[1]]
        if statics[cid]:
            paths = [image_path(folder, STATIC_DIR, cid, i) for i in statics[cid]]
            sblobs = [b for b in _detect_files(paths, config, workers, report, tick) if b is not None]
            markers = static_markers_from_frames(sblobs)
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


def ensure_points_level(folder: str | Path, progress: Callable[[dict], None] | None = None) -> Path:
    """Return ``folder`` with a points level, running detection first if wand.csv is missing."""
    folder = Path(folder)
    if not (folder / WAND_FILE).is_file():
        detect_capture(folder, progress=progress)
    return folder
