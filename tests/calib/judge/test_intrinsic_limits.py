"""The honest sigma: how far a camera's position hinges on a focal length that was given
(calib/judge/intrinsic_limits.py)."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.intrinsic_limits import (
    DEFAULT_FOCAL_REL_STD,
    LIMIT_RATIO,
    focal_limit,
    limited_cameras,
)
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
