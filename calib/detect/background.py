"""Background models for blob detection: what to subtract from a frame before thresholding.

Real frames are not a dark field with bright dots. Glare off glass, a lit wall or daylight raise
the background by more than a marker's contrast in places, so one grey-level threshold for the
whole frame either misses the markers on the dark part or takes the bright part for blobs
(docs/decisions/0012-detection-background.md measures this on OpenPTV's cavity images). Three
models remove it, each giving a residual image of the frame's own dtype that the detector
thresholds as before:

- :func:`highpass`: each pixel minus the mean of its ``(2h+1) x (2h+1)`` neighbourhood, rounded
  down, clipped at zero: OpenPTV's ``prepare_image`` (its ``fast_box_blur`` and ``subtract_img``).
  Needs nothing but the frame.
- :func:`median_background` + :func:`subtract`: a per-pixel background from a recording of the
  empty volume (the per-pixel median of its frames), subtracted from every frame.
- :class:`RunningBackground`: an exponential running average of the camera's own frames,
  not updated under the markers it detects, so still markers stay visible.

:func:`is_flat` measures from a sparse grid of pixels whether a frame's background is flat (its
spread is the pixel noise) or not; ``background="auto"`` uses the high-pass only when not.
:func:`pixel_noise`, from neighbouring-pixel differences, is also the noise the automatic
threshold of a high-passed frame is set from.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from wandcal.calib.errors import CalibrationError

# Subsampling step for the background statistics. Every 32nd pixel of every 32nd row gives 1,280
# samples at 1280x1024: the standard error of a percentile-based sigma from n samples is
# ~1.1/sqrt(n), 3 % here, so a 6-sigma threshold lands within 5.8-6.2 sigma. Each sample costs a
# cache miss on a frame fresh from the camera, so fewer is faster: 16 us per frame, against
# ~50-90 us for a 16-step grid (8/16-bit) and 130 us for np.percentile on an 8-step one.
SAMPLE_STEP = 32

# The flatness test (is_flat) needs only a rough spread and noise, to compare them by a factor of
# 3: every 64th pixel of every 64th row (320 samples at 1280x1024, ~7 % standard error) is
# plenty, and costs a quarter of the threshold's sample when the threshold is fixed.
FLAT_SAMPLE_STEP = 64

# One standard deviation of a normal distribution lies between its 50th and 84.13th percentiles.
# The upper one-sided spread is used because sparse bright markers barely move the 84th percentile.
ONE_SIGMA_QUANTILE = 0.84134

# sigma of a normal variable from the median of |a - b| for two independent draws a, b:
# median |N(0, 2 sigma^2)| = 0.6745 * sqrt(2) * sigma.
NOISE_FROM_PAIR_MEDIAN = 1.0 / (0.67449 * np.sqrt(2.0))

# The automatic threshold of a high-passed frame measures the pixel noise on a denser grid than the
# flatness test: every 16th pixel of every 16th row gives 5,120 neighbour pairs at 1280x1024, whose
# median pins sigma to ~2 %, i.e. a 6-sigma threshold to about +-0.1 grey level at OpenPTV's noise
# (1.3 grey). It costs ~40 us, against ~2 ms for the high-pass itself.
NOISE_SAMPLE_STEP = 16

# A background counts as flat when its spread over the frame (the sample's 50-84 % percentile
# gap) is at most this many times the pixel noise (from neighbouring-pixel differences, which a
# smooth background does not change). Read noise alone gives a ratio near 1; OpenPTV's cavity
# frames, with glare and a glowing back wall, give 14-20. 3 leaves room for vignetting.
FLAT_SPREAD_RATIO = 3.0

# The noise estimate never counts as less than one grey level: a noise-free or heavily quantised
# frame has neighbour differences of 0, and a spread of one grey level is then still flat.
MIN_NOISE_GREY = 1.0

# Running background: pixels this far around a detected blob's bounding box keep their old value
# when the average is updated, so the faint rim of a still marker does not creep into it either.
RUNNING_KEEP_MARGIN_PX = 2


def sample_stats(image: np.ndarray, step: int = SAMPLE_STEP) -> tuple[float, float]:
    """Background level and spread of ``image`` from a sparse grid of pixels.

    Args:
        image: (H, W) uint8 or uint16.
        step: the grid's spacing, pixels.

    Returns:
        ``(median, upper)``, grey levels: the sample's median and 84.13th percentile, so
        ``upper - median`` is one sigma of the background's spread over the frame.
    """
    sample = image[::step, ::step].ravel()
    median_at, upper_at = sample.size // 2, min(int(sample.size * ONE_SIGMA_QUANTILE), sample.size - 1)
    ordered = np.partition(sample, [median_at, upper_at])
    return float(ordered[median_at]), float(ordered[upper_at])


def pixel_noise(image: np.ndarray, step: int = FLAT_SAMPLE_STEP) -> float:
    """Pixel noise sigma of ``image``, grey levels, from the differences of horizontally
    neighbouring pixels on a grid of spacing ``step`` (a smooth background does not change them,
    and the few pairs on a particle's flank do not move their median).

    The differences are whole grey levels, so their plain median jumps in steps of 1.05 grey
    (OpenPTV's cavity frames gave 1.05 or 2.10 for noise near 1.3-1.6): the median of grouped data
    is used instead, placing it inside its integer bin by the share of the pairs below it.
    """
    if image.shape[1] < 2:
        return 0.0
    left = image[::step, 0 : image.shape[1] - 1 : step].ravel()
    right = image[::step, 1::step].ravel()  # the same cache lines as ``left``
    gaps = np.abs(left.astype(np.int32) - right.astype(np.int32))
    median = int(np.partition(gaps, gaps.size // 2)[gaps.size // 2])
    share = (gaps.size / 2.0 - np.count_nonzero(gaps < median)) / np.count_nonzero(gaps == median)
    # A rounded gap of m stands for a true one in [m - 0.5, m + 0.5); a gap of 0 for one in [0, 0.5).
    low, width = (median - 0.5, 1.0) if median else (0.0, 0.5)
    return (low + share * width) * NOISE_FROM_PAIR_MEDIAN


def is_flat(image: np.ndarray, stats: tuple[float, float]) -> bool:
    """Whether ``image``'s background is flat: its spread (``stats`` of :func:`sample_stats`) is at
    most :data:`FLAT_SPREAD_RATIO` times the pixel noise (:func:`pixel_noise`, at least
    :data:`MIN_NOISE_GREY`)."""
    spread = stats[1] - stats[0]
    if spread <= FLAT_SPREAD_RATIO * MIN_NOISE_GREY:
        return True  # flat whatever the noise: skip measuring it (most dark 8-bit frames)
    return spread <= FLAT_SPREAD_RATIO * max(pixel_noise(image), MIN_NOISE_GREY)


def local_mean(image: np.ndarray, half_px: int) -> np.ndarray:
    """(H, W) float32 mean of each pixel's ``(2 * half_px + 1)^2`` neighbourhood (edges replicated)."""
    n = 2 * int(half_px) + 1
    return cv2.boxFilter(image, cv2.CV_32F, (n, n), normalize=True, borderType=cv2.BORDER_REPLICATE)


def highpass(image: np.ndarray, half_px: int) -> np.ndarray:
    """``max(I - floor(box mean), 0)``: OpenPTV's high-pass, in the image's own dtype.

    Args:
        image: (H, W) uint8 or uint16.
        half_px: half-width of the box, pixels; the box is ``2 * half_px + 1`` wide.

    Returns:
        (H, W) array of ``image``'s dtype. Rounding the mean down, as OpenPTV's integer division
        does, makes the residual of an 8-bit frame identical to OpenPTV's inside the frame.
    """
    n = 2 * int(half_px) + 1
    area = n * n
    # Box sums in float32 are exact for 8-bit frames (< 2^24); floor(s / area) is then computed
    # as round((s + 0.5) / area - 0.5), which never lands on a .5 tie, by one saturating convert.
    sums = cv2.boxFilter(image, cv2.CV_32F, (n, n), normalize=False, borderType=cv2.BORDER_REPLICATE)
    if image.dtype == np.uint8:
        low = cv2.convertScaleAbs(sums, alpha=1.0 / area, beta=0.5 / area - 0.5)
    else:
        # 16-bit sums pass 2^24, so float32 rounds them by a grey level or two: a 1-level change
        # of the mean, far below 16-bit read noise (hundreds of levels).
        low = cv2.addWeighted(sums, 1.0 / area, sums, 0.0, 0.5 / area - 0.5, dtype=cv2.CV_16U)
    return cv2.subtract(image, low)


def subtract(image: np.ndarray, background: np.ndarray, where: str = "background") -> np.ndarray:
    """``max(image - background, 0)`` in the image's dtype (a saturating subtraction).

    Args:
        image: (H, W) uint8 or uint16.
        background: (H, W) of the same dtype, or float32 (a running average).
        where: names the background in an error.
    """
    if background.shape != image.shape:
        raise CalibrationError(
            f"{where}: its size {background.shape[1]}x{background.shape[0]} differs from the frame's "
            f"{image.shape[1]}x{image.shape[0]}; record the empty volume with the same camera settings"
        )
    if background.dtype == image.dtype:
        return cv2.subtract(image, background)
    if background.dtype != np.float32:
        raise CalibrationError(f"{where}: pixel type {background.dtype} differs from the frame's {image.dtype}; "
                               "record the empty volume at the same bit depth")
    return cv2.subtract(image, background, dtype=cv2.CV_8U if image.dtype == np.uint8 else cv2.CV_16U)


def median_background(frames: Sequence[np.ndarray], where: str = "empty-volume recording") -> np.ndarray:
    """Per-pixel median of an empty-volume recording: the background to :func:`subtract`.

    The median ignores anything present in fewer than half the frames (someone walking out of
    the volume, a flicker), and shrinks the read noise by ~1.25/sqrt(N) for N frames.

    Args:
        frames: N >= 1 (H, W) uint8/uint16 frames of one camera, the volume empty of markers.

    Returns:
        (H, W) array of the frames' dtype.
    """
    frames = list(frames)
    if not frames:
        raise CalibrationError(f"{where}: no frames; record a few frames of the empty volume")
    first = frames[0]
    for i, f in enumerate(frames):
        if f.shape != first.shape or f.dtype != first.dtype:
            raise CalibrationError(f"{where}: frame {i} is {f.shape[1]}x{f.shape[0]} {f.dtype}, frame 0 "
                                   f"{first.shape[1]}x{first.shape[0]} {first.dtype}; use one camera's frames")
    if len(frames) == 1:
        return first.copy()
    stack = np.stack(frames)
    # The lower median (an element of the data, of the frames' dtype) rather than a mean of two.
    return np.partition(stack, (len(frames) - 1) // 2, axis=0)[(len(frames) - 1) // 2]


class RunningBackground:
    """An exponential running average of one camera's frames, updated around its markers.

    ``residual(frame)`` subtracts the present estimate; ``update(frame, boxes)`` then moves the
    estimate toward the frame by ``1 / frames`` everywhere except within
    :data:`RUNNING_KEEP_MARGIN_PX` of the detected blobs' boxes, so markers, also still ones, never
    fade into the background. The first frame has no history: its local mean (the high-pass's) is
    the first estimate, so detection works from the first frame and the estimate converges to the
    per-pixel background within a few time constants.

    Args:
        frames: time constant, frames (> 1).
        half_px: the high-pass half-width for the first estimate, pixels.
    """

    def __init__(self, frames: float, half_px: int):
        if not frames > 1:
            raise CalibrationError(f"RunningBackground: frames must be > 1, got {frames!r}")
        self.rate = 1.0 / float(frames)
        self.half_px = int(half_px)
        self.mean: np.ndarray | None = None
        self.count = 0

    def residual(self, image: np.ndarray) -> np.ndarray:
        """``image`` minus the present estimate, in the image's dtype."""
        if self.mean is None:
            self.mean = local_mean(image, self.half_px)
        return subtract(image, self.mean, "running background")

    def update(self, image: np.ndarray, boxes: np.ndarray) -> None:
        """Fold ``image`` into the estimate outside ``boxes``.

        Args:
            image: the frame just detected, (H, W).
            boxes: (K, 4) int ``x_first, y_first, x_last, y_last`` of the blobs found in it.
        """
        if self.mean is None:
            self.mean = local_mean(image, self.half_px)
        height, width = image.shape
        m = RUNNING_KEEP_MARGIN_PX
        kept = []
        for x0, y0, x1, y1 in np.asarray(boxes, dtype=np.int64).reshape(-1, 4):
            ys = slice(max(y0 - m, 0), min(y1 + m + 1, height))
            xs = slice(max(x0 - m, 0), min(x1 + m + 1, width))
            kept.append((ys, xs, self.mean[ys, xs].copy()))
        cv2.accumulateWeighted(image, self.mean, self.rate)
        for ys, xs, patch in kept:
            self.mean[ys, xs] = patch
        self.count += 1
