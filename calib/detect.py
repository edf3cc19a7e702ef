"""Bright-blob detection for IR images of wand and static-object markers.

Retro-reflective or LED markers appear as small bright spots on a dark background. This module
finds them and measures sub-pixel centroids, then turns per-frame blob lists into wand
observations (frames that show exactly the two wand markers) and static-object marker positions
(blobs that stay put, averaged over time).

Pixel convention (``docs/conventions.md``, as OpenCV): origin at the top-left, x right, y down,
pixel centres at integer coordinates, so a single lit pixel at column 3, row 7 has centroid
``(3.0, 7.0)``.

How detection stays fast (``docs/decisions/0003-blob-detector.md``): the markers are sparse, so
the detector first takes the maximum of every row (one cheap vectorised pass over the image),
keeps the bands of consecutive rows whose maximum is above the threshold, takes each band's
column maxima, and so cuts the image into small regions of interest that together hold every
bright pixel. Only those regions are labelled and measured. An 8-connected blob spans
consecutive rows and, inside its band, consecutive columns, so no blob is ever split between two
regions.

Centroids are intensity-weighted with background-subtracted weights ``w = I - threshold`` over the
pixels above the threshold: subtracting the threshold makes the weight fall continuously to zero
at the blob's rim, which removes most of the bias a plain grey-value centroid picks up from the
pixels that happen to cross the threshold.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.special import erf

from calib.errors import CalibrationError

SUPPORTED_DTYPES = (np.uint8, np.uint16)  # what IR machine-vision cameras deliver (8-bit, or 10-16 bit in uint16)

# The footprint of one pixel adds this variance (px^2) along each axis (a uniform distribution
# over a unit interval has variance 1/12). Adding it keeps the roundness of a single pixel or a
# one-pixel-wide line finite and honest: a line L pixels long gets roundness ~1/L.
PIXEL_VARIANCE_PX2 = 1.0 / 12.0

# Subsampling step for the background statistics of the automatic threshold. Every 32nd pixel of
# every 32nd row gives 1,280 samples at 1280x1024: the standard error of a percentile-based sigma
# from n samples is ~1.1/sqrt(n), 3 % here, so a 6-sigma threshold lands within 5.8-6.2 sigma.
# Each sample costs a cache miss on a frame fresh from the camera, so fewer is faster: 16 us per
# frame, against ~50-90 us for a 16-step grid (8/16-bit) and 130 us for np.percentile on an 8-step one.
AUTO_SAMPLE_STEP = 32

# One standard deviation of a normal distribution lies between its 50th and 84.13th percentiles.
# The upper one-sided spread is used because sparse bright markers barely move the 84th percentile.
ONE_SIGMA_QUANTILE = 0.84134


@dataclass(frozen=True)
class DetectConfig:
    """Settings of :func:`detect_blobs`.

    Args:
        threshold: absolute grey level (a whole number); pixels strictly brighter are blob
            pixels and weigh ``I - threshold``. ``None`` picks
            one per image: the background median plus the larger of ``auto_noise_sigmas`` noise
            standard deviations and ``auto_peak_fraction`` of the (peak - background) range.
        min_area_px: smallest blob, in pixels. The default 4 rejects hot pixels and lone noise
            pixels; a marker blurred with sigma >= 0.7 px covers at least 4 pixels above a
            threshold at a quarter of its peak.
        max_area_px: largest blob, in pixels. 1500 px is a disc of ~44 px diameter, far larger
            than a marker at working distance; bigger blobs are reflections, lamps or flares.
        min_roundness: smallest ratio of minor to major axis (sqrt of the eigenvalue ratio of the
            weighted pixel covariance, plus the pixel footprint). 0.5 admits the 2:1 smear of a
            marker moving fast during the exposure and rejects streaks, edges and cables.
        reject_border: drop blobs that touch the image edge; part of such a blob is cut off, so
            its centroid is biased toward the inside.
        connectivity: 8 joins pixels that touch at a corner into one blob (a blurred marker is
            8-connected); 4 joins only edge neighbours, as OpenPTV's ``targ_rec`` does.
        auto_noise_sigmas: automatic threshold, noise term. At 6 sigma a Gaussian read noise
            lifts about one pixel in 10^9 above it, i.e. ~0.001 false pixels per 1.3 Mpx frame.
        auto_peak_fraction: automatic threshold, contrast term: keeps the faint halo of a bright
            frame (and quantisation steps of a noise-free one) out of the blobs.
    """

    threshold: float | None = None
    min_area_px: int = 4
    max_area_px: int = 1500
    min_roundness: float = 0.5
    reject_border: bool = True
    connectivity: int = 8
    auto_noise_sigmas: float = 6.0
    auto_peak_fraction: float = 0.05

    def __post_init__(self) -> None:
        if self.threshold is not None and not (
            np.isfinite(self.threshold) and self.threshold >= 0 and float(self.threshold).is_integer()
        ):
            raise CalibrationError(
                f"DetectConfig.threshold must be a whole grey level >= 0 or None (automatic), got {self.threshold!r}"
            )
        if not (isinstance(self.min_area_px, (int, np.integer)) and self.min_area_px >= 1):
            raise CalibrationError(f"DetectConfig.min_area_px must be an integer >= 1, got {self.min_area_px!r}")
        if not (isinstance(self.max_area_px, (int, np.integer)) and self.max_area_px >= self.min_area_px):
            raise CalibrationError(
                f"DetectConfig.max_area_px must be an integer >= min_area_px ({self.min_area_px}), "
                f"got {self.max_area_px!r}"
            )
        if self.connectivity not in (4, 8):
            raise CalibrationError(f"DetectConfig.connectivity must be 4 or 8, got {self.connectivity!r}")
        if not 0.0 <= self.min_roundness <= 1.0:
            raise CalibrationError(f"DetectConfig.min_roundness must lie in [0, 1], got {self.min_roundness!r}")
        if not (self.auto_noise_sigmas >= 0 and 0.0 <= self.auto_peak_fraction < 1.0):
            raise CalibrationError(
                "DetectConfig.auto_noise_sigmas must be >= 0 and auto_peak_fraction in [0, 1)"
            )


DEFAULT_CONFIG = DetectConfig()


@dataclass(frozen=True, eq=False)
class Blobs:
    """The blobs found in one image, sorted by centroid row then column.

    Args:
        uv: (K, 2) float64 intensity-weighted centroids in pixels (x right, y down, pixel
            centres at integer coordinates).
        area: (K,) int64 pixel counts above the threshold.
        roundness: (K,) float64 minor/major axis ratio in (0, 1]; 1 is a round spot.
        flux: (K,) float64 summed weight ``sum(I - threshold)``, grey levels.
        threshold: the grey level that was used (the automatic one when configured ``None``).
    """

    uv: np.ndarray
    area: np.ndarray
    roundness: np.ndarray
    flux: np.ndarray
    threshold: float = float("nan")

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
    def empty(cls, threshold: float = float("nan")) -> Blobs:
        return cls(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0), threshold)


def _check_image(image: np.ndarray, where: str = "image") -> np.ndarray:
    if not isinstance(image, np.ndarray):
        raise CalibrationError(f"{where}: expected a numpy array, got {type(image).__name__}")
    if image.ndim != 2:
        raise CalibrationError(
            f"{where}: expected a 2-D grayscale array (H, W), got ndim={image.ndim} shape {image.shape}; "
            "convert colour frames to grey before detection"
        )
    if image.dtype not in SUPPORTED_DTYPES:
        raise CalibrationError(
            f"{where}: expected dtype uint8 or uint16, got {image.dtype}; "
            "pass the camera's raw 8- or 16-bit frame"
        )
    if image.size == 0:
        raise CalibrationError(f"{where}: the image is empty (shape {image.shape})")
    return np.ascontiguousarray(image)


def auto_threshold(image: np.ndarray, peak: float, config: DetectConfig = DEFAULT_CONFIG) -> float:
    """The automatic threshold of :class:`DetectConfig` for ``image``, a grey level.

    Args:
        image: (H, W) uint8 or uint16.
        peak: the image's maximum grey level (the caller has it already).
    """
    sample = image[::AUTO_SAMPLE_STEP, ::AUTO_SAMPLE_STEP].ravel()
    median_at, upper_at = sample.size // 2, min(int(sample.size * ONE_SIGMA_QUANTILE), sample.size - 1)
    ordered = np.partition(sample, [median_at, upper_at])
    background, upper = float(ordered[median_at]), float(ordered[upper_at])
    sigma = upper - background
    margin = max(config.auto_noise_sigmas * sigma, config.auto_peak_fraction * (peak - background))
    # At least one grey level above the background, or a flat frame would be all "blob".
    return float(np.ceil(background + max(margin, 1.0)))


def _runs(index: np.ndarray) -> list[tuple[int, int]]:
    """Split sorted integer indices into runs of consecutive values: [(first, last), ...]."""
    # Plain slicing and lists: this runs a few times per frame, where np.diff/np.concatenate's
    # call overhead would cost more than the work.
    gaps = np.flatnonzero(index[1:] - index[:-1] > 1)
    starts = [int(index[0])] + index[gaps + 1].tolist()
    ends = index[gaps].tolist() + [int(index[-1])]
    return list(zip(starts, ends))


def _roundness(m00: np.ndarray, mu20: np.ndarray, mu02: np.ndarray, mu11: np.ndarray) -> np.ndarray:
    """sqrt(lambda_min / lambda_max) of the weighted covariance plus the pixel footprint."""
    a = mu20 / m00 + PIXEL_VARIANCE_PX2
    c = mu02 / m00 + PIXEL_VARIANCE_PX2
    b = mu11 / m00
    half_gap = np.sqrt(((a - c) / 2.0) ** 2 + b**2)
    mean = (a + c) / 2.0
    return np.sqrt(np.maximum(mean - half_gap, 0.0) / (mean + half_gap))


def _measure_roi(weight: np.ndarray, x0: int, y0: int, config: DetectConfig) -> list[tuple]:
    """Label one region of interest and measure each connected blob in it.

    Args:
        weight: (h, w) background-subtracted weights ``max(I - threshold, 0)`` of the region.
        x0, y0: the region's top-left pixel in the image.

    Returns:
        rows ``(u, v, area, roundness, flux, x_first, y_first, x_last, y_last)`` in image pixels.
    """
    # connectedComponents takes any non-zero 8-bit pixel for foreground, so 8-bit weights need
    # no mask of their own.
    mask = weight if weight.dtype == np.uint8 else (weight > 0).view(np.uint8)
    count, labels = cv2.connectedComponents(mask, connectivity=config.connectivity)
    out = []
    if count == 2:
        # The common case, a region holding one blob: OpenCV's moments of the weights are exact
        # and cost a few microseconds, and no per-label statistics are needed.
        area = cv2.countNonZero(weight)
        if not config.min_area_px <= area <= config.max_area_px:
            return out
        m = cv2.moments(weight)
        if m["m00"] <= 0:
            return out
        m00 = m["m00"]
        a, c, b = m["mu20"] / m00 + PIXEL_VARIANCE_PX2, m["mu02"] / m00 + PIXEL_VARIANCE_PX2, m["mu11"] / m00
        half_gap, mean = math.hypot((a - c) / 2.0, b), (a + c) / 2.0  # the eigenvalues, as _roundness
        r = math.sqrt(max(mean - half_gap, 0.0) / (mean + half_gap))
        h, w = weight.shape
        out.append((x0 + m["m10"] / m00, y0 + m["m01"] / m00, area, r, m00, x0, y0, x0 + w - 1, y0 + h - 1))
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
    r = _roundness(m00, m20 - ul * m10, m02 - vl * m01, m11 - ul * m01)
    left = stats[keep, cv2.CC_STAT_LEFT]
    top = stats[keep, cv2.CC_STAT_TOP]
    right = left + stats[keep, cv2.CC_STAT_WIDTH] - 1
    bottom = top + stats[keep, cv2.CC_STAT_HEIGHT] - 1
    for i in range(len(keep)):
        out.append(
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
        )
    return out


def detect_blobs(image: np.ndarray, config: DetectConfig | None = None) -> Blobs:
    """Find bright blobs in one grayscale image and measure their sub-pixel centroids.

    Args:
        image: (H, W) uint8 or uint16 grey levels, bright markers on a dark background.
        config: thresholds and blob filters; ``None`` uses :class:`DetectConfig` defaults.

    Returns:
        :class:`Blobs`: centroids ``uv`` (K, 2) in pixels (pixel centres at integers), pixel
        counts, roundness and flux of the blobs that pass the area, roundness and border filters.

    Raises:
        CalibrationError: the image is not a 2-D uint8/uint16 array.
    """
    config = DEFAULT_CONFIG if config is None else config
    image = _check_image(image)
    height, width = image.shape
    row_max = image.max(axis=1)
    peak = float(row_max.max())
    threshold = auto_threshold(image, peak, config) if config.threshold is None else float(config.threshold)
    level = int(threshold)
    if peak <= level:
        return Blobs.empty(threshold)
    level_value = image.dtype.type(level)  # < peak here, so it fits the image's dtype
    rows = np.flatnonzero(row_max > level)
    found = []
    for r0, r1 in _runs(rows):
        band = image[r0 : r1 + 1]
        cols = np.flatnonzero(band.max(axis=0) > level)
        for c0, c1 in _runs(cols):
            # Weights max(I - level, 0). Not cv2.subtract(roi, level): OpenCV's Python binding
            # takes a (4, 1) array for a scalar and then refuses the call.
            roi = band[:, c0 : c1 + 1]
            weight = np.maximum(roi, level_value) - level_value
            found.extend(_measure_roi(weight, c0, r0, config))
    if not found:
        return Blobs.empty(threshold)
    table = np.array(found, dtype=np.float64)
    uv, area, flux = table[:, :2], table[:, 2], table[:, 4]
    keep = table[:, 3] >= config.min_roundness
    if config.reject_border:
        keep &= (table[:, 5] > 0) & (table[:, 6] > 0) & (table[:, 7] < width - 1) & (table[:, 8] < height - 1)
    order = np.lexsort((uv[keep, 0], uv[keep, 1]))
    idx = np.flatnonzero(keep)[order]
    return Blobs(uv[idx], area[idx].astype(np.int64), table[idx, 3], flux[idx], threshold)


@functools.lru_cache(maxsize=None)
def _thread_pool(workers: int) -> ThreadPoolExecutor:
    """One long-lived pool per worker count: starting threads for every frame set would cost
    a third of a frame's detection time (~0.12 ms per call measured)."""
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix="calib-detect")


def detect_many(
    images: Sequence[np.ndarray], config: DetectConfig | None = None, workers: int | None = None
) -> list[Blobs]:
    """:func:`detect_blobs` over many images (e.g. one frame set of several cameras), in order.

    The images are split into ``workers`` contiguous chunks, each detected by one thread of a
    long-lived pool. OpenCV and NumPy release the GIL inside their calls; how much that buys over
    one thread depends on how much of the time is Python between those calls (measured in
    ``bench/bench_detect.py``, discussed in docs/decisions/0003-blob-detector.md). Decoding
    usually costs far more than detecting (a 1280x1024 PNG: ~6 ms against ~0.3 ms), so a caller
    that reads image files should decode in its worker threads too, not before calling this
    (docs/decisions/0006-parallel-detection.md).

    Args:
        images: sequence of (H, W) uint8/uint16 arrays; sizes may differ.
        config: as for :func:`detect_blobs`.
        workers: threads; ``None`` uses every core, 1 runs in the calling thread.

    Returns:
        one :class:`Blobs` per image, in the order given.
    """
    images = list(images)
    for i, image in enumerate(images):
        _check_image(image, f"image {i}")
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers < 1:
        raise CalibrationError(f"detect_many: workers must be >= 1 or None, got {workers}")
    workers = min(workers, len(images))
    if workers <= 1:
        return [detect_blobs(image, config) for image in images]
    bounds = np.linspace(0, len(images), workers + 1).astype(int)
    chunks = [images[lo:hi] for lo, hi in zip(bounds[:-1], bounds[1:])]
    results = _thread_pool(workers).map(lambda chunk: [detect_blobs(image, config) for image in chunk], chunks)
    return [blobs for chunk in results for blobs in chunk]


# Half-width of the window rendered around each spot, in sigmas: beyond 6 sigma a Gaussian holds
# less than 1e-9 of its volume, far below one grey level even for a saturated 16-bit spot.
RENDER_HALF_WIDTH_SIGMAS = 6.0


def render_blobs(
    shape: tuple[int, int],
    uv: np.ndarray,
    sigma_px: float | np.ndarray = 1.2,
    peak: float | np.ndarray = 200.0,
    background: float = 10.0,
    noise: float = 0.0,
    bit_depth: int = 8,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Render Gaussian marker spots as a camera would record them (a pure function).

    Each spot is a 2-D Gaussian of standard deviation ``sigma_px`` centred at ``uv``, integrated
    over each pixel's unit square with erf differences, so the true centre of the rendered light
    is exactly ``uv`` (pixel centres at integer coordinates). Then Gaussian read noise is added
    and the values are rounded and clipped to the bit depth, as an ADC would.

    Args:
        shape: (H, W) image size in pixels.
        uv: (K, 2) spot centres in pixels (x right, y down).
        sigma_px: scalar or (K,) Gaussian standard deviation, pixels.
        peak: scalar or (K,) peak of the continuous Gaussian above the background, grey levels
            (a pixel centred on the spot gets slightly less, as it averages over its area).
        background: grey level of the dark background.
        noise: standard deviation of the additive read noise, grey levels; needs ``rng`` if > 0.
        bit_depth: 8 gives uint8; 10, 12, 14 or 16 give uint16 clipped at ``2**bit_depth - 1``.
        rng: NumPy generator for the noise.

    Returns:
        (H, W) uint8 or uint16 image.
    """
    height, width = (int(shape[0]), int(shape[1]))
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    k = len(uv)
    sigma = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (k,))
    amp = np.broadcast_to(np.asarray(peak, dtype=np.float64), (k,))
    if bit_depth not in (8, 10, 12, 14, 16):
        raise CalibrationError(f"render_blobs: bit_depth must be 8, 10, 12, 14 or 16, got {bit_depth}")
    if np.any(sigma <= 0):
        raise CalibrationError("render_blobs: sigma_px must be positive")
    if noise > 0 and rng is None:
        raise CalibrationError("render_blobs: pass rng (a numpy Generator) to add noise")
    light = np.full((height, width), float(background))
    for (u, v), s, a in zip(uv, sigma, amp):
        half = RENDER_HALF_WIDTH_SIGMAS * s + 1.0
        x0, x1 = max(int(np.floor(u - half)), 0), min(int(np.ceil(u + half)) + 1, width)
        y0, y1 = max(int(np.floor(v - half)), 0), min(int(np.ceil(v + half)) + 1, height)
        if x0 >= x1 or y0 >= y1:
            continue
        # Fraction of a 1-D unit Gaussian falling in [x - 0.5, x + 0.5], per pixel column / row.
        scale = 1.0 / (np.sqrt(2.0) * s)
        ex = erf((np.arange(x0, x1 + 1) - 0.5 - u) * scale)
        ey = erf((np.arange(y0, y1 + 1) - 0.5 - v) * scale)
        px = 0.5 * np.diff(ex)
        py = 0.5 * np.diff(ey)
        # The continuous Gaussian a*exp(-r^2/2s^2) holds volume a*2*pi*s^2; the pixel gets its share.
        light[y0:y1, x0:x1] += (a * 2.0 * np.pi * s * s) * np.outer(py, px)
    if noise > 0:
        light += rng.normal(0.0, noise, light.shape)
    full_scale = 2**bit_depth - 1
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.clip(np.rint(light), 0, full_scale).astype(dtype)


# Blobs of one marker in different frames of a still object scatter by the centroid noise
# (~0.01-0.1 px); 2 px is far above that and below the spacing of two distinct markers, which
# would merge into one blob before they came within a marker diameter (> 2 px) of each other.
STILL_RADIUS_PX = 2.0

# A still marker must be seen in this fraction of a static recording; the person placing the
# L-frame or a passing occlusion may hide a marker in a few frames.
STATIC_MIN_PRESENCE = 0.8

# During wanding, a blob position occupied in this fraction of the frames is a still marker (the
# L-frame left on the floor, a lamp). The moving wand never stays this long at one spot unless it
# is held still for half the recording; the waver's body hiding the L-frame costs some presence.
WAND_STILL_PRESENCE = 0.5

# Too few frames give no basis for telling still blobs from a wand that rests for a moment.
WAND_STILL_MIN_FRAMES = 20

WAND_MARKERS = 2


def _frame_uv(item, index: int) -> np.ndarray:
    uv = item.uv if isinstance(item, Blobs) else np.asarray(item, dtype=np.float64)
    if uv.size == 0:
        return np.zeros((0, 2))
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise CalibrationError(
            f"frame {index}: expected Blobs or a (K, 2) array of blob centroids, got shape {uv.shape}"
        )
    return uv


def _cluster_positions(frames: list[np.ndarray], radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Cluster blob positions across frames.

    Each blob joins the nearest cluster whose running mean is within ``radius_px``; a blob
    farther from every cluster opens a new one. A frame adds at most one blob per cluster.

    Returns:
        centres (C, 2) mean positions, and frames (C,) int how many frames each cluster was seen in.
    """
    sums = np.zeros((0, 2))
    counts = np.zeros(0, dtype=np.int64)
    for uv in frames:
        if len(uv) == 0:
            continue
        taken = np.zeros(len(counts), dtype=bool)
        new = []
        centres = sums / np.maximum(counts, 1)[:, None]
        for p in uv:
            if len(centres):
                d = np.hypot(*(centres - p).T)
                d[taken] = np.inf
                j = int(np.argmin(d))
                if d[j] <= radius_px:
                    sums[j] += p
                    counts[j] += 1
                    taken[j] = True
                    continue
            new.append(p)
        if new:
            sums = np.vstack((sums, new))
            counts = np.concatenate((counts, np.ones(len(new), dtype=np.int64)))
    return sums / np.maximum(counts, 1)[:, None], counts


def static_markers_from_frames(
    blobs_by_frame: Sequence[Blobs | np.ndarray],
    radius_px: float = STILL_RADIUS_PX,
    min_presence: float = STATIC_MIN_PRESENCE,
) -> np.ndarray:
    """The still markers of a short recording of the static object alone, averaged over time.

    Blobs are clustered across frames (within ``radius_px`` of a cluster's mean); clusters seen
    in at least ``min_presence`` of the frames are markers and their mean position is returned.
    Averaging N frames shrinks the centroid noise by sqrt(N).

    Args:
        blobs_by_frame: one camera's frames, each a :class:`Blobs` or a (K, 2) array of uv.
        radius_px: largest distance of one marker's blob from its mean, pixels.
        min_presence: fraction of frames a marker must appear in, (0, 1].

    Returns:
        (M, 2) float64 marker positions in pixels, sorted by row then column.
    """
    if not 0.0 < min_presence <= 1.0:
        raise CalibrationError(f"min_presence must lie in (0, 1], got {min_presence!r}")
    if radius_px <= 0:
        raise CalibrationError(f"radius_px must be positive, got {radius_px!r}")
    frames = [_frame_uv(item, i) for i, item in enumerate(blobs_by_frame)]
    if not frames:
        return np.zeros((0, 2))
    centres, counts = _cluster_positions(frames, radius_px)
    markers = centres[counts >= min_presence * len(frames)]
    return markers[np.lexsort((markers[:, 0], markers[:, 1]))] if len(markers) else np.zeros((0, 2))


@dataclass(frozen=True, eq=False)
class WandFrames:
    """The frames of one camera that show the wand's two markers, and why the others were dropped.

    Args:
        frame: (N,) int64 indices (into the input sequence) of the kept frames.
        uv: (N, 2, 2) float64 the two wand blobs of each kept frame, pixels (order within a frame
            is the detector's: by row, then column).
        too_few: frames dropped with 0 or 1 wand blob (wand out of view or occluded).
        too_many: frames dropped with more than 2 blobs left (reflections, another marker).
        still_uv: (M, 2) still-marker positions whose blobs were removed first.
        still_removed: total blobs removed as still markers, over all frames.
        total: number of input frames.
    """

    frame: np.ndarray
    uv: np.ndarray
    too_few: int
    too_many: int
    still_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    still_removed: int = 0
    total: int = 0

    def __len__(self) -> int:
        return len(self.frame)

    def summary(self) -> str:
        """One sentence for a report."""
        text = (
            f"kept {len(self)} of {self.total} frames with exactly {WAND_MARKERS} wand blobs; "
            f"dropped {self.too_few} with 0 or 1 blob and {self.too_many} with more than {WAND_MARKERS}"
        )
        if len(self.still_uv):
            text += f"; ignored {len(self.still_uv)} still marker(s) ({self.still_removed} blobs)"
        return text


def wand_frames(
    blobs_by_frame: Sequence[Blobs | np.ndarray],
    static_uv: np.ndarray | None = None,
    *,
    radius_px: float = STILL_RADIUS_PX,
    auto_still: bool = True,
) -> WandFrames:
    """Keep the frames of one camera that show exactly the two wand markers.

    Blobs within ``radius_px`` of a still marker are removed first, so an L-frame left in view
    while wanding is not taken for the wand. The still markers are ``static_uv`` when given;
    otherwise (``auto_still``) they are found in the recording itself as blob positions occupied
    in at least half the frames, which the moving wand never is.

    Args:
        blobs_by_frame: one camera's frames in time order, each a :class:`Blobs` or (K, 2) uv.
        static_uv: (M, 2) still-marker positions in pixels (e.g. from
            :func:`static_markers_from_frames`), or None.
        radius_px: a blob this close to a still marker is that marker, pixels.
        auto_still: with ``static_uv=None``, look for still markers in the recording (needs at
            least 20 frames); pass an empty (0, 2) array to remove nothing.

    Returns:
        :class:`WandFrames` with the kept frames' (2, 2) uv and counts of dropped frames by reason.
    """
    frames = [_frame_uv(item, i) for i, item in enumerate(blobs_by_frame)]
    if static_uv is None:
        if auto_still and len(frames) >= WAND_STILL_MIN_FRAMES:
            static_uv = static_markers_from_frames(frames, radius_px, WAND_STILL_PRESENCE)
        else:
            static_uv = np.zeros((0, 2))
    still = np.asarray(static_uv, dtype=np.float64).reshape(-1, 2)
    kept, kept_uv = [], []
    too_few = too_many = removed = 0
    for i, uv in enumerate(frames):
        if len(still) and len(uv):
            near = (np.hypot(*(uv[:, None, :] - still[None, :, :]).transpose(2, 0, 1)) <= radius_px).any(axis=1)
            removed += int(near.sum())
            uv = uv[~near]
        if len(uv) < WAND_MARKERS:
            too_few += 1
        elif len(uv) > WAND_MARKERS:
            too_many += 1
        else:
            kept.append(i)
            kept_uv.append(uv)
    return WandFrames(
        frame=np.asarray(kept, dtype=np.int64),
        uv=np.asarray(kept_uv, dtype=np.float64).reshape(-1, WAND_MARKERS, 2),
        too_few=too_few,
        too_many=too_many,
        still_uv=still,
        still_removed=removed,
        total=len(frames),
    )
