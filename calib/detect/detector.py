"""Bright-blob detection for IR images of wand and static-object markers.

Retro-reflective or LED markers appear as small bright spots. This module finds them and
measures sub-pixel centroids, in four steps:

1. a background model (:mod:`wandcal.calib.detect.background`, ``DetectConfig.background``) leaves a residual
   image of bright spots on a dark field: the frame itself, its high-pass, or the frame minus an
   empty-volume or running background;
2. a per-camera mask (:mod:`wandcal.calib.detect.masks`) zeroes the pixels the camera should ignore;
3. a threshold, fixed or automatic, and the regions-of-interest scan of :mod:`wandcal.calib.detect.measure`
   find and measure the blobs;
4. area, roundness, image-edge and mask-edge filters keep the marker-like ones.

:func:`detect_blobs` is the stateless form (one frame); :class:`CameraDetector` holds one
camera's mask, background and running-average state. The per-frame blob lists then become wand
observations and static-object markers in :mod:`wandcal.calib.detect.wand_frames`.

Pixel convention (``docs/conventions.md``, as OpenCV): origin at the top-left, x right, y down,
pixel centres at integer coordinates, so a single lit pixel at column 3, row 7 has centroid
``(3.0, 7.0)``. OpenPTV's centroids are 0.5 px larger on both axes (its ``targ_rec`` adds 0.5).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from wandcal.calib.detect import background as bg
from wandcal.calib.detect.config import DEFAULT_CONFIG, DetectConfig
from wandcal.calib.detect.masks import MaskIndex, block_visible
from wandcal.calib.detect.measure import Blobs, find_blobs
from wandcal.calib.errors import CalibrationError

SUPPORTED_DTYPES = (np.uint8, np.uint16)  # what IR machine-vision cameras deliver (8-bit, or 10-16 bit in uint16)

STATEFUL = ("empty", "running")  # background models that need a camera's own data


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


def auto_threshold(image: np.ndarray, peak: float, config: DetectConfig = DEFAULT_CONFIG,
                   stats: tuple[float, float] | None = None, noise: float | None = None) -> float:
    """The automatic threshold of :class:`DetectConfig` for ``image``, a grey level.

    Args:
        image: (H, W) uint8 or uint16 (the residual after the background model).
        peak: the image's maximum grey level (the caller has it already).
        stats: ``wandcal.calib.detect.background.sample_stats(image)`` when the caller has it already.
        noise: for a high-passed residual, the pixel noise sigma of the frame it came from
            (:func:`wandcal.calib.detect.background.pixel_noise`), grey levels. The threshold is then the
            median plus ``auto_noise_sigmas`` of it, with no peak term: on a cluttered frame the
            sample's spread counts faint and out-of-focus particles as noise, and its peak is
            glare or a saturated particle (OpenPTV's cavity: 18-24 grey that way, 9-10 this way,
            against OpenPTV's hand-set 9-11; docs/decisions/0012).
    """
    background, upper = bg.sample_stats(image) if stats is None else stats
    if noise is not None:
        margin = config.auto_noise_sigmas * max(noise, bg.MIN_NOISE_GREY)
    else:
        sigma = upper - background
        margin = max(config.auto_noise_sigmas * sigma, config.auto_peak_fraction * (peak - background))
    # At least one grey level above the background, or a flat frame would be all "blob".
    return float(np.ceil(background + max(margin, 1.0)))


def _residual(image: np.ndarray, config: DetectConfig, background: np.ndarray | None):
    """(residual image, background model used, sample stats of the residual or None, pixel noise
    of the frame for the automatic threshold of a high-passed residual or None)."""
    model = config.background
    if model in STATEFUL:
        if background is None:
            raise CalibrationError(
                f"background {model!r} needs the camera's own background image; pass background= "
                "(wandcal.calib.detect.background.median_background of an empty-volume recording), or detect with "
                "wandcal.calib.detect.CameraDetector")
        return bg.subtract(image, background, f"{model} background"), model, None, None
    if background is not None:
        raise CalibrationError(f"background= is an image to subtract, used with background 'empty' or "
                               f"'running'; this DetectConfig says {model!r}")
    if model == "none":
        return image, "none", None, None
    if model == "auto":
        # With an automatic threshold its sample serves the flatness test too; with a fixed one a
        # coarser sample is enough.
        auto = config.threshold is None
        stats = bg.sample_stats(image, bg.SAMPLE_STEP if auto else bg.FLAT_SAMPLE_STEP)
        if bg.is_flat(image, stats):
            return image, "none", stats if auto else None, None
    # The noise of the frame, not of the residual: the high-pass clips half its pixels to zero.
    noise = bg.pixel_noise(image, bg.NOISE_SAMPLE_STEP) if config.threshold is None else None
    return bg.highpass(image, config.highpass_px), "highpass", None, noise


def _detect_residual(residual: np.ndarray, model: str, config: DetectConfig, mask: MaskIndex | None,
                     stats=None, noise: float | None = None) -> tuple[Blobs, np.ndarray]:
    """The blobs of a background-subtracted image, and their (K, 4) bounding boxes."""
    if config.threshold is None and stats is None:
        stats = bg.sample_stats(residual)  # before masking: blocked zeros would pull the median down
    if mask is not None:
        residual = mask.apply(residual)
    height, width = residual.shape
    row_max = residual.max(axis=1)
    peak = float(row_max.max())
    threshold = auto_threshold(residual, peak, config, stats, noise) if config.threshold is None \
        else float(config.threshold)
    no_boxes = np.zeros((0, 4), np.int64)
    if peak <= threshold:
        return Blobs.empty(threshold, model), no_boxes
    table = find_blobs(residual, row_max, int(threshold), config)
    if not len(table):
        return Blobs.empty(threshold, model), no_boxes
    boxes = table[:, 5:9].astype(np.int64)
    keep = table[:, 3] >= config.roundness_limit(model)
    if config.reject_border:
        keep &= (boxes[:, 0] > 0) & (boxes[:, 1] > 0) & (boxes[:, 2] < width - 1) & (boxes[:, 3] < height - 1)
        if mask is not None:
            keep &= ~mask.touches(boxes)
    uv = table[:, :2]
    idx = np.flatnonzero(keep)[np.lexsort((uv[keep, 0], uv[keep, 1]))]
    blobs = Blobs(uv[idx], table[idx, 2].astype(np.int64), table[idx, 3], table[idx, 4], threshold, model)
    return blobs, boxes[idx]


def detect_blobs(image: np.ndarray, config: DetectConfig | None = None, *,
                 background: np.ndarray | None = None, mask: np.ndarray | None = None) -> Blobs:
    """Find bright blobs in one grayscale image and measure their sub-pixel centroids.

    Args:
        image: (H, W) uint8 or uint16 grey levels, bright markers.
        config: background model, threshold and blob filters; ``None`` uses the defaults.
        background: (H, W) image to subtract, of ``image``'s dtype (or float32), for the models
            ``"empty"`` and ``"running"`` only (:class:`CameraDetector` keeps it for you).
        mask: (H, W) bool or integer image, non-zero where pixels are used (:mod:`wandcal.calib.detect.masks`).

    Returns:
        :class:`Blobs`: centroids ``uv`` (K, 2) in pixels (pixel centres at integers), pixel
        counts, roundness and flux of the blobs that pass the area, roundness and border filters.

    Raises:
        CalibrationError: the image is not a 2-D uint8/uint16 array, or a background or mask
            does not fit it.
    """
    config = DEFAULT_CONFIG if config is None else config
    image = _check_image(image)
    index = None if mask is None else MaskIndex(mask, image.shape)
    residual, model, stats, noise = _residual(image, config, background)
    return _detect_residual(residual, model, config, index, stats, noise)[0]


class CameraDetector:
    """One camera's blob detector: the settings plus the camera's mask and background.

    With ``config.background == "running"`` it keeps the running average between frames, so
    give it one camera's frames in time order from one thread. Otherwise :meth:`detect` is a pure
    function of the frame and may run in several threads.

    Args:
        config: the settings (``None``: defaults).
        mask: (H, W) bool or integer image, non-zero where pixels are used, or None.
        background: (H, W) empty-volume background (:func:`wandcal.calib.detect.background.median_background`),
            required with ``config.background == "empty"``, refused otherwise.
        camera: the camera's name, for error messages.
    """

    def __init__(self, config: DetectConfig | None = None, *, mask: np.ndarray | None = None,
                 background: np.ndarray | None = None, camera: str = "camera"):
        self.config = DEFAULT_CONFIG if config is None else config
        self.camera = camera
        model = self.config.background
        if model == "empty" and background is None:
            raise CalibrationError(f"camera {camera}: background 'empty' needs a recording of the empty volume; "
                                   "record one (docs/capture-format.md, background/) or choose another background")
        if model != "empty" and background is not None:
            raise CalibrationError(f"camera {camera}: an empty-volume background is only used with background "
                                   f"'empty', not {model!r}")
        self.background = None if background is None else _check_image(background, f"camera {camera}: background")
        self.mask = None if mask is None else MaskIndex(mask, getattr(mask, "shape", (0, 0)), f"camera {camera}: mask")
        self.running = (bg.RunningBackground(self.config.running_frames, self.config.highpass_px)
                        if model == "running" else None)

    def _fit(self, image: np.ndarray) -> np.ndarray:
        image = _check_image(image, f"camera {self.camera}")
        for name, ref in (("mask", None if self.mask is None else self.mask.used), ("background", self.background)):
            if ref is not None and ref.shape != image.shape:
                raise CalibrationError(
                    f"camera {self.camera}: the {name} is {ref.shape[1]}x{ref.shape[0]} but the frame is "
                    f"{image.shape[1]}x{image.shape[0]}; make the {name} from this camera's frames")
        return image

    def detect(self, image: np.ndarray) -> Blobs:
        """The blobs of one frame (and, for a running background, one update of it)."""
        image = self._fit(image)
        if self.running is not None:
            residual = self.running.residual(image)
            blobs, boxes = _detect_residual(residual, "running", self.config, self.mask)
            self.running.update(image, boxes)
            return blobs
        residual, model, stats, noise = _residual(image, self.config, self.background)
        return _detect_residual(residual, model, self.config, self.mask, stats, noise)[0]

    def bright(self, image: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels of ``image`` above the detection threshold, before any mask.

        The background model is the detector's, except that a running average (which would learn
        an empty volume as its background) is replaced by the high-pass it starts from.
        """
        image = self._fit(image)
        config = self.config if self.running is None else self.config.replace(background="highpass")
        residual, _, stats, noise = _residual(image, config, self.background)
        if config.threshold is not None:
            return residual > config.threshold
        return residual > auto_threshold(residual, float(residual.max()), config, stats, noise)


def visible_mask(frames: Sequence[np.ndarray], detector: CameraDetector | None = None, **options) -> np.ndarray:
    """The mask that blocks what a detector sees in a recording of the empty volume.

    Args:
        frames: (H, W) frames of one camera, the volume empty of markers.
        detector: whose background model and threshold decide what is bright (``None``: defaults).
        options: ``presence`` and ``margin_px`` of :func:`wandcal.calib.detect.masks.block_visible`.

    Returns:
        (H, W) bool, True where pixels stay used.
    """
    detector = CameraDetector() if detector is None else detector
    return block_visible([detector.bright(f) for f in frames], where=f"camera {detector.camera}: empty volume",
                         **options)


@functools.cache
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
        config: as for :func:`detect_blobs`; a per-camera background (``"empty"``,
            ``"running"``) needs a :class:`CameraDetector` per camera instead.
        workers: threads; ``None`` uses every core, 1 runs in the calling thread.

    Returns:
        one :class:`Blobs` per image, in the order given.
    """
    images = list(images)
    for i, image in enumerate(images):
        _check_image(image, f"image {i}")
    if config is not None and config.background in STATEFUL:
        raise CalibrationError(f"detect_many: background {config.background!r} is per camera; detect each "
                               "camera's frames with its own wandcal.calib.detect.CameraDetector")
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
