"""Rendering marker spots as a camera records them: the simulated cameras' frames and the
detector's test images (a pure function, seeded by the caller).

Pixel convention (``docs/conventions.md``, as OpenCV): origin at the top-left, x right, y down,
pixel centres at integer coordinates.
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

from wandcal.calib.errors import CalibrationError

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
    if noise > 0 and rng is not None:  # checked above: noise needs rng
        light += rng.normal(0.0, noise, light.shape)
    full_scale = 2**bit_depth - 1
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.clip(np.rint(light), 0, full_scale).astype(dtype)
