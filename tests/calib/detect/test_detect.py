"""Blob detection: accuracy on rendered spots, rejection filters and wand/static frame logic.

Background models, masks and the seed and weight options: test_detect_background.py; real images
against OpenPTV's detections: tests/capture/test_openptv_real.py."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.detect import Blobs, DetectConfig, detect_blobs, detect_many, static_markers_from_frames, wand_frames
from wandcal.calib.errors import CalibrationError
from wandcal.calib.sim.render import render_blobs

# The accuracy requirement for centroids of rendered blobs, px RMS.
CENTROID_RMS_PX = 0.05


def _match(found: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N,) distance from each true position to the nearest found one."""
    if len(found) == 0:
        return np.full(len(truth), np.inf)
    return np.min(np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2), axis=1)


def _random_spots(rng, n, shape, margin=20.0, spacing=15.0):
    """n spot centres inside ``shape`` (H, W), at least ``spacing`` px apart."""
    uv = []
    while len(uv) < n:
        p = rng.uniform([margin, margin], [shape[1] - margin, shape[0] - margin])
        if all(np.hypot(*(p - q)) >= spacing for q in uv):
            uv.append(p)
    return np.array(uv)


def test_render_blobs_puts_the_light_centre_exactly_at_uv():
    # 16-bit and a large peak so integer rounding is negligible; no noise, zero background.
    uv = np.array([[30.3, 20.71], [61.5, 44.0], [12.02, 50.49]])
    image = render_blobs((64, 80), uv, sigma_px=1.3, peak=30000.0, background=0.0, bit_depth=16)
    assert image.dtype == np.uint16 and image.shape == (64, 80)
    for u, v in uv:
        ys, xs = np.mgrid[int(v) - 9 : int(v) + 10, int(u) - 9 : int(u) + 10]
        w = image[ys, xs].astype(float)
        # Rounding each pixel to an integer moves the centroid by at most ~0.5 * 19^2 px / sum(w).
        assert abs((w * xs).sum() / w.sum() - u) < 1e-3
        assert abs((w * ys).sum() / w.sum() - v) < 1e-3


def test_render_blobs_clips_to_bit_depth_and_adds_noise():
    rng = np.random.default_rng(0)
    image = render_blobs((50, 60), [[30, 25]], sigma_px=2.0, peak=5000.0, background=100.0, noise=4.0, bit_depth=12, rng=rng)
    assert image.dtype == np.uint16 and image.max() == 4095
    corner = image[:10, :10].astype(float)
    assert abs(corner.mean() - 100.0) < 2.0 and 3.0 < corner.std() < 5.0
    with pytest.raises(CalibrationError, match="rng"):
        render_blobs((10, 10), [[5, 5]], noise=1.0)


@pytest.mark.parametrize(
    "bit_depth, peak_range, noise, background",
    [(8, (120.0, 240.0), 2.0, 12.0), (16, (20000.0, 60000.0), 300.0, 2000.0)],
)
@pytest.mark.parametrize("threshold", ["auto", "fixed"])
def test_centroids_of_rendered_blobs_meet_the_accuracy_requirement(bit_depth, peak_range, noise, background, threshold):
    rng = np.random.default_rng(bit_depth)
    shape = (240, 320)
    errors = []
    for _ in range(8):
        n = 12
        uv = _random_spots(rng, n, shape)
        sigma = rng.uniform(1.0, 2.0, n)
        peak = rng.uniform(*peak_range, n)
        image = render_blobs(shape, uv, sigma, peak, background, noise, bit_depth, rng)
        # Fixed: a quarter of the dimmest peak above the background, as one would set it by eye.
        config = DetectConfig() if threshold == "auto" else DetectConfig(threshold=int(background + peak_range[0] / 4))
        blobs = detect_blobs(image, config)
        assert len(blobs) == n
        errors.append(_match(blobs.uv, uv))
        assert np.all(blobs.roundness > 0.9) and np.all(blobs.flux > 0) and np.all(blobs.area >= 4)
    errors = np.concatenate(errors)
    assert np.sqrt(np.mean(errors**2)) <= CENTROID_RMS_PX


def test_blobs_sharing_one_region_are_measured_like_lone_blobs():
    # Diagonal neighbours: their row bands and column runs overlap, so both land in one region
    # of interest and go through the several-blobs path; each must match its lone measurement.
    uv = np.array([[40.3, 30.6], [47.8, 37.2], [80.4, 31.9]])
    image = render_blobs((80, 120), uv, sigma_px=1.2, peak=200.0, background=5.0, bit_depth=8)
    config = DetectConfig(threshold=20)
    together = detect_blobs(image, config)
    assert len(together) == 3
    for p in uv:
        alone = detect_blobs(render_blobs((80, 120), p[None], 1.2, 200.0, 5.0, bit_depth=8), config)
        j = int(np.argmin(np.linalg.norm(together.uv - p, axis=1)))
        np.testing.assert_allclose(together.uv[j], alone.uv[0], atol=1e-9)
        assert together.area[j] == alone.area[0] and together.flux[j] == alone.flux[0]
        np.testing.assert_allclose(together.roundness[j], alone.roundness[0], atol=1e-9)


def test_centroid_convention_is_pixel_centres_at_integers():
    image = np.zeros((20, 20), np.uint8)
    image[7:10, 3:6] = 50
    image[8, 4] = 100
    blobs = detect_blobs(image, DetectConfig(threshold=10))
    np.testing.assert_allclose(blobs.uv, [[4.0, 8.0]])
    assert blobs.area.tolist() == [9] and blobs.flux.tolist() == [8 * 40 + 90]


def test_streak_hot_pixel_flare_and_border_blob_are_rejected():
    rng = np.random.default_rng(3)
    shape = (300, 400)
    marker = np.array([[200.4, 150.7]])
    image = render_blobs(shape, marker, 1.5, 200.0, 10.0, 2.0, 8, rng)
    # A streak: a line of overlapping spots (a cable or an edge catching the light), 40 px long.
    streak = render_blobs(shape, np.c_[np.linspace(40, 80, 41), np.full(41, 60.0)], 1.0, 120.0, 0.0, bit_depth=8)
    # A huge saturated flare (a lamp in view): sigma 25 px, clipped at 255.
    flare = render_blobs(shape, [[300.0, 200.0]], 25.0, 1000.0, 0.0, bit_depth=8)
    # A marker cut by the image edge.
    edge = render_blobs(shape, [[1.0, 250.0]], 1.5, 200.0, 0.0, bit_depth=8)
    image = np.maximum(np.maximum(image, streak), np.maximum(flare, edge))
    image[100, 300] = 255  # a hot pixel
    config = DetectConfig()
    blobs = detect_blobs(image, config)
    np.testing.assert_allclose(blobs.uv, marker, atol=0.05)
    # Each one passes when its own filter is relaxed, so each filter did the rejecting.
    relaxed = detect_blobs(image, DetectConfig(min_area_px=1, max_area_px=10**6, min_roundness=0.0, reject_border=False))
    assert len(relaxed) == 5
    assert np.all(_match(relaxed.uv, np.array([[60.0, 60.0], [300.0, 200.0], [300.0, 100.0]])) < 0.5)
    assert len(detect_blobs(image, DetectConfig(min_roundness=0.0))) == 2  # + the streak
    assert len(detect_blobs(image, DetectConfig(min_area_px=1))) == 2  # + the hot pixel
    assert len(detect_blobs(image, DetectConfig(max_area_px=10**6))) == 2  # + the flare
    assert len(detect_blobs(image, DetectConfig(reject_border=False))) == 2  # + the cut marker


def test_empty_and_noise_only_images_give_no_blobs():
    for dtype in (np.uint8, np.uint16):
        blobs = detect_blobs(np.zeros((64, 48), dtype))
        assert isinstance(blobs, Blobs) and len(blobs) == 0
        assert blobs.uv.shape == (0, 2) and blobs.area.shape == (0,) and blobs.flux.shape == (0,)
    # The automatic threshold sits 6 sigma above the read noise: no false blobs in a full frame.
    rng = np.random.default_rng(5)
    noise = render_blobs((1024, 1280), np.zeros((0, 2)), background=20.0, noise=3.0, bit_depth=8, rng=rng)
    assert len(detect_blobs(noise)) == 0


def test_detect_many_equals_detect_blobs_per_image():
    rng = np.random.default_rng(11)
    images = []
    for i in range(7):
        shape = (200 + 10 * i, 260)
        bit_depth = 8 if i % 2 else 16
        peak = 200.0 if bit_depth == 8 else 40000.0
        images.append(render_blobs(shape, _random_spots(rng, 5, shape), 1.4, peak, 10.0, 2.0, bit_depth, rng))
    config = DetectConfig(min_roundness=0.3)
    expected = [detect_blobs(image, config) for image in images]
    for workers in (None, 1, 2):
        got = detect_many(images, config, workers=workers)
        assert len(got) == len(images)
        for g, e in zip(got, expected):
            np.testing.assert_array_equal(g.uv, e.uv)
            np.testing.assert_array_equal(g.area, e.area)
            np.testing.assert_array_equal(g.flux, e.flux)
            np.testing.assert_array_equal(g.roundness, e.roundness)
    assert detect_many([], config) == []


@pytest.mark.parametrize(
    "image, message",
    [
        (np.zeros((10, 10), np.float32), "dtype uint8 or uint16"),
        (np.zeros((10, 10, 3), np.uint8), "2-D grayscale"),
        (np.zeros(10, np.uint8), "ndim=1"),
        ([[0, 1], [2, 3]], "numpy array"),
        (np.zeros((0, 10), np.uint8), "empty"),
    ],
)
def test_bad_images_raise_a_calibration_error_naming_the_problem(image, message):
    with pytest.raises(CalibrationError, match=message):
        detect_blobs(image)
    with pytest.raises(CalibrationError, match=f"image 1: .*{message}"):
        detect_many([np.zeros((4, 4), np.uint8), image])


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"threshold": -1}, "threshold"),
        ({"threshold": 9.5}, "threshold"),
        ({"min_area_px": 0}, "min_area_px"),
        ({"min_area_px": 10, "max_area_px": 5}, "max_area_px"),
        ({"min_roundness": 1.5}, "min_roundness"),
        ({"connectivity": 6}, "connectivity"),
        ({"connectivity": True}, "connectivity"),
        ({"seed_ratio": 0.5}, "seed_ratio"),
        ({"weights": "grey"}, "weights"),
        ({"background": "median"}, "background"),
        ({"highpass_px": 0}, "highpass_px"),
        ({"highpass_px": 2.5}, "highpass_px"),
        ({"running_frames": 1}, "running_frames"),
        ({"threshold": float("nan")}, "threshold"),
        ({"reject_border": "yes"}, "reject_border"),
    ],
)
def test_bad_config_is_refused(kwargs, field):
    with pytest.raises(CalibrationError, match=field):
        DetectConfig(**kwargs)
    with pytest.raises(CalibrationError, match=field):
        DetectConfig().replace(**kwargs)


def test_config_is_one_validated_value_with_its_defaults_in_one_place():
    config = DetectConfig(threshold=9.0)
    assert config.threshold == 9 and isinstance(config.threshold, int)
    assert config.replace(min_area_px=2) == DetectConfig(threshold=9, min_area_px=2)
    assert DetectConfig().describe() == "default detection settings"
    assert "threshold=9" in config.describe() and "min_area_px" not in config.describe()
    assert DetectConfig(**DetectConfig().to_dict()) == DetectConfig()
    with pytest.raises(CalibrationError, match="no field"):
        DetectConfig().replace(treshold=3)


# ---------------------------------------------------------------------------------------------
# Wand frames and static markers (blob lists, as the detector returns them)

L_FRAME_UV = np.array([[400.0, 700.0], [520.0, 702.0], [700.0, 705.0], [398.0, 560.0]])
STILL_JITTER_PX = 0.05  # centroid noise of a still marker between frames


def _still(rng, n=None):
    uv = L_FRAME_UV + rng.normal(0, STILL_JITTER_PX, L_FRAME_UV.shape)
    return uv if n is None else uv[:n]


def _wanding(rng, frames=120):
    """Frames of an L-frame left in view plus a moving wand; returns blobs and the truth."""
    t = np.arange(frames)
    centre = np.c_[640 + 400 * np.sin(t / 17.0), 450 + 250 * np.cos(t / 11.0)]
    half = 40 * np.c_[np.cos(t / 5.0), np.sin(t / 5.0)]
    wand = np.stack((centre - half, centre + half), axis=1)  # (frames, 2, 2)
    blobs, expect_keep, too_few, too_many = [], [], 0, 0
    for i in range(frames):
        parts = [_still(rng, 3 if i % 9 == 0 else None)]  # the waver sometimes hides a marker
        if i % 10 == 3:
            parts.append(wand[i, :1])  # one wand marker out of view
            too_few += 1
        elif i % 10 == 7:
            parts.append(np.vstack((wand[i], [[100.0 + i, 100.0]])))  # a stray reflection
            too_many += 1
        else:
            parts.append(wand[i])
            expect_keep.append(i)
        uv = np.vstack(parts)
        blobs.append(uv[rng.permutation(len(uv))])
    return blobs, wand, np.array(expect_keep), too_few, too_many


@pytest.mark.parametrize("source", ["static recording", "auto"])
def test_wand_frames_ignore_a_still_l_frame_in_view(source):
    rng = np.random.default_rng(21)
    blobs, wand, keep, too_few, too_many = _wanding(rng)
    static_uv = static_markers_from_frames([_still(rng) for _ in range(25)]) if source != "auto" else None
    result = wand_frames(blobs, static_uv)
    np.testing.assert_array_equal(result.frame, keep)
    assert result.too_few == too_few and result.too_many == too_many and result.total == len(blobs)
    assert len(result.still_uv) == len(L_FRAME_UV)
    assert result.uv.shape == (len(keep), 2, 2)
    for uv, i in zip(result.uv, result.frame):
        # The pair, in either order, is the wand's.
        assert np.allclose(np.sort(uv, axis=0), np.sort(wand[i], axis=0))
    assert f"kept {len(keep)} of {len(blobs)}" in result.summary()


def test_wand_frames_without_still_markers_take_the_l_frame_for_clutter():
    # What the still-marker removal protects against: with it disabled, every frame has > 2 blobs.
    rng = np.random.default_rng(22)
    blobs, *_ = _wanding(rng)
    result = wand_frames(blobs, np.zeros((0, 2)))
    assert len(result) == 0 and result.too_many == len(blobs)


def test_wand_frames_accept_blobs_objects_and_count_empty_frames():
    frames = [Blobs.empty(), Blobs(np.array([[10.0, 10.0], [50.0, 50.0]]), [5, 5], [1, 1], [9, 9]), np.zeros((0, 2))]
    result = wand_frames(frames)
    assert result.frame.tolist() == [1] and result.too_few == 2 and result.too_many == 0


def test_static_markers_are_averaged_over_frames():
    rng = np.random.default_rng(31)
    frames = []
    for i in range(25):
        uv = _still(rng, 3 if i < 3 else None)  # marker 4 hidden in 3 frames: present in 88 %
        if i % 8 == 0:
            uv = np.vstack((uv, rng.uniform(0, 1000, (1, 2))))  # a passing reflection
        frames.append(uv)
    markers = static_markers_from_frames(frames)
    assert markers.shape == (4, 2)
    truth = L_FRAME_UV[np.lexsort((L_FRAME_UV[:, 0], L_FRAME_UV[:, 1]))]
    # The mean of >= 22 frames has standard error <= 0.05 / sqrt(22) per axis; allow 5 of them.
    assert np.max(np.abs(markers - truth)) < 5 * STILL_JITTER_PX / np.sqrt(22)
    assert len(static_markers_from_frames(frames, min_presence=0.95)) == 3
    assert static_markers_from_frames([]).shape == (0, 2)
    with pytest.raises(CalibrationError, match="frame 1"):
        static_markers_from_frames([np.zeros((0, 2)), np.zeros((3, 3))])


def test_wand_frames_from_rendered_images_end_to_end():
    # A small image-level run: render, detect (both cores), find the still markers, keep frames.
    rng = np.random.default_rng(41)
    shape = (240, 320)
    still = np.array([[60.0, 200.0], [120.0, 202.0], [200.0, 205.0], [58.0, 150.0]])
    images, truth = [], []
    for i in range(24):
        wand = np.array([[80 + 6 * i, 60.0 + 2 * i], [110 + 6 * i, 90.0 - i]])
        truth.append(wand)
        images.append(render_blobs(shape, np.vstack((still, wand)), 1.5, 200.0, 10.0, 2.0, 8, rng))
    blobs = detect_many(images, workers=2)
    static = static_markers_from_frames(blobs[:5])
    np.testing.assert_allclose(static, still[np.lexsort((still[:, 0], still[:, 1]))], atol=0.05)
    result = wand_frames(blobs, static)
    assert result.frame.tolist() == list(range(24))
    err = [_match(uv, t) for uv, t in zip(result.uv, truth)]
    assert np.sqrt(np.mean(np.square(err))) <= CENTROID_RMS_PX
