"""Per-camera detection masks: the pixels a camera's blob detector ignores.

A mask is an (H, W) boolean image, True where the camera's pixels are used and False where they
are blocked: a lamp, a shiny screw head, a reflection off the floor. Blocked pixels are set to zero
before thresholding, and a blob that touches a blocked pixel is dropped like one cut by the image
edge (part of it may lie under the mask, so its centroid would be biased).

:func:`block_visible` makes a mask automatically from a recording of the empty volume, as the
"block visible" step of commercial motion-capture software does: whatever is bright there is not a
marker, so it is blocked, with a margin.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from wandcal.calib.errors import CalibrationError

# A pixel is blocked when it is above the detection threshold in at least this fraction of the
# empty-volume frames. A steady reflection is there in every frame, a flickering one in some;
# someone walking out of the volume while it is recorded covers a pixel for a moment, well under
# a quarter of a few-second recording, and read noise at a 6-sigma threshold almost never.
BLOCK_PRESENCE = 0.25

# Blocked areas grow by this many pixels: a reflection's faint rim lies below the threshold in the
# empty frames but may rise above it in a later frame, and a marker passing right next to it should
# touch the mask (and be dropped) rather than merge with the rim into one biased blob.
BLOCK_MARGIN_PX = 2


def check_mask(mask, shape: tuple[int, int], where: str = "mask") -> np.ndarray:
    """A mask as a contiguous (H, W) bool array, True where pixels are used.

    Args:
        mask: (H, W) bool, or an integer image where non-zero means used (a PNG: black blocks).
        shape: the camera's (H, W).
        where: names the mask (its file, its camera) in an error.
    """
    if not isinstance(mask, np.ndarray) or mask.ndim != 2:
        raise CalibrationError(f"{where}: expected a 2-D image (H, W), got "
                               f"{getattr(mask, 'shape', type(mask).__name__)}; save masks as grey PNGs")
    if mask.shape != tuple(shape):
        raise CalibrationError(f"{where}: its size {mask.shape[1]}x{mask.shape[0]} differs from the camera's "
                               f"{shape[1]}x{shape[0]}; make the mask from this camera's frames")
    if mask.dtype != np.bool_ and not np.issubdtype(mask.dtype, np.integer):
        raise CalibrationError(f"{where}: pixel type {mask.dtype}; use a grey PNG (0 = ignored, else used)")
    used = np.ascontiguousarray(mask != 0)
    if not used.any():
        raise CalibrationError(f"{where}: blocks every pixel; a mask is black only where the camera should "
                               "not look")
    return used


class MaskIndex:
    """A checked mask with what detection needs of it, computed once per camera.

    Args:
        mask: see :func:`check_mask`.
        shape: the camera's (H, W).
        where: names the mask in errors.
    """

    def __init__(self, mask, shape: tuple[int, int], where: str = "mask"):
        self.used = check_mask(mask, shape, where)
        self.used_u8 = self.used.view(np.uint8)
        # Integral image of blocked pixels: the blocked count in any box in four lookups.
        self._blocked = cv2.integral((~self.used).view(np.uint8))
        self.fraction_used = float(self.used.mean())

    def apply(self, image: np.ndarray) -> np.ndarray:
        """``image`` with blocked pixels set to 0, in its dtype."""
        return np.multiply(image, self.used_u8, dtype=image.dtype)

    def touches(self, boxes: np.ndarray) -> np.ndarray:
        """(K,) bool: whether each box grown by one pixel holds a blocked pixel.

        Args:
            boxes: (K, 4) int ``x_first, y_first, x_last, y_last``.
        """
        boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
        height, width = self.used.shape
        x0 = np.clip(boxes[:, 0] - 1, 0, width)
        y0 = np.clip(boxes[:, 1] - 1, 0, height)
        x1 = np.clip(boxes[:, 2] + 2, 0, width)
        y1 = np.clip(boxes[:, 3] + 2, 0, height)
        s = self._blocked
        return (s[y1, x1] - s[y0, x1] - s[y1, x0] + s[y0, x0]) > 0


def block_visible(bright: Sequence[np.ndarray], presence: float = BLOCK_PRESENCE,
                  margin_px: int = BLOCK_MARGIN_PX, where: str = "empty-volume recording") -> np.ndarray:
    """The mask that blocks what is bright in an empty-volume recording ("block visible").

    Args:
        bright: N (H, W) bool images, True where a frame of the empty volume is above the
            detection threshold (see ``wandcal.calib.detect.CameraDetector.block_visible``).
        presence: fraction of the frames a pixel must be bright in to be blocked, (0, 1].
        margin_px: blocked areas grow by this many pixels (a square neighbourhood).

    Returns:
        (H, W) bool mask, True where pixels stay used.
    """
    if not 0.0 < presence <= 1.0:
        raise CalibrationError(f"block_visible: presence must lie in (0, 1], got {presence!r}")
    if margin_px < 0:
        raise CalibrationError(f"block_visible: margin_px must be >= 0, got {margin_px!r}")
    bright = list(bright)
    if not bright:
        raise CalibrationError(f"{where}: no frames; record a few frames of the empty volume to mask it")
    count = np.zeros(bright[0].shape, np.uint16)
    for i, b in enumerate(bright):
        if b.shape != count.shape:
            raise CalibrationError(f"{where}: frame {i} differs in size from frame 0")
        count += b
    blocked = (count >= max(1, int(np.ceil(presence * len(bright))))).view(np.uint8)
    if margin_px:
        kernel = np.ones((2 * margin_px + 1, 2 * margin_px + 1), np.uint8)
        blocked = np.asarray(cv2.dilate(blocked, kernel), np.uint8)
    used = blocked == 0
    if not used.any():
        raise CalibrationError(f"{where}: every pixel is bright in the empty volume; check the exposure, or "
                               "give a threshold")
    return used
