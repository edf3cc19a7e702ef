"""calib/refraction.py: a pinhole camera behind a flat window (air, glass, water), against Snell's law
and the pinhole it must become when the three media are one."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import project_normalized
from wandcal.calib.refraction import FlatWindow, nearest_to_rays, project_through_window, trace_into_medium

ROUNDING_M = 1e-12  # float64 on paths of ~0.6 m: ~1e-16 relative, a thousandfold margin for the iterations


def look_at(C, target=None):
    """(R, t) of a camera at C (3,) looking at target (the origin if None), image y along world -y."""
    target = np.zeros(3) if target is None else target
    z = (target - C) / np.linalg.norm(target - C)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ C


def cavity_camera(side=-1.0, offset=0.08):
    """A camera 0.57 m from the origin on the -z (side -1) or +z side, behind a window 0.125 m out."""
    C = np.array([offset, 0.016, side * 0.57])
    window = FlatWindow(np.array([0.0, 0.0, side]), 0.125, 0.006, 1.0, 1.49, 1.33)
    return (*look_at(C), window)


def points_in_water(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.04, -0.03, -0.02], [0.04, 0.03, 0.02], (n, 3))


@pytest.mark.parametrize("side", [-1.0, 1.0])
def test_projection_and_tracing_are_one_ray(side):
    """A point projected, then its image traced into the water: the ray passes through the point."""
    R, t, window = cavity_camera(side)
    X = points_in_water(200)
    origin, direction = trace_into_medium(window, R, t, project_through_window(window, R, t, X))
    off = np.cross(X - origin, direction)
    assert np.abs(np.linalg.norm(off, axis=1)).max() < ROUNDING_M


def test_traced_ray_obeys_snell():
    """n_air sin(air angle) = n_water sin(water angle), the rays in the plane of the normal."""
    R, t, window = cavity_camera()
    xy = np.random.default_rng(1).uniform(-0.05, 0.05, (100, 2))
    v_air = np.concatenate([xy, np.ones((100, 1))], axis=1) @ R
    v_air /= np.linalg.norm(v_air, axis=1, keepdims=True)
    _, v_water = trace_into_medium(window, R, t, xy)
    n = window.normal
    sin_air = np.linalg.norm(np.cross(v_air, n), axis=1)
    sin_water = np.linalg.norm(np.cross(v_water, n), axis=1)
    np.testing.assert_allclose(window.n_air * sin_air, window.n_water * sin_water, atol=1e-14)
    assert np.abs(np.einsum("ij,ij->i", np.cross(v_air, n), v_water)).max() < 1e-14  # coplanar
    np.testing.assert_allclose(np.linalg.norm(v_water, axis=1), 1.0, atol=1e-14)


def test_one_medium_is_a_pinhole():
    R, t, window = cavity_camera()
    same = FlatWindow(window.normal, window.distance, window.thickness, 1.0, 1.0, 1.0)
    X = points_in_water(50)
    np.testing.assert_allclose(project_through_window(same, R, t, X), project_normalized(R, t, X), atol=1e-14)


def test_refraction_moves_the_image_as_snell_says():
    """A point on the window's normal through the camera stays put; one off it appears further out
    than a pinhole puts it (water and glass bend the ray towards the normal)."""
    R, t, window = cavity_camera(offset=0.0)
    C = -R.T @ t
    on_axis = np.array([[C[0], C[1], 0.0]])
    np.testing.assert_allclose(project_through_window(window, R, t, on_axis), project_normalized(R, t, on_axis),
                               atol=1e-15)
    X = np.array([[0.03, 0.016, 0.0]])
    radial = lambda xy: np.linalg.norm(xy - project_normalized(R, t, on_axis), axis=1)  # noqa: E731
    assert radial(project_through_window(window, R, t, X)) > radial(project_normalized(R, t, X))


def test_points_outside_the_water_have_no_image():
    R, t, window = cavity_camera()
    X = np.array([[0.0, 0.0, -0.2], [0.0, 0.0, 0.0]])  # the first is between the window and the camera
    xy = project_through_window(window, R, t, X)
    assert np.isnan(xy[0]).all() and np.isfinite(xy[1]).all()


def test_nearest_to_rays_meets_the_rays():
    X = points_in_water(30, seed=2)
    origin = np.concatenate([X + [0.1, 0.0, -0.3], X + [-0.1, 0.05, 0.3]])
    direction = np.concatenate([X, X]) - origin
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    point = np.tile(np.arange(30), 2)
    np.testing.assert_allclose(nearest_to_rays(origin, direction, point, 31)[:30], X, atol=ROUNDING_M)
    assert np.isnan(nearest_to_rays(origin, direction, point, 31)[30]).all()  # no rays


@pytest.mark.parametrize("kwargs, words", [
    ({"normal": [0, 0, 0]}, "normal"),
    ({"n_air": 1.5, "n_glass": 1.49}, "least dense"),
    ({"thickness": -0.001}, "thickness"),
])
def test_bad_windows_are_refused(kwargs, words):
    args = {"normal": [0, 0, 1], "distance": 0.1, "thickness": 0.006, "n_air": 1.0, "n_glass": 1.49, "n_water": 1.33} | kwargs
    with pytest.raises(CalibrationError, match=words):
        FlatWindow(**args)


def test_a_camera_inside_the_window_is_refused():
    R, t, window = cavity_camera()
    flipped = FlatWindow(-window.normal, window.distance, window.thickness, 1.0, 1.49, 1.33)
    with pytest.raises(CalibrationError, match="normal must point"):
        project_through_window(flipped, R, t, points_in_water(3))
