"""Blob measurement: cut a thresholded image into regions of interest, label and measure each.

How detection stays fast (``docs/decisions/0003-blob-detector.md``): the markers are sparse, so
the detector first takes the maximum of every row (one cheap vectorised pass over the image),
keeps the bands of consecutive rows whose maximum is above the threshold, takes each band's
column maxima, and so cuts the image into small regions of interest that together hold every
bright pixel. Only those regions are labelled and measured. An 8-connected blob spans
consecutive rows and, inside its band, consecutive columns, so no blob is ever split between two
regions.

Centroids are weighted (``DetectConfig.weights``): by default with ``w = I - threshold`` over the
pixels above the threshold, so the weight falls continuously to zero at the blob's rim, which
removes most of the bias a plain grey-value centroid picks up from the pixels that happen to
cross the threshold; or with ``w = I`` (OpenPTV's weights).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from wandcal.calib.detect.config import DetectConfig
from wandcal.calib.errors import CalibrationError

# The footprint of one pixel adds this variance (px^2) along each axis (a uniform distribution
# over a unit interval has variance 1/12). Adding it keeps the roundness of a single pixel or a
# one-pixel-wide line finite and honest: a line L pixels long gets roundness ~1/L.
PIXEL_VARIANCE_PX2 = 1.0 / 12.0

# Columns of the table :func:`find_blobs` returns, one row per blob.
TABLE_COLUMNS = ("u", "v", "area", "roundness", "flux", "x_first", "y_first", "x_last", "y_last")


@dataclass(frozen=True, eq=False)
class Blobs:
    """The blobs found in one image, sorted by centroid row then column.

    Args:
        uv: (K, 2) float64 weighted centroids in pixels (x right, y down, pixel centres at
            integer coordinates).
        area: (K,) int64 pixel counts above the threshold.
        roundness: (K,) float64 minor/major axis ratio in (0, 1]; 1 is a round spot.
        flux: (K,) float64 summed centroid weight, grey levels: ``sum(I - threshold)`` with the
            default weights, ``sum(I)`` with ``weights="signal"`` (I after the background model).
        threshold: the grey level that was used (the automatic one when configured ``None``).
        background: the background model that was applied: ``"none"``, ``"highpass"``,
            ``"empty"`` or ``"running"`` (``"auto"`` resolves to one of the first two per frame).
    """

    uv: np.ndarray
    area: np.ndarray
    roundness: np.ndarray
    flux: np.ndarray
    threshold: float = float("nan")
    background: str = "none"

    def __post_init__(self) -> None:
        object.__setattr__(self, "uv", np.asarray(self.uv, dtype=np.float64).reshape(-1, 2))
        object.__setattr__(self, "area", np.asarray(self.area, dtype=np.int64).ravel())
        object.__setattr__(self, "roundness", np.asarray(self.roundness, dtype=np.float64).ravel())
        object.__setattr__(self, "flux", np.asarray(self.flux, dtype=np.float64).ravel())
        if not (len(self.uv) == len(self.area) == len(self.roundness) == len(self.flux)):
            raise CalibrationError("Blobs: uv, area, roundness and flux must have the same length")

    def __len__(self) -> int:
        return len(self.uv)

    @classmethod
    def empty(cls, threshold: float = float("nan"), background: str = "none") -> Blobs:
        return cls(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0), threshold, background)


def runs(index: np.ndarray) -> list[tuple[int, int]]:
    """Split sorted integer indices into runs of consecutive values: [(first, last), ...]."""
    # Plain slicing and lists: this runs a few times per frame, where np.diff/np.concatenate's
    # call overhead would cost more than the work.
    gaps = np.flatnonzero(index[1:] - index[:-1] > 1)
    starts = [int(index[0])] + index[gaps + 1].tolist()
    ends = index[gaps].tolist() + [int(index[-1])]
    return list(zip(starts, ends))


def roundness(m00: np.ndarray, mu20: np.ndarray, mu02: np.ndarray, mu11: np.ndarray) -> np.ndarray:
    """sqrt(lambda_min / lambda_max) of the weighted covariance plus the pixel footprint."""
    a = mu20 / m00 + PIXEL_VARIANCE_PX2
    c = mu02 / m00 + PIXEL_VARIANCE_PX2
    b = mu11 / m00
    half_gap = np.sqrt(((a - c) / 2.0) ** 2 + b**2)
    mean = (a + c) / 2.0
    return np.sqrt(np.maximum(mean - half_gap, 0.0) / (mean + half_gap))


def _drop_unseeded(weight: np.ndarray, roi: np.ndarray, seed: int) -> np.ndarray:
    """``weight`` with the 4-connected pieces that hold no pixel brighter than ``seed`` zeroed."""
    mask = (weight > 0).view(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=4)
    seeded = np.zeros(count, dtype=bool)
    seeded[labels[roi > seed]] = True
    seeded[0] = False
    if seeded[1:].all():
        return weight
    return np.where(seeded[labels], weight, 0).astype(weight.dtype)


def measure_roi(weight: np.ndarray, x0: int, y0: int, config: DetectConfig) -> list[tuple]:
    """Label one region of interest and measure each connected blob in it.

    Args:
        weight: (h, w) centroid weights of the region, zero outside the blobs.
        x0, y0: the region's top-left pixel in the image.

    Returns:
        rows of :data:`TABLE_COLUMNS` in image pixels.
    """
    # connectedComponents takes any non-zero 8-bit pixel for foreground, so 8-bit weights need
    # no mask of their own.
    mask = weight if weight.dtype == np.uint8 else (weight > 0).view(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=config.connectivity)
    out: list[tuple] = []
    if count == 2:
        # The common case, a region holding one blob: OpenCV's moments of the weights are exact
        # and cost a few microseconds, and no per-label statistics are needed.
        one_area = cv2.countNonZero(weight)
        if not config.min_area_px <= one_area <= config.max_area_px:
            return out
        m = cv2.moments(weight)
        mass = m["m00"]
        if mass <= 0:
            return out
        a, c, b = m["mu20"] / mass + PIXEL_VARIANCE_PX2, m["mu02"] / mass + PIXEL_VARIANCE_PX2, m["mu11"] / mass
        half_gap, mean = math.hypot((a - c) / 2.0, b), (a + c) / 2.0  # the eigenvalues, as roundness()
        one_round = math.sqrt(max(mean - half_gap, 0.0) / (mean + half_gap))
        h, w = weight.shape
        out.append((x0 + m["m10"] / mass, y0 + m["m01"] / mass, one_area, one_round, mass,
                    x0, y0, x0 + w - 1, y0 + h - 1))
        return out
    if count < 2:
        return out
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=config.connectivity)
    # Several blobs in one region (clutter, or blobs whose bands overlap): accumulate the weighted
    # moments of all of them at once from their labels.
    ys, xs = np.nonzero(mask)
    lab = labels[ys, xs]
    wv = weight[ys, xs].astype(np.float64)
    # Coordinates relative to each blob's bounding box keep the sums of squares small.
    xl = xs - stats[lab, cv2.CC_STAT_LEFT]
    yl = ys - stats[lab, cv2.CC_STAT_TOP]
    m00 = np.bincount(lab, wv, count)
    m10 = np.bincount(lab, wv * xl, count)
    m01 = np.bincount(lab, wv * yl, count)
    m20 = np.bincount(lab, wv * xl * xl, count)
    m02 = np.bincount(lab, wv * yl * yl, count)
    m11 = np.bincount(lab, wv * xl * yl, count)
    area = stats[:, cv2.CC_STAT_AREA]
    keep = np.flatnonzero((area >= config.min_area_px) & (area <= config.max_area_px) & (m00 > 0))
    keep = keep[keep > 0]  # label 0 is the background
    if len(keep) == 0:
        return out
    m00, m10, m01, m20, m02, m11 = (a[keep] for a in (m00, m10, m01, m20, m02, m11))
    ul, vl = m10 / m00, m01 / m00
    r = roundness(m00, m20 - ul * m10, m02 - vl * m01, m11 - ul * m01)
    left = stats[keep, cv2.CC_STAT_LEFT]
    top = stats[keep, cv2.CC_STAT_TOP]
    right = left + stats[keep, cv2.CC_STAT_WIDTH] - 1
    bottom = top + stats[keep, cv2.CC_STAT_HEIGHT] - 1
    out.extend(
        (
            x0 + left[i] + ul[i],
            y0 + top[i] + vl[i],
            int(area[keep[i]]),
            float(r[i]),
            float(m00[i]),
            x0 + int(left[i]),
            y0 + int(top[i]),
            x0 + int(right[i]),
            y0 + int(bottom[i]),
        )
        for i in range(len(keep))
    )
    return out


def find_blobs(image: np.ndarray, row_max: np.ndarray, level: int, config: DetectConfig) -> np.ndarray:
    """Every blob of ``image`` above ``level`` that passes the area filter, unsorted.

    Args:
        image: (H, W) uint8/uint16, already background-subtracted and masked.
        row_max: (H,) the maximum of every row of ``image`` (the caller has it already).
        level: the threshold, a grey level below ``row_max.max()``.
        config: weights, seed ratio, connectivity and area limits.

    Returns:
        (K, 9) float64 table of :data:`TABLE_COLUMNS`; roundness and border are not filtered yet.
    """
    level_value = image.dtype.type(level)  # below the peak, so it fits the image's dtype
    signal = config.weights == "signal"
    # The seed level is compared with grey levels, so round it down: "brighter than 2 x 9" is ">= 19".
    seed = int(config.seed_ratio * level) if config.seed_ratio > 1.0 else None
    rows = np.flatnonzero(row_max > level)
    found = []
    for r0, r1 in runs(rows):
        band = image[r0 : r1 + 1]
        band_max = band.max(axis=0)
        cols = np.flatnonzero(band_max > level)
        for c0, c1 in runs(cols):
            if seed is not None and band_max[c0 : c1 + 1].max() <= seed:
                continue  # nothing in this region reaches the seed level
            roi = band[:, c0 : c1 + 1]
            # Not cv2.subtract(roi, level): OpenCV's Python binding takes a (4, 1) array for a
            # scalar and then refuses the call.
            if signal:
                weight = np.where(roi > level_value, roi, 0).astype(roi.dtype)
            else:
                weight = np.maximum(roi, level_value) - level_value
            if seed is not None:
                weight = _drop_unseeded(weight, roi, seed)
            found.extend(measure_roi(weight, c0, r0, config))
    return np.array(found, dtype=np.float64).reshape(-1, len(TABLE_COLUMNS))
