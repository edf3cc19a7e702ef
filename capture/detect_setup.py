"""Per-camera detection inputs of a capture folder: masks and empty-volume recordings.

A capture folder may hold, beside its frames (docs/capture-format.md, "Detection inputs"):

    masks/<camera_id>.png               8-bit grey, the camera's size: 0 = ignored, else used
    background/<camera_id>/<n:06d>.png  frames of the empty volume (no markers in view)

:func:`camera_detectors` turns them and a :class:`DetectConfig` into one
:class:`wandcal.calib.detect.CameraDetector` per camera: the empty-volume background (per-pixel median)
for ``background="empty"``, and the mask, read from ``masks/``, from another folder, or made
automatically from the empty-volume recording ("block visible") and then saved to ``masks/``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from wandcal.calib.detect import CameraDetector, visible_mask
from wandcal.calib.detect.background import median_background
from wandcal.calib.detect.config import DetectConfig
from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Rig
from wandcal.capture.folder import CaptureFormatError
from wandcal.drivers.capture_files import BACKGROUND_DIR, FRAMES_DIR, MASKS_DIR
from wandcal.drivers.imagefolder import IMAGE_SUFFIX

# Frames of an empty-volume recording used per camera, evenly spread over it. The per-pixel
# median of 25 frames has ~1.25/5 = 0.25 of one frame's read noise, and 25 decoded 1280x1024
# 16-bit frames hold 66 MB: more frames would cost memory and decode time for little.
MAX_EMPTY_FRAMES = 25

# What ``mask`` may say besides a folder of masks/<camera_id>.png files.
MASK_FOLDER, MASK_NONE, MASK_AUTO = "folder", "none", "auto"


@dataclass(frozen=True)
class CameraSetup:
    """What detection of one camera uses besides the settings, for the report."""

    camera_id: str
    mask_source: str | None = None  # the file it was read from or written to; None: no mask
    masked_share: float = 0.0  # share of the pixels the mask blocks
    empty_frames: int = 0  # frames of the empty-volume recording used

    def line(self) -> str:
        parts = []
        if self.mask_source is not None:
            parts.append(f"mask {self.mask_source} blocks {100 * self.masked_share:.2f} % of the pixels")
        if self.empty_frames:
            parts.append(f"empty volume from {self.empty_frames} frames")
        return f"{self.camera_id}: " + ("; ".join(parts) if parts else "no mask, no empty-volume recording")


def _read_grey(path: Path) -> np.ndarray | None:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is not None and image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return image


def empty_frames(source: Path, camera_id: str, own: bool) -> list[np.ndarray]:
    """Up to :data:`MAX_EMPTY_FRAMES` frames of the empty volume for one camera.

    Args:
        source: the capture folder itself (``own``), or a folder holding the recording as
            ``background/<camera_id>/``, ``frames/<camera_id>/`` (an image-level capture recorded
            of the empty volume) or ``<camera_id>/``, looked up in that order.
        own: ``source`` is the capture being detected: only its ``background/`` counts (its
            ``frames/`` are the wand frames).
    """
    places = [BACKGROUND_DIR] if own else [BACKGROUND_DIR, FRAMES_DIR, "."]
    for place in places:
        folder = (source / place / camera_id).resolve()
        paths = sorted(folder.glob(f"*{IMAGE_SUFFIX}")) if folder.is_dir() else []
        if paths:
            pick = np.unique(np.linspace(0, len(paths) - 1, min(len(paths), MAX_EMPTY_FRAMES)).round().astype(int))
            frames = []
            for i in pick:
                image = _read_grey(paths[i])
                if image is None:
                    raise CaptureFormatError(f"{paths[i]}: cannot be read as an image; replace or delete it")
                frames.append(image)
            return frames
    where = " or ".join(str(source / p / camera_id) for p in places)
    raise CaptureFormatError(f"camera {camera_id}: no empty-volume frames in {where}; record a few frames with "
                             "no markers in view there (docs/capture-format.md, 'Detection inputs')")


def read_mask(path: Path, shape: tuple[int, int], camera_id: str) -> np.ndarray:
    """A camera's mask file as (H, W) bool, True where pixels are used."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise CaptureFormatError(f"{path}: cannot be read as an image; a mask is a grey PNG (0 = ignored)")
    if image.shape != tuple(shape):
        raise CaptureFormatError(f"{path}: {image.shape[1]}x{image.shape[0]}, but camera {camera_id} is "
                                 f"{shape[1]}x{shape[0]}; make the mask at the camera's size")
    return image != 0


def write_mask(path: Path, used: np.ndarray) -> None:
    """Save a mask as an 8-bit PNG: 255 where used, 0 where blocked."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), used.astype(np.uint8) * 255):
        raise CaptureFormatError(f"{path}: cannot write the mask here; check the folder's permissions")


def camera_detectors(folder: Path, rig: Rig, config: DetectConfig, mask: str | Path = MASK_FOLDER,
                     empty: Path | None = None) -> tuple[dict[str, CameraDetector], list[CameraSetup]]:
    """One :class:`CameraDetector` per rig camera, with its mask and empty-volume background.

    Args:
        folder: the capture folder.
        rig: its cameras (ids and image sizes).
        config: the detection settings.
        mask: ``"folder"`` (``masks/<camera_id>.png`` where present), ``"none"``, ``"auto"`` (block
            what is bright in the empty-volume recording, and save it to ``masks/``), or a folder
            holding ``<camera_id>.png`` files.
        empty: where the empty-volume recording is (see :func:`empty_frames`); None: the
            capture's own ``background/``. Needed for ``config.background == "empty"`` and
            ``mask="auto"``.

    Returns:
        the detectors by camera id, and what each uses, for the report.
    """
    folder = Path(folder)
    source, own = (folder, True) if empty is None else (Path(empty), False)
    detectors, setups = {}, []
    for cam in rig.cameras:
        shape = (cam.height, cam.width)
        frames = (empty_frames(source, cam.id, own)
                  if config.background == "empty" or mask == MASK_AUTO else [])
        for i, f in enumerate(frames):
            if f.shape != shape:
                raise CaptureFormatError(f"camera {cam.id}: empty-volume frame {i} is {f.shape[1]}x{f.shape[0]}, "
                                         f"rig.json says {cam.width}x{cam.height}; record it with this camera")
        try:
            background = median_background(frames, f"camera {cam.id}: empty volume") \
                if config.background == "empty" else None
            used, mask_source = None, None
            if mask == MASK_AUTO:
                probe = CameraDetector(config, background=background, camera=cam.id)
                used = visible_mask(frames, probe)
                mask_source = str(folder / MASKS_DIR / f"{cam.id}.png")
                write_mask(Path(mask_source), used)
            elif mask != MASK_NONE:
                path = (folder / MASKS_DIR if mask == MASK_FOLDER else Path(mask)) / f"{cam.id}.png"
                if path.is_file():
                    used, mask_source = read_mask(path, shape, cam.id), str(path)
                elif mask != MASK_FOLDER:
                    raise CaptureFormatError(f"{path}: no mask for camera {cam.id}; add one, or detect "
                                             "without --mask")
            detectors[cam.id] = CameraDetector(config, mask=used, background=background, camera=cam.id)
        except CalibrationError as exc:
            if isinstance(exc, CaptureFormatError):
                raise
            raise CaptureFormatError(str(exc)) from None
        share = 0.0 if used is None else 1.0 - float(used.mean())
        setups.append(CameraSetup(cam.id, mask_source, share, len(frames) if background is not None else 0))
    return detectors, setups
