"""Detection: bright marker blobs in camera images, and a camera's wand frames from them.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.detect.detector` | :func:`detect_blobs`, :class:`CameraDetector` (a camera's mask and background), :func:`detect_many` |
| :mod:`~wandcal.calib.detect.measure` | :class:`Blobs`: connected regions and their weighted centroids |
| :mod:`~wandcal.calib.detect.background` | background models: high-pass, empty-volume median, running |
| :mod:`~wandcal.calib.detect.masks` | per-camera masks of always-bright regions |
| :mod:`~wandcal.calib.detect.config` | :class:`DetectConfig`, the validated detection settings |
| :mod:`~wandcal.calib.detect.wand_frames` | per-frame blob lists to wand observations and static markers |
"""

from wandcal.calib.detect.config import BACKGROUNDS, DEFAULT_CONFIG, WEIGHTS, DetectConfig
from wandcal.calib.detect.detector import (
    STATEFUL,
    SUPPORTED_DTYPES,
    CameraDetector,
    auto_threshold,
    detect_blobs,
    detect_many,
    visible_mask,
)
from wandcal.calib.detect.measure import PIXEL_VARIANCE_PX2, Blobs
from wandcal.calib.detect.wand_frames import (
    STATIC_MIN_PRESENCE,
    STILL_RADIUS_PX,
    WAND_MARKERS,
    WAND_STILL_MIN_FRAMES,
    WAND_STILL_PRESENCE,
    WandFrames,
    static_markers_from_frames,
    wand_frames,
)

__all__ = [
    "BACKGROUNDS", "DEFAULT_CONFIG", "PIXEL_VARIANCE_PX2", "STATEFUL", "STATIC_MIN_PRESENCE", "STILL_RADIUS_PX",
    "SUPPORTED_DTYPES", "WAND_MARKERS", "WAND_STILL_MIN_FRAMES", "WAND_STILL_PRESENCE", "WEIGHTS", "Blobs",
    "CameraDetector", "DetectConfig", "WandFrames", "auto_threshold", "detect_blobs", "detect_many",
    "static_markers_from_frames", "visible_mask", "wand_frames",
]
