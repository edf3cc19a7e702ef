"""The blob detector's settings: one validated value object and the one place for their defaults.

Every caller (``wandcal detect``, live capture, the service's ``[detect]`` settings group) builds a
:class:`DetectConfig`; a bad value raises :class:`CalibrationError` naming the field and what it
accepts. The module needs NumPy only, so settings can import it without loading OpenCV.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Literal

import numpy as np

from wandcal.calib.errors import CalibrationError

# What a background model may be (calib/detect/background.py):
# - "none": the frame as it is; the threshold is a grey level of the frame.
# - "highpass": subtract each pixel's local mean (OpenPTV's high-pass), every frame on its own.
# - "auto": "highpass" on a frame whose background is not flat (glare, a glowing wall), else "none";
#   decided per frame from a sample of pixels, so a dark IR frame costs nothing extra.
# - "empty": subtract a per-pixel background taken from a recording of the empty volume.
# - "running": subtract a running average of the camera's own recent frames (a stateful detector).
BACKGROUNDS = ("auto", "none", "highpass", "empty", "running")
Background = Literal["auto", "none", "highpass", "empty", "running"]

# How a blob pixel weighs in the centroid:
# - "excess": the grey level above the threshold (docs/decisions/0003): the weight falls to zero at
#   the rim, so pixels that only just cross the threshold barely move the centroid.
# - "signal": the grey level itself (after the background model), as OpenPTV's peak_fit/targ_rec;
#   reproduces OpenPTV's centroids to the last digit, at about twice the centroid error on
#   rendered spots (docs/decisions/0012-detection-background.md).
WEIGHTS = ("excess", "signal")
Weights = Literal["excess", "signal"]

# OpenPTV's default high-pass half-width (its "dim_lp" of 12: a 25 x 25 box mean). The window must
# be wider than a marker, or the marker's own light raises its local mean: 25 px holds a marker of
# up to ~12 px across with room for its halo.
DEFAULT_HIGHPASS_PX = 12

# Running background: its time constant in frames. 100 frames is one second at the usual 100 Hz:
# slow enough that a marker passing a pixel leaves ~1 % of its light behind, fast enough to follow
# daylight drifting through a window or a lamp warming up.
DEFAULT_RUNNING_FRAMES = 100.0

# The automatic roundness limit (min_roundness=None) depends on the background model a frame got.
# - A flat or subtracted background ("none", "empty", "running"): a marker seen by an IR camera.
#   0.5 admits the 2:1 smear of a marker moving fast during the exposure and rejects streaks,
#   edges and cables, and touching markers far enough apart to look 2:1 (docs/decisions/0003).
MARKER_MIN_ROUNDNESS = 0.5
# - The high-pass (a cluttered real scene: glare, a glowing wall, particles). Half of OpenPTV's
#   isolated particles are rounder than 0.55 only, a tenth below 0.25: they are motion streaks,
#   and a limit of 0.5 loses ~45 % of them (docs/decisions/0012). 0.1 (10:1) still drops long thin
#   light, glass rims and cables; it lost 0.3 % of the isolated particles.
CLUTTER_MIN_ROUNDNESS = 0.1


@dataclass(frozen=True)
class DetectConfig:
    """Settings of :func:`wandcal.calib.detect.detect_blobs` and :class:`wandcal.calib.detect.CameraDetector`.

    Args:
        threshold: grey level (a whole number) of the background-subtracted image; pixels strictly
            brighter are blob pixels. ``None`` picks one per image: the background median plus
            ``auto_noise_sigmas`` noise standard deviations, or ``auto_peak_fraction`` of the
            (peak - background) range if that is more. The noise is the spread of a pixel sample
            of the frame, except after the high-pass: there it is the frame's pixel noise from
            neighbouring-pixel differences (:func:`wandcal.calib.detect.background.pixel_noise`), and the peak
            term is left out, because the spread and the peak of a cluttered frame measure its
            particles and glare, not its noise (docs/decisions/0012).
        seed_ratio: hysteresis. Each 4-connected piece of a blob must hold a pixel brighter than
            ``seed_ratio * threshold``, or it is dropped; with ``connectivity=8`` the seeded pieces
            that touch at a corner are then one blob. 1 (the default) turns it off. OpenPTV grows
            its targets from peaks above twice its threshold: ``seed_ratio=2`` reproduces that.
        min_area_px: smallest blob, in pixels. The default 4 rejects hot pixels and lone noise
            pixels; a marker blurred with sigma >= 0.7 px covers at least 4 pixels above a
            threshold at a quarter of its peak.
        max_area_px: largest blob, in pixels. 1500 px is a disc of ~44 px diameter, far larger
            than a marker at working distance; bigger blobs are reflections, lamps or flares.
        min_roundness: smallest ratio of minor to major axis (sqrt of the eigenvalue ratio of the
            weighted pixel covariance, plus the pixel footprint), in [0, 1]. ``None`` (the default)
            picks it per frame from the background model used: :data:`MARKER_MIN_ROUNDNESS` (0.5)
            on a flat or subtracted background, :data:`CLUTTER_MIN_ROUNDNESS` (0.1) after the
            high-pass, whose frames are cluttered scenes with streaky particles.
        reject_border: drop blobs that touch the image edge or a masked pixel; part of such a blob
            is cut off, so its centroid is biased toward the inside.
        connectivity: 8 joins pixels that touch at a corner into one blob (a blurred marker is
            8-connected); 4 joins only edge neighbours.
        weights: centroid weights, ``"excess"`` (grey level above the threshold) or ``"signal"``
            (the grey level itself, OpenPTV's); see :data:`WEIGHTS`.
        background: the background model, one of :data:`BACKGROUNDS`.
        highpass_px: half-width of the high-pass's box mean, pixels (window ``2 * highpass_px + 1``).
        running_frames: time constant of the running background, frames (> 1).
        auto_noise_sigmas: automatic threshold, noise term. At 6 sigma a Gaussian read noise
            lifts about one pixel in 10^9 above it, i.e. ~0.001 false pixels per 1.3 Mpx frame.
        auto_peak_fraction: automatic threshold, contrast term: keeps the faint halo of a bright
            frame (and quantisation steps of a noise-free one) out of the blobs. Not used after the
            high-pass, where the peak is often glare or a saturated particle.
    """

    threshold: int | None = None
    seed_ratio: float = 1.0
    min_area_px: int = 4
    max_area_px: int = 1500
    min_roundness: float | None = None
    reject_border: bool = True
    connectivity: int = 8
    weights: Weights = "excess"
    background: Background = "auto"
    highpass_px: int = DEFAULT_HIGHPASS_PX
    running_frames: float = DEFAULT_RUNNING_FRAMES
    auto_noise_sigmas: float = 6.0
    auto_peak_fraction: float = 0.05

    def __post_init__(self) -> None:
        self._check_spot_settings()
        self._check_background_settings()

    def _bad(self, name: str, accepts: str) -> CalibrationError:
        return CalibrationError(f"DetectConfig.{name} must be {accepts}, got {getattr(self, name)!r}")

    def _check_spot_settings(self) -> None:
        """Threshold, spot sizes, roundness, border and connectivity."""
        bad = self._bad
        if self.threshold is not None:
            if isinstance(self.threshold, bool) or not _real(self.threshold) or self.threshold < 0 \
                    or not float(self.threshold).is_integer():
                raise bad("threshold", "a whole grey level >= 0 or None (automatic)")
            object.__setattr__(self, "threshold", int(self.threshold))
        if not (_real(self.seed_ratio) and self.seed_ratio >= 1.0):
            raise bad("seed_ratio", "a number >= 1 (1 turns the seed test off)")
        if not (_whole(self.min_area_px) and self.min_area_px >= 1):
            raise bad("min_area_px", "a whole number >= 1")
        if not (_whole(self.max_area_px) and self.max_area_px >= self.min_area_px):
            raise bad("max_area_px", f"a whole number >= min_area_px ({self.min_area_px})")
        if self.min_roundness is not None and not (_real(self.min_roundness) and 0.0 <= self.min_roundness <= 1.0):
            raise bad("min_roundness", "a number in [0, 1] or None (automatic)")
        if not isinstance(self.reject_border, (bool, np.bool_)):
            raise bad("reject_border", "true or false")
        if self.connectivity not in (4, 8) or isinstance(self.connectivity, bool):
            raise bad("connectivity", "4 or 8")

    def _check_background_settings(self) -> None:
        """Weights, the background model and its automatic settings."""
        bad = self._bad
        if self.weights not in WEIGHTS:
            raise bad("weights", " or ".join(repr(w) for w in WEIGHTS))
        if self.background not in BACKGROUNDS:
            raise bad("background", ", ".join(repr(b) for b in BACKGROUNDS))
        if not (_whole(self.highpass_px) and self.highpass_px >= 1):
            raise bad("highpass_px", "a whole number of pixels >= 1")
        if not (_real(self.running_frames) and self.running_frames > 1.0):
            raise bad("running_frames", "a number of frames > 1")
        if not (_real(self.auto_noise_sigmas) and self.auto_noise_sigmas >= 0):
            raise bad("auto_noise_sigmas", "a number >= 0")
        if not (_real(self.auto_peak_fraction) and 0.0 <= self.auto_peak_fraction < 1.0):
            raise bad("auto_peak_fraction", "a number in [0, 1)")

    def roundness_limit(self, model: str) -> float:
        """The smallest roundness kept on a frame that got background model ``model``."""
        if self.min_roundness is not None:
            return float(self.min_roundness)
        return CLUTTER_MIN_ROUNDNESS if model == "highpass" else MARKER_MIN_ROUNDNESS

    def replace(self, **changes) -> DetectConfig:
        """A copy with ``changes`` applied (and validated)."""
        unknown = set(changes) - set(FIELDS)
        if unknown:
            raise CalibrationError(f"DetectConfig has no field(s) {', '.join(sorted(unknown))}; "
                                   f"fields: {', '.join(FIELDS)}")
        return replace(self, **changes)

    def to_dict(self) -> dict:
        """The settings as plain JSON values (for a capture log or an API answer)."""
        return asdict(self)

    def describe(self) -> str:
        """One line for a report: the settings that differ from the defaults."""
        changed = [f"{k}={v}" for k, v in self.to_dict().items() if v != getattr(DEFAULT_CONFIG, k)]
        return "default detection settings" if not changed else "detection: " + ", ".join(changed)


def _real(value) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) \
        and bool(np.isfinite(value))


def _whole(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


FIELDS = tuple(f.name for f in fields(DetectConfig))
DEFAULT_CONFIG = DetectConfig()
