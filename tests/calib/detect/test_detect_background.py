"""Background models, masks, hysteresis seeds and centroid weights of the blob detector, on
rendered frames with glare, clutter and reflections whose truth is known."""

from __future__ import annotations

import numpy as np
import pytest

from tests.calib.detect.test_detect import _random_spots
from wandcal.calib.detect import CameraDetector, DetectConfig, detect_blobs, visible_mask
from wandcal.calib.detect.background import NOISE_SAMPLE_STEP, highpass, median_background, pixel_noise, sample_stats
from wandcal.calib.detect.config import CLUTTER_MIN_ROUNDNESS, MARKER_MIN_ROUNDNESS
from wandcal.calib.detect.masks import block_visible
from wandcal.calib.errors import CalibrationError
from wandcal.calib.sim.render import render_blobs

CENTROID_RMS_PX = 0.05  # the accuracy requirement for rendered blobs (as test_detect.py)
SHAPE = (240, 320)
NOISE = 2.0  # read noise, grey levels


def _spots(rng, n):
    return _random_spots(rng, n, SHAPE, margin=25.0, spacing=30.0)


def _glow(rng, amplitude=60.0):
    """A smooth glowing background: a wide bright patch and a gradient, as glare off a wall."""
    yy, xx = np.mgrid[: SHAPE[0], : SHAPE[1]]
    c = rng.uniform([0, 0], [SHAPE[1], SHAPE[0]])
    return amplitude * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * 70.0**2)) + 25.0 * xx / SHAPE[1]


def _frame(rng, uv, extra=None, sigma=1.5, peak=150.0):
    image = render_blobs(SHAPE, uv, sigma, peak, 10.0, NOISE, 8, rng).astype(float)
    if extra is not None:
        image += extra
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def _errors(found, truth):
    if len(found) == 0:
        return np.full(len(truth), np.inf)
    return np.min(np.linalg.norm(truth[:, None] - found[None], axis=2), axis=1)


def test_highpass_is_openptvs_floor_of_the_box_mean():
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (60, 90), dtype=np.uint8)
    half = 4
    n = 2 * half + 1
    padded = np.pad(image.astype(np.int64), half, mode="edge")
    box = sum(padded[dy : dy + 60, dx : dx + 90] for dy in range(n) for dx in range(n))
    expect = np.clip(image - box // (n * n), 0, 255)
    np.testing.assert_array_equal(highpass(image, half), expect)
    deep = (image.astype(np.uint16) * 257)  # 16 bits: float32 sums may move the mean by a level
    padded = np.pad(deep.astype(np.int64), half, mode="edge")
    box = sum(padded[dy : dy + 60, dx : dx + 90] for dy in range(n) for dx in range(n))
    got = highpass(deep, half).astype(np.int64)
    assert highpass(deep, half).dtype == np.uint16
    assert np.max(np.abs(got - np.clip(deep - box // (n * n), 0, None))) <= 1


def test_auto_background_finds_markers_on_a_glowing_background():
    rng = np.random.default_rng(2)
    errors, plain_found = [], 0
    for _ in range(6):
        uv = _spots(rng, 8)
        image = _frame(rng, uv, _glow(rng))
        median, upper = sample_stats(image)
        assert upper - median > 3 * pixel_noise(image)  # the glow is what "auto" must notice
        blobs = detect_blobs(image)
        assert blobs.background == "highpass" and len(blobs) == len(uv)
        errors.append(_errors(blobs.uv, uv))
        plain_found += int(np.sum(_errors(detect_blobs(image, DetectConfig(background="none")).uv, uv) < 1.0))
    assert np.sqrt(np.mean(np.concatenate(errors) ** 2)) <= CENTROID_RMS_PX
    # Without a background model one threshold cannot serve the glow and the dark part alike.
    assert plain_found < 0.5 * 6 * 8


def test_auto_background_leaves_a_flat_frame_alone():
    rng = np.random.default_rng(3)
    image = _frame(rng, _spots(rng, 6))
    auto, plain = detect_blobs(image), detect_blobs(image, DetectConfig(background="none"))
    assert auto.background == "none"
    np.testing.assert_array_equal(auto.uv, plain.uv)
    assert auto.threshold == plain.threshold


def test_empty_volume_background_removes_static_clutter():
    rng = np.random.default_rng(4)
    clutter = _glow(rng) + render_blobs(SHAPE, [[160.0, 120.0], [60.5, 200.2]], 1.6, 120.0, 0.0, bit_depth=8)
    empty = [_frame(rng, np.zeros((0, 2)), clutter) for _ in range(9)]
    background = median_background(empty)
    detector = CameraDetector(DetectConfig(background="empty"), background=background, camera="cam1")
    errors = []
    for _ in range(5):
        uv = _spots(rng, 6)
        uv = uv[np.min(np.linalg.norm(uv[:, None] - [[160.0, 120.0], [60.5, 200.2]], axis=2), axis=1) > 12]
        blobs = detector.detect(_frame(rng, uv, clutter))
        assert blobs.background == "empty" and len(blobs) == len(uv)  # the clutter spots are gone
        errors.append(_errors(blobs.uv, uv))
    assert np.sqrt(np.mean(np.concatenate(errors) ** 2)) <= CENTROID_RMS_PX
    with pytest.raises(CalibrationError, match="camera cam2: background 'empty' needs a recording"):
        CameraDetector(DetectConfig(background="empty"), camera="cam2")
    with pytest.raises(CalibrationError, match="only used with background 'empty'"):
        CameraDetector(DetectConfig(), background=background)
    with pytest.raises(CalibrationError, match="the background is 320x240 but the frame is 100x50"):
        detector.detect(np.zeros((50, 100), np.uint8))
    with pytest.raises(CalibrationError, match="background 'empty' needs the camera's own background"):
        detect_blobs(empty[0], DetectConfig(background="empty"))


def test_running_background_keeps_still_markers_and_follows_the_light():
    rng = np.random.default_rng(5)
    still = np.array([[60.0, 60.0], [260.3, 180.6]])
    detector = CameraDetector(DetectConfig(background="running", running_frames=20), camera="cam1")
    glow = _glow(rng, 40.0)
    errors = []
    for i in range(80):
        wand = np.array([[100.0 + 1.5 * i, 100.0], [100.0 + 1.5 * i, 140.0]])
        light = glow * (1.0 + i / 80.0)  # the ambient light doubles during the recording
        blobs = detector.detect(_frame(rng, np.vstack((still, wand)), light))
        assert len(blobs) == 4, i  # still markers never fade, and the changing light makes no blobs
        if i >= 40:  # after two time constants the estimate is the per-pixel background
            errors.append(_errors(blobs.uv, np.vstack((still, wand))))
    assert detector.running.count == 80
    assert np.sqrt(np.mean(np.concatenate(errors) ** 2)) <= CENTROID_RMS_PX


def test_mask_blocks_pixels_and_drops_the_blobs_it_cuts():
    rng = np.random.default_rng(6)
    uv = np.array([[80.0, 60.0], [200.0, 60.0], [240.0, 180.0]])
    image = _frame(rng, uv)
    image[150:170, 40:60] = 250  # a lamp
    mask = np.ones(SHAPE, bool)
    mask[145:175, 35:65] = False  # over the lamp
    mask[55:65, 201:230] = False  # over the right half of the second marker: it is cut
    blobs = detect_blobs(image, DetectConfig(), mask=mask)
    np.testing.assert_allclose(blobs.uv[np.lexsort(blobs.uv.T)], uv[[0, 2]][np.lexsort(uv[[0, 2]].T)], atol=0.05)
    kept = detect_blobs(image, DetectConfig(reject_border=False), mask=mask)
    assert len(kept) == 3  # the cut marker is there when cut blobs are kept, biased to the left
    cut = kept.uv[np.argmin(np.linalg.norm(kept.uv - uv[1], axis=1))]
    assert cut[0] < uv[1][0] - 0.2
    with pytest.raises(CalibrationError, match="blocks every pixel"):
        detect_blobs(image, mask=np.zeros(SHAPE, bool))
    with pytest.raises(CalibrationError, match="differs from the camera's 320x240"):
        detect_blobs(image, mask=np.ones((10, 10), bool))


def test_block_visible_masks_what_is_bright_in_the_empty_volume():
    rng = np.random.default_rng(7)
    reflection = np.array([[150.0, 100.0]])
    empty = [_frame(rng, reflection) for _ in range(8)]
    empty[3] = _frame(rng, np.vstack((reflection, [[40.0, 40.0]])))  # someone's hand, in one frame only
    used = visible_mask(empty, CameraDetector(camera="cam1"))
    assert not used[100, 150] and not used[100, 153]  # the reflection and its margin are blocked
    assert used[40, 40]  # present in one frame of eight, under the presence of a quarter
    assert 0.99 < used.mean() < 1.0
    blobs = CameraDetector(mask=used).detect(_frame(rng, np.vstack((reflection, [[250.0, 200.0]]))))
    np.testing.assert_allclose(blobs.uv, [[250.0, 200.0]], atol=0.05)
    with pytest.raises(CalibrationError, match="no frames"):
        block_visible([])
    with pytest.raises(CalibrationError, match="every pixel is bright"):
        block_visible([np.ones((4, 4), bool)])


def test_seed_ratio_drops_faint_pieces_that_only_touch_at_a_corner():
    image = np.zeros((20, 20), np.uint8)
    image[5:8, 5:8] = [[40, 60, 40], [60, 100, 60], [40, 60, 40]]  # a bright spot
    image[8:10, 8:10] = 14  # a faint piece touching its corner
    alone = detect_blobs(image[:8, :8].copy(), DetectConfig(threshold=9, min_area_px=1, reject_border=False))
    joined = detect_blobs(image, DetectConfig(threshold=9, min_area_px=1, min_roundness=0))
    seeded = detect_blobs(image, DetectConfig(threshold=9, min_area_px=1, min_roundness=0, seed_ratio=2))
    assert joined.area.tolist() == [13]  # 8-connected: the faint piece pulls the centroid
    assert seeded.area.tolist() == [9]  # its peak 14 is below 2 x 9: dropped
    np.testing.assert_allclose(seeded.uv, alone.uv, atol=1e-12)
    image[8:10, 8:10] = 30  # now it reaches 2 x 9 and stays, joined at the corner
    assert detect_blobs(image, DetectConfig(threshold=9, min_area_px=1, min_roundness=0, seed_ratio=2)).area.tolist() == [13]


def test_signal_weights_are_the_grey_levels_themselves():
    image = np.zeros((20, 20), np.uint8)
    image[7:10, 3:6] = 50
    image[8, 5] = 100
    blobs = detect_blobs(image, DetectConfig(threshold=10, weights="signal", background="none"))
    ys, xs = np.nonzero(image)
    w = image[ys, xs].astype(float)
    np.testing.assert_allclose(blobs.uv, [[(w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()]], atol=1e-12)
    assert blobs.flux.tolist() == [w.sum()]


def _relative_se_of_pair_median(pairs: int) -> float:
    """Relative standard error of a noise sigma from the median of ``pairs`` absolute differences
    of Gaussian pixel pairs: 1 / (2 f(m) sqrt(n)) at the median m of |N(0, 2 sigma^2)|."""
    return 1.166 / np.sqrt(pairs)


@pytest.mark.parametrize("sigma", [1.3, 2.0, 3.0])
def test_pixel_noise_reads_between_whole_grey_levels(sigma):
    # Neighbour differences of an 8-bit frame are whole grey levels; their plain median is 1 or 2
    # (1.05 or 2.10 after scaling) for any noise between about 0.8 and 2.2. The grouped median
    # places it inside its bin: the estimate follows the noise of the rounded pixels.
    rng = np.random.default_rng(int(10 * sigma))
    image = render_blobs((1024, 1280), np.zeros((0, 2)), background=40.0, noise=sigma, bit_depth=8, rng=rng)
    rounded = np.sqrt(sigma**2 + 1.0 / 12.0)  # rounding adds a uniform error of variance 1/12
    pairs = len(range(0, 1024, NOISE_SAMPLE_STEP)) * len(range(0, 1279, NOISE_SAMPLE_STEP))
    assert abs(pixel_noise(image, NOISE_SAMPLE_STEP) / rounded - 1.0) <= 3 * _relative_se_of_pair_median(pairs)


def test_highpass_threshold_follows_the_pixel_noise_not_the_clutter():
    # A cluttered real scene: glare, and a haze of wide, faint out-of-focus particles whose light
    # fills the pixel sample's upper percentiles. The sample's spread is then not the noise; the
    # neighbour differences nearly are, as the haze changes little from one pixel to the next
    # (docs/decisions/0012: OpenPTV's cavity gave 18-24 grey the old way, 8-10 this way).
    rng = np.random.default_rng(8)
    shape, sigma = (1024, 1280), 1.3
    markers = _random_spots(rng, 12, shape, margin=40.0, spacing=60.0)
    haze = rng.uniform([0, 0], [shape[1], shape[0]], (2000, 2))
    light = render_blobs(shape, haze, rng.uniform(7.0, 10.0, len(haze)), rng.uniform(5.0, 14.0, len(haze)), 0.0)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    light = light + 60.0 * np.exp(-((xx - 400.0) ** 2 + (yy - 300.0) ** 2) / (2 * 250.0**2))
    image = render_blobs(shape, markers, 1.5, 150.0, 20.0, sigma, 8, rng).astype(float) + light
    image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    blobs = detect_blobs(image)
    assert blobs.background == "highpass"
    median, upper = sample_stats(highpass(image, DetectConfig().highpass_px))
    assert upper - median >= 2 * sigma  # the haze fills the sample: the old rule's 6 "sigmas" are >= 12 sigma
    # The noise the neighbour differences see: the pixels' own (with rounding) and, at most, half the
    # mean square step of the noise-free light between neighbours; within 3 standard errors.
    pairs = len(range(0, shape[0], NOISE_SAMPLE_STEP)) * len(range(0, shape[1] - 1, NOISE_SAMPLE_STEP))
    tolerance = 3 * _relative_se_of_pair_median(pairs)
    low = np.sqrt(sigma**2 + 1.0 / 12.0)
    high = np.sqrt(low**2 + np.mean(np.diff(light, axis=1) ** 2) / 2.0)
    assert np.floor(median + 6 * low * (1 - tolerance)) <= blobs.threshold <= np.ceil(median + 6 * high * (1 + tolerance))
    assert blobs.threshold < median + 6 * (upper - median)
    found = _errors(blobs.uv, markers)
    assert np.all(found < 1.0) and np.sqrt(np.mean(found**2)) <= CENTROID_RMS_PX


def test_roundness_limit_is_automatic_by_background_model():
    # A particle smeared 4:1 by its motion (roundness ~0.3): on a dark frame of markers a streak
    # is clutter (0.5 drops it); after the high-pass, on a cluttered scene, it is a particle and
    # stays. A 40 px line (roundness ~0.1 or less: a cable, a glass rim) is dropped on both.
    rng = np.random.default_rng(9)
    smear = render_blobs(SHAPE, np.c_[np.linspace(100, 106, 13), np.full(13, 80.0)], 1.0, 60.0, 0.0)
    line = render_blobs(SHAPE, np.c_[np.linspace(60, 100, 41), np.full(41, 180.0)], 0.8, 60.0, 0.0)
    marker = np.array([[240.0, 120.0]])
    flat = _frame(rng, marker, smear + line)
    glowing = _frame(rng, marker, smear + line + _glow(rng))
    on_flat, on_glow = detect_blobs(flat), detect_blobs(glowing)
    assert on_flat.background == "none" and on_glow.background == "highpass"
    assert len(on_flat) == 1 and np.all(_errors(on_flat.uv, marker) < 0.1)
    assert len(on_glow) == 2 and np.all(_errors(on_glow.uv, np.vstack((marker, [[103.0, 80.0]]))) < 0.3)
    # Any given limit applies to every frame, as before.
    assert len(detect_blobs(glowing, DetectConfig(min_roundness=0.5))) == 1
    assert len(detect_blobs(flat, DetectConfig(min_roundness=0.0))) == 3
    assert DetectConfig().roundness_limit("none") == MARKER_MIN_ROUNDNESS
    assert DetectConfig().roundness_limit("highpass") == CLUTTER_MIN_ROUNDNESS
