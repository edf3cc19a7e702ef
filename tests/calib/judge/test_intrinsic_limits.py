"""The honest sigma: how far a camera's position hinges on a focal length that was given
(calib/judge/intrinsic_limits.py)."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.intrinsic_limits import (
    DEFAULT_FOCAL_REL_STD,
    DEFAULT_NOMINAL_PRINCIPAL_WIDTH_STD,
    DEFAULT_PRINCIPAL_WIDTH_STD,
    DEFAULT_RADIAL_CORNER_STD,
    DEFAULT_TANGENTIAL_STD,
    LIMIT_RATIO,
    LensLimit,
    focal_limit,
    lens_columns,
    lens_limited,
    lens_sigmas,
    limit_entry,
    limited_cameras,
)
from wandcal.calib.judge.verdict import SIGMA_REL_SE
from wandcal.calib.rig import Camera


def _camera_view(depth: float, n: int = 400, seed: int = 0, noise: float = 0.0):
    """A camera at a random pose seeing points on the plane at ``depth`` in front of it: its pose,
    and the points' normalised projections, depths and residuals."""
    rng = np.random.default_rng(seed)
    R = rotvec_to_matrix(rng.normal(0, 0.5, 3))
    t = rng.normal(0, 1.0, 3)
    xy = rng.uniform(-0.4, 0.4, (n, 2))
    residual = rng.normal(0, noise, (n, 2)) if noise else np.zeros((n, 2))
    return R, t, xy, np.full(n, depth), residual


def test_a_focal_length_off_by_d_moves_a_camera_along_its_axis_by_d_times_the_planes_depth():
    # points on a fronto-parallel plane at depth D: a focal length (1 + d) times the true one
    # scales the image by 1 / (1 + d), exactly what moving back by D d does to first order
    depth = 3.0
    R, t, xy, d, r = _camera_view(depth)
    many_views = np.full(len(d), 10**9)  # points pinned by the other cameras: the pose takes it all
    limit = focal_limit(R, t, xy, d, r, many_views, DEFAULT_FOCAL_REL_STD, "default")
    assert limit.along_axis_m_per_unit == pytest.approx(-depth, rel=1e-4)
    np.testing.assert_allclose(limit.shift_m_per_unit, -depth * R[2], atol=1e-4 * depth)
    assert limit.std == pytest.approx(depth * DEFAULT_FOCAL_REL_STD, rel=1e-4)
    # a point seen by two cameras moves to share the error: the pose takes up half
    two = focal_limit(R, t, xy, d, r, np.full(len(d), 2), DEFAULT_FOCAL_REL_STD, "default")
    assert two.along_axis_m_per_unit == pytest.approx(-depth / 2, rel=1e-4)


def test_the_datas_own_focal_standard_error_grows_with_the_residual_scatter():
    # points at two depths tell the focal length from the distance, the better the less they scatter
    R, t, xy, _, _ = _camera_view(3.0, noise=1e-3)
    depth = np.where(np.arange(len(xy)) % 2 == 0, 2.0, 4.0)
    views = np.full(len(xy), 3)
    quiet = focal_limit(R, t, xy, depth, np.random.default_rng(1).normal(0, 1e-4, xy.shape), views, 0.02, "default")
    loud = focal_limit(R, t, xy, depth, np.random.default_rng(1).normal(0, 1e-3, xy.shape), views, 0.02, "default")
    assert np.isfinite(quiet.data_rel_std) and quiet.data_rel_std > 0
    assert loud.data_rel_std == pytest.approx(10 * quiet.data_rel_std, rel=1e-6)


def test_a_camera_is_named_only_where_its_focal_length_outweighs_its_geometry():
    R, t, xy, d, r = _camera_view(3.0)
    limit = focal_limit(R, t, xy, d, r, np.full(len(d), 10**9), 0.02, "default")  # 60 mm from the focal length
    named = limited_cameras(["cam1", "cam2"], [limit, limit], [limit.std / LIMIT_RATIO * 1.01, 0.001], scaled=True)
    assert [n["camera"] for n in named] == ["cam2"]
    assert "3000.0 mm for each 1%" not in named[0]["message"] and "30.0 mm for each 1%" in named[0]["message"]
    assert "focal_std_px" in named[0]["message"]  # says the 2% is assumed, and where to give the real one
    assert limited_cameras(["cam1"], [None], [0.001], scaled=True) == []


def test_a_cameras_focal_std_is_read_from_rig_json_and_written_back():
    from wandcal.capture.folder import CaptureFormatError
    from wandcal.capture.rig_file import rig_from_json, rig_to_json

    cam = {"id": "cam1", "width": 640, "height": 480, "K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]],
           "dist": [0, 0, 0, 0, 0]}
    doc = {"format": "wandcal-capture/1", "cameras": [cam | {"focal_std_px": 4.0}, cam | {"id": "cam2"}],
           "wand": {"length_m": 0.5}}
    rig = rig_from_json(doc)
    assert [c.focal_std_px for c in rig.cameras] == [4.0, None]
    assert rig_from_json(rig_to_json(rig)).cameras[0].focal_std_px == 4.0
    for bad in (-1.0, "4", 0.0):
        with pytest.raises(CaptureFormatError, match=r"cameras\[0\]\.focal_std_px"):
            rig_from_json(doc | {"cameras": [cam | {"focal_std_px": bad}, cam | {"id": "cam2"}]})
    with pytest.raises(CalibrationError, match="focal_std_px"):
        Camera("cam1", 640, 480, np.array(cam["K"], float), np.zeros(5), focal_std_px=900.0)


# -- every other given intrinsic (cx, cy, k1, k2, p1, p2) ------------------------------------------

def _lens_camera(dist=(0.0, 0.0, 0.0, 0.0, 0.0)) -> Camera:
    K = np.array([[1000.0, 0, 640], [0, 1000.0, 480], [0, 0, 1]])
    return Camera("cam1", 1280, 960, K, np.array(dist, float))


def test_the_default_sigmas_are_the_stated_shares_of_the_image():
    nominal = _lens_camera()  # its principal point at the image's centre: nominal, not calibrated
    assert lens_sigmas(nominal)["cx"] == pytest.approx(DEFAULT_NOMINAL_PRINCIPAL_WIDTH_STD * 1280)
    K = nominal.K.copy()
    K[0, 2] = 646.0
    cam = Camera("cam1", 1280, 960, K, np.zeros(5))
    sig = lens_sigmas(cam)
    corner = np.hypot(646 / 1000, 0.48)  # the corner's normalised radius
    assert sig["cx"] == sig["cy"] == pytest.approx(DEFAULT_PRINCIPAL_WIDTH_STD * 1280)
    assert sig["k1"] * corner ** 2 == pytest.approx(DEFAULT_RADIAL_CORNER_STD["k1"])
    assert sig["k2"] * corner ** 4 == pytest.approx(DEFAULT_RADIAL_CORNER_STD["k2"])
    assert sig["p1"] == sig["p2"] == DEFAULT_TANGENTIAL_STD


def test_a_principal_point_off_moves_every_observation_by_its_pixels_over_the_focal_length():
    # without distortion, x = (u - cx) / fx exactly: cx off by s moves every x by -s / fx
    cam = _lens_camera()
    xy = np.random.default_rng(3).uniform(-0.5, 0.5, (50, 2))
    cols = lens_columns(cam, xy, {"cx": 6.0, "cy": 4.0})
    np.testing.assert_allclose(cols["cx"], np.tile([-6.0 / 1000, 0.0], (50, 1)), atol=1e-12)
    np.testing.assert_allclose(cols["cy"], np.tile([0.0, -4.0 / 1000], (50, 1)), atol=1e-12)


def test_a_k1_off_moves_an_observation_by_k1_r2_times_its_radius():
    # x_d = x (1 + k1 r^2): k1 off by s moves the undistorted point by -s r^2 x to first order; the
    # central difference leaves the third order, under (s r^2)^2 of it
    cam = _lens_camera()
    xy = np.random.default_rng(4).uniform(-0.5, 0.5, (50, 2))
    s = 0.02
    col = lens_columns(cam, xy, {"k1": s})["k1"]
    r2 = np.sum(xy ** 2, axis=1, keepdims=True)
    np.testing.assert_allclose(col, -s * r2 * xy, atol=float(np.max((s * r2) ** 2 * np.abs(xy))) * 4 + 1e-15)


def test_a_parameter_is_named_where_it_outweighs_the_geometry_with_what_to_do():
    shift = np.array([0.003, 0.0, 0.0])
    cy = LensLimit("cy", shift, 0.0, 2.7, 0.1)  # 3 mm for 2.7 px, the data give it to 0.1 sigma
    k2 = LensLimit("k2", shift / 20, 0.0, 0.03, 2.0)  # 0.15 mm: under a 0.5 mm geometry sigma's material share
    p1 = LensLimit("p1", shift, 0.0, 0.0007, 0.1)
    named = lens_limited("cam4", [cy, k2, p1], 0.0005, scaled=True)
    assert [n["parameter"] for n in named] == ["cy", "p1"]
    assert named[0]["message"].startswith("cam4's principal point's y (cy) is determined by this capture (to 0.10 of its")
    assert "(2.7 px: docs/verdict.md" in named[0]["message"] and "it moves the camera 3 mm" in named[0]["message"]
    assert "--refine-intrinsics principal" in named[0]["message"] and named[0]["evidence"]["determined"]
    assert "wandcal does not refine it" in named[1]["message"]
    undetermined = lens_limited("cam4", [LensLimit("cy", shift, 0.0, 2.7, 0.9)], 0.0005, scaled=True)
    assert undetermined[0]["message"].startswith("cam4's principal point's y (cy) cannot be determined from this capture: ")
    assert undetermined[0]["message"].endswith("; give it from a lens calibration")


def test_a_part_is_material_where_it_raises_the_geometry_sigma_past_its_own_standard_error():
    """The one rule for every intrinsic: named where sqrt(geo^2 + part^2) passes (1 + SIGMA_REL_SE) geo."""
    geo = 0.0005
    at = np.sqrt((1 + SIGMA_REL_SE) ** 2 - 1) * geo  # the part that raises the 0.5 mm sigma by exactly 11%
    for part, named in ((0.99 * at, False), (1.01 * at, True)):
        assert bool(lens_limited("cam4", [LensLimit("k2", np.array([part, 0.0, 0.0]), 0.0, 0.03, 2.0)], geo, True)) is named
        assert np.hypot(geo, part) > (1 + SIGMA_REL_SE) * geo if named else np.hypot(geo, part) < (1 + SIGMA_REL_SE) * geo
    R, t, xy, d, r = _camera_view(3.0)
    focal = focal_limit(R, t, xy, d, r, np.full(len(d), 10**9), 0.02, "default")
    assert [n["camera"] for n in limited_cameras(["a", "b"], [focal, focal], [focal.std / LIMIT_RATIO * 1.01,
                                                                             focal.std / LIMIT_RATIO * 0.99], True)] == ["b"]


def test_the_honest_sigma_adds_every_given_intrinsics_part():
    R, t, xy, d, r = _camera_view(3.0)
    focal = focal_limit(R, t, xy, d, r, np.full(len(d), 10**9), 0.02, "default")
    cy = LensLimit("cy", np.array([0.0, 0.004, 0.0]), 0.0, 2.7, 0.5)
    entry = limit_entry(focal, 0.001, True, [cy])
    want = np.sqrt(0.001 ** 2 + focal.std ** 2 + 0.004 ** 2)
    assert entry["geometry_std_honest_mm"] == pytest.approx(1000 * want, abs=1e-4)
    assert entry["lens_limits"]["cy"]["mm_per_sigma"] == pytest.approx(4.0)
    assert limit_entry(None, 0.001, True, [cy])["geometry_std_honest_mm"] == pytest.approx(1000 * np.hypot(0.001, 0.004), abs=1e-4)
    assert limit_entry(None, 0.001, True, []) is None


def test_a_result_keeps_its_lens_limits_through_json():
    from wandcal.calib.run.camera_figures import CameraFigures

    doc = {"reprojection_rms_px": 0.3, "observations": 10, "frames_with_both_ends": 5, "worst_frames": [],
           "initial_pose": "pnp", "lens_limits": {"cy": {"sigma": 2.7, "unit": "px", "source": "default",
                                                         "mm_per_sigma": 4.0, "along_axis_mm_per_sigma": 0.1,
                                                         "data_std_sigmas": 0.5}},
           "geometry_std_honest_mm": 4.1}
    cam = CameraFigures.from_json(doc)
    assert cam.focal_limit is not None and cam.focal_limit.focal_limit is None
    assert cam.to_json() == doc


def test_a_distorted_pinhole_lens_columns_agree_with_undistorting_the_same_pixels_again():
    # first order (the columns) against central differences through OpenCV's iterative undistortion:
    # they differ by the second order, (the parameter's share of the radius at the corner, <= 2.4%)^2
    # times a few, so 2% of a column's size bounds it
    from dataclasses import replace

    from wandcal.calib.geometry import distort_points, undistort_points
    from wandcal.calib.judge.lens_sigmas import _perturbed

    cam = replace(_lens_camera(), dist=np.array([-0.17, 0.14, 0.0005, -0.0007, 0.01]))
    xy = np.random.default_rng(5).uniform(-0.55, 0.55, (200, 2))
    sig = lens_sigmas(cam)
    cols = lens_columns(cam, xy, sig)
    uv = distort_points(cam, xy)
    for name, s in sig.items():
        numeric = 0.5 * (undistort_points(_perturbed(cam, name, s), uv) - undistort_points(_perturbed(cam, name, -s), uv))
        assert np.abs(cols[name] - numeric).max() <= 0.02 * np.abs(numeric).max(), name


def test_a_fisheye_lens_has_its_radial_terms_and_no_tangential_ones():
    K = np.array([[600.0, 0, 640], [0, 600.0, 480], [0, 0, 1]])
    cam = Camera("cam1", 1280, 960, K, np.array([0.05, 0.01, 0.0, 0.0]), model="fisheye")
    sig = lens_sigmas(cam)
    assert set(sig) == {"cx", "cy", "k1", "k2"}
    xy = np.random.default_rng(6).uniform(-0.8, 0.8, (50, 2))
    cols = lens_columns(cam, xy, sig)
    assert all(np.all(np.isfinite(c)) and np.abs(c).max() > 0 for c in cols.values())
