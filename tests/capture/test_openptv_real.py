"""Detection on real, cluttered images: OpenPTV's test_cavity frame 10000 (4 cameras, bright
particles with glare off the glass and a glowing back wall), against OpenPTV's own detections.

Read in place from ../shared/data/openptv_test_cavity (SOURCE.md there); skipped when absent.
The figures are in docs/benchmarks.md, "Detection on real images" (bench/bench_detect.py --real).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from wandcal.calib.detect import CameraDetector, DetectConfig

pytestmark = pytest.mark.shared_data

CAMERAS = (1, 2, 3, 4)
# docs/conventions.md: OpenPTV's targ_rec/peak_fit add 0.5 to the weighted pixel index (its origin
# is the top-left pixel's corner); ours puts pixel centres at integers.
OPENPTV_OFFSET_PX = 0.5
MATCH_RADIUS_PX = 0.5  # SOURCE.md: "match centroids within about 0.5 px"
ISOLATED_PX = 10.0  # reference targets with no other target this close: no split/merge ambiguity
# The goals: isolated-target recall and median centroid difference after the convention.
GOAL_ISOLATED_RECALL = 0.95
GOAL_MEDIAN_PX = 0.1
# What the default settings reach (docs/decisions/0012, addendum 2026-11-23): 3,116 of the 3,506
# isolated targets. The goal's 95 % needs OpenPTV's own threshold to the grey level and its weights.
DEFAULT_ISOLATED_RECALL = 3116 / 3506
DETECTION_SIGMAS = 3  # a change must not lose more than 3 binomial standard errors of that recall
OPENPTV_HIGHPASS_PX = 12  # OpenPTV's high-pass half-width ("dim_lp"; not in its .par files)
OPENPTV_SEED_RATIO = 2.0  # OpenPTV grows targets only from peaks above twice the threshold
TARGETS_DECIMALS = 4  # the _targets files print x, y with 4 decimals: +-5e-5 px


def _read(root, cam):
    image = cv2.imread(str(root / "img" / f"cam{cam}.10000"), cv2.IMREAD_UNCHANGED)
    assert image is not None and image.dtype == np.uint8 and image.shape == (1024, 1280)
    ref = np.loadtxt(root / "img" / f"cam{cam}.10000_targets", skiprows=1, ndmin=2)
    return image, ref  # ref rows: pnr x y n nx ny sumg tnr


def _targ_rec(root):
    """targ_rec.par (SOURCE.md): per-camera thresholds, pixel-count limits, minimum sum of grey."""
    lines = (root / "parameters" / "targ_rec.par").read_text().split()
    return [int(v) for v in lines[:4]], int(lines[5]), int(lines[6]), float(lines[11])


def _openptv_like(threshold, n_min, n_max, weights="signal"):
    return DetectConfig(threshold=threshold, seed_ratio=OPENPTV_SEED_RATIO, min_area_px=n_min, max_area_px=n_max,
                        min_roundness=0.0, weights=weights, background="highpass", highpass_px=OPENPTV_HIGHPASS_PX)


def _isolated(ref_uv):
    neighbour = np.sort(np.linalg.norm(ref_uv[:, None] - ref_uv[None], axis=2), axis=1)[:, 1]
    return neighbour >= ISOLATED_PX


def _nearest(found, ref_uv):
    """(distance, index of the nearest found blob) per reference target."""
    d = np.linalg.norm(ref_uv[:, None] - found[None], axis=2)
    return d.min(axis=1), d.argmin(axis=1)


def _compare(root, weights):
    thresholds, n_min, n_max, sumg_min = _targ_rec(root)
    hits = iso_hits = iso_total = 0
    total, matched_d, offsets = 0, [], []
    for cam in CAMERAS:
        image, ref = _read(root, cam)
        blobs = CameraDetector(_openptv_like(thresholds[cam - 1], n_min, n_max, weights), camera=f"cam{cam}").detect(image)
        # OpenPTV's minimum sum of grey values: the flux with signal weights, + area x threshold otherwise.
        sumg = blobs.flux if weights == "signal" else blobs.flux + blobs.area * blobs.threshold
        uv = blobs.uv[sumg > sumg_min]
        ref_uv = ref[:, 1:3] - OPENPTV_OFFSET_PX
        d, j = _nearest(uv, ref_uv)
        ok, iso = d < MATCH_RADIUS_PX, _isolated(ref_uv)
        hits, total = hits + int(ok.sum()), total + len(ok)
        iso_hits, iso_total = iso_hits + int(ok[iso].sum()), iso_total + int(iso.sum())
        matched_d.append(d[ok])
        offsets.append(ref[ok, 1:3] - uv[j[ok]])
    return iso_hits / iso_total, hits / total, np.concatenate(matched_d), np.concatenate(offsets)


def test_openptv_settings_find_openptvs_isolated_targets(shared_data):
    iso_recall, recall, d, _ = _compare(shared_data / "openptv_test_cavity", "signal")
    assert iso_recall >= GOAL_ISOLATED_RECALL
    assert np.median(d) <= GOAL_MEDIAN_PX
    # The rest are touching targets, which OpenPTV splits at local maxima and we keep whole.
    assert recall > 0.8


def test_pixel_origin_differs_from_openptvs_by_half_a_pixel(shared_data):
    # With OpenPTV's weights the same pixels give the same centroid, so every matched target sits
    # exactly OPENPTV_OFFSET_PX from ours on both axes, up to the file's printed digits.
    *_, offsets = _compare(shared_data / "openptv_test_cavity", "signal")
    rounding = 0.5 * 10.0**-TARGETS_DECIMALS
    assert np.median(np.abs(offsets - OPENPTV_OFFSET_PX)) <= rounding + 1e-9


def test_default_weights_agree_with_openptv_within_the_goal(shared_data):
    # Our default weights (grey level above the threshold) differ from OpenPTV's on purpose:
    # they halve the centroid error on rendered spots (docs/decisions/0012); the matched
    # centroids still agree to within the goal's median.
    _, _, d, _ = _compare(shared_data / "openptv_test_cavity", "excess")
    assert np.median(d) <= GOAL_MEDIAN_PX


def test_defaults_see_past_the_glare(shared_data):
    root = shared_data / "openptv_test_cavity"
    for cam in CAMERAS:
        image, ref = _read(root, cam)
        ref_uv = ref[:, 1:3] - OPENPTV_OFFSET_PX
        blobs = CameraDetector(camera=f"cam{cam}").detect(image)
        flat = CameraDetector(DetectConfig(background="none"), camera=f"cam{cam}").detect(image)
        # The glare and the glowing wall make the background uneven: "auto" takes the high-pass,
        # and the automatic threshold is no longer set by the glare (the issue: grey 95-215).
        assert blobs.background == "highpass" and flat.background == "none"
        assert blobs.threshold < flat.threshold / 3
        found = np.sum(_nearest(blobs.uv, ref_uv)[0] < MATCH_RADIUS_PX)
        found_flat = np.sum(_nearest(flat.uv, ref_uv)[0] < MATCH_RADIUS_PX)
        assert found > 3 * found_flat


def test_defaults_find_openptvs_isolated_targets(shared_data):
    # The defaults alone: "auto" takes the high-pass, the threshold is 6 sigmas of the frames' pixel
    # noise, the roundness limit that of a cluttered scene, and the weights stay ours ("excess").
    root = shared_data / "openptv_test_cavity"
    thresholds = _targ_rec(root)[0]
    iso_hits = iso_total = 0
    matched = []
    for cam in CAMERAS:
        image, ref = _read(root, cam)
        ref_uv = ref[:, 1:3] - OPENPTV_OFFSET_PX
        blobs = CameraDetector(camera=f"cam{cam}").detect(image)
        assert blobs.background == "highpass"
        # The automatic threshold lands within a grey level of OpenPTV's hand-set one (9/9/9/11).
        assert abs(blobs.threshold - thresholds[cam - 1]) <= 1
        d = _nearest(blobs.uv, ref_uv)[0]
        ok, iso = d < MATCH_RADIUS_PX, _isolated(ref_uv)
        iso_hits, iso_total = iso_hits + int(ok[iso].sum()), iso_total + int(iso.sum())
        matched.append(d[ok])
    recall = iso_hits / iso_total
    se = np.sqrt(DEFAULT_ISOLATED_RECALL * (1 - DEFAULT_ISOLATED_RECALL) / iso_total)
    assert recall >= DEFAULT_ISOLATED_RECALL - DETECTION_SIGMAS * se
    assert np.median(np.concatenate(matched)) <= GOAL_MEDIAN_PX
