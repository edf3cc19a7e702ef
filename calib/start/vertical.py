"""The world's vertical from the floor or from gravity, for captures without an L-frame.

Two references that easyWand and Argus offer, besides the static object and axis points:

- **the floor** (``floor.csv``): named points on the floor, each seen by two or more cameras. The
  plane fitted to them (least squares, by the singular vectors of the centred points) gives z (its
  normal, towards the cameras) and the origin (the points' centroid, on the plane);
- **gravity** (``drop.csv``): an object dropped or thrown through the volume, one blob per camera
  and frame. The quadratic fitted to its triangulated track gives the acceleration, whose
  direction is down; the origin stays the wand volume's.

In both, x is the gauge camera's image-right made level, as in the wand volume's frame. Each
reference carries its own noise (:class:`VerticalFit`): the plane's tilt and height, or the
acceleration's direction, from the fit's residuals. calib/solve/uncertainty.py adds the poses' part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers, undistort_by_camera
from wandcal.calib.rig import Rig, VerticalObservations
from wandcal.calib.triangulate import triangulate_points

MIN_FLOOR_POINTS = 3  # three points fit a plane; its noise needs a fourth
MIN_DROP_FRAMES = 5  # a quadratic in time (three coefficients per axis) and two degrees of freedom
# the track's acceleration must stand this many standard errors clear of zero for its direction to
# mean anything (its direction's standard error is then under 1/10 rad, ~6 degrees)
MIN_ACCELERATION_SE = 10.0


@dataclass(frozen=True, eq=False)
class VerticalFit:
    """What a floor or a dropped object says about the vertical, in the gauge frame.

    up: (3,) unit vector; origin: (3,) the floor points' centroid, or None for gravity (the origin
    is then the wand volume's); tilt_axes: (2, 3) two unit vectors orthogonal to ``up``;
    tilt_cov: (2, 2) covariance of the small rotations of ``up`` about them, rad^2; height_var: the
    plane's variance along ``up``, m^2 (floor only, else 0); used: floor points or frames fitted;
    rms_m: the fit's residual RMS (floor: distance to the plane; gravity: the track's 3D residual);
    acceleration: the track's acceleration, metres per frame^2 (gravity only, else None)."""

    kind: str
    up: np.ndarray
    origin: np.ndarray | None
    tilt_axes: np.ndarray
    tilt_cov: np.ndarray
    height_var: float
    used: int
    rms_m: float
    acceleration: float | None = None

    @property
    def vertical_std_deg(self) -> float:
        """The vertical's own standard error, degrees (the RMS of its two tilts)."""
        return float(np.degrees(np.sqrt(np.trace(self.tilt_cov))))


def triangulated(rig: Rig, obs: VerticalObservations, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(keys (K,), X (K, 3)): each floor point or frame seen by two or more cameras, triangulated."""
    keys, index = np.unique(obs.key, return_inverse=True)
    xy = undistort_by_camera(rig.cameras, obs.camera, obs.uv)
    X = triangulate_points(R, t, index, obs.camera, xy, len(keys))
    ok = np.all(np.isfinite(X), axis=1)
    return keys[ok], X[ok]


def vertical_fit(rig: Rig, obs: VerticalObservations, R: np.ndarray, t: np.ndarray) -> VerticalFit | None:
    """The floor's plane or the drop's gravity, or None when the observations cannot set it (too
    few points or frames seen by two cameras, no acceleration); :func:`unusable` says why."""
    keys, X = triangulated(rig, obs, R, t)
    if obs.kind == "floor":
        return _floor(X, camera_centers(R, t).mean(0)) if len(X) >= MIN_FLOOR_POINTS else None
    return _drop(keys, X) if len(X) >= MIN_DROP_FRAMES else None


def unusable(rig: Rig, obs: VerticalObservations, R: np.ndarray, t: np.ndarray) -> str:
    """Why :func:`vertical_fit` found no vertical, in words a user can act on."""
    keys, X = triangulated(rig, obs, R, t)
    if obs.kind == "floor":
        return (f"floor.csv: only {len(X)} floor point(s) are seen by two or more cameras, {MIN_FLOOR_POINTS} "
                f"needed (4 or more for the plane's sigma); digitise more floor points, spread over the floor")
    if len(X) < MIN_DROP_FRAMES:
        return (f"drop.csv: only {len(X)} frame(s) of the dropped object are seen by two or more cameras, "
                f"{MIN_DROP_FRAMES} needed; record a longer fall where two cameras see it")
    return ("drop.csv: the object's track shows no clear acceleration (under "
            f"{MIN_ACCELERATION_SE:g} standard errors); drop it from higher, through more frames, or check "
            "that every row is the one falling object")


def unused_warning(rig: Rig, obs: VerticalObservations, R: np.ndarray, t: np.ndarray, frame: str) -> str:
    """The warning for a floor or drop that did not set the world frame: another reference did
    (``frame``), or it could not (:func:`unusable`, and the wand volume's frame stands in)."""
    name = f"{obs.kind}.csv"
    if frame == "static_object":
        return f"{name} is not used: the static object (static.csv) sets the world frame; remove one of them"
    return unusable(rig, obs, R, t) + "; the world frame is the wand volume's (z up from the cameras' image-down)"


def _floor(X: np.ndarray, cameras_centre: np.ndarray) -> VerticalFit:
    centroid = X.mean(0)
    q = X - centroid
    _, _, Vt = np.linalg.svd(q, full_matrices=False)
    up = Vt[2] if (cameras_centre - centroid) @ Vt[2] >= 0 else -Vt[2]
    e1 = Vt[0]
    e2 = np.cross(up, e1)
    u, v, d = q @ e1, q @ e2, q @ up
    dof = len(X) - 3
    s2 = float(d @ d) / dof if dof > 0 else np.nan
    # height at (u, v) after small turns a about e1 and b about e2: v a - u b
    info = np.array([[v @ v, -(u @ v)], [-(u @ v), u @ u]])
    tilt_cov = s2 * np.linalg.pinv(info)
    return VerticalFit("floor", up, centroid, np.stack([e1, e2]), tilt_cov, s2 / len(X), len(X),
                       float(np.sqrt(np.mean(d**2))))


def _drop(frames: np.ndarray, X: np.ndarray) -> VerticalFit | None:
    tau = (frames - frames.mean()).astype(float)
    A = np.stack([np.ones_like(tau), tau, tau**2], axis=1)
    coef, *_ = np.linalg.lstsq(A, X, rcond=None)
    resid = X - A @ coef
    dof = 3 * (len(X) - 3)
    s2 = float(np.sum(resid**2)) / dof
    var_c = s2 * float(np.linalg.inv(A.T @ A)[2, 2])
    accel = 2 * coef[2]
    half = float(np.linalg.norm(coef[2]))
    if half == 0 or half < MIN_ACCELERATION_SE * np.sqrt(var_c):
        return None
    up = -coef[2] / half
    helper = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(up, helper)
    e1 /= np.linalg.norm(e1)
    tilt_cov = np.eye(2) * var_c / half**2  # each component of c across the direction, over its length
    return VerticalFit("drop", up, None, np.stack([e1, np.cross(up, e1)]), tilt_cov, 0.0, len(X),
                       float(np.sqrt(np.mean(np.sum(resid**2, axis=1)))), float(np.linalg.norm(accel)))


def vertical_frame(fit: VerticalFit, R: np.ndarray, gauge: int, volume_origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Rw, tw): ``x_world = Rw x + tw`` with z = ``fit.up``, x the gauge camera's image-right made
    level (its optical axis if it is rolled onto its side), origin the floor's centroid or, for
    gravity, ``volume_origin``."""
    z = fit.up
    x = R[gauge, 0] - z * (R[gauge, 0] @ z)
    if np.linalg.norm(x) < 0.1:
        x = R[gauge, 2] - z * (R[gauge, 2] @ z)
    x = x / np.linalg.norm(x)
    Rw = np.stack([x, np.cross(z, x), z])
    origin = fit.origin if fit.origin is not None else volume_origin
    return Rw, -Rw @ origin


def frame_noise(fit: VerticalFit, Rw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reference's own noise as the world frame's (frame_cov (6, 6): rotation about the world
    axes, radians, then translation, metres; and the point it turns about), for
    calib/solve/uncertainty.py: the tilts of z and, for a floor, its height; the turn about z and
    the origin's place in the plane come from the gauge camera and the points, whose noise the
    poses' propagation carries."""
    axes_world = fit.tilt_axes @ Rw.T  # (2, 3): the tilt axes in world coordinates (in the xy plane)
    cov = np.zeros((6, 6))
    cov[:3, :3] = axes_world.T @ fit.tilt_cov @ axes_world
    cov[5, 5] = fit.height_var
    return cov, np.zeros(3)  # both frames turn about their origin


def details(fit: VerticalFit) -> dict:
    """The world frame's description and details for the result."""
    if fit.kind == "floor":
        return {
            "frame": "floor",
            "description": "the floor's frame: origin at the floor points' centroid, z up along the floor plane's "
            "normal, x along the first camera's image-right made level; metres",
            "floor_points": fit.used,
            "floor_rms_m": fit.rms_m,
            "vertical_std_deg": fit.vertical_std_deg,
            "height_std_m": float(np.sqrt(fit.height_var)),
        }
    return {
        "frame": "gravity",
        "description": "gravity's frame: z up against the dropped object's acceleration, origin at the wand "
        "volume's centroid, x along the first camera's image-right made level; metres",
        "drop_frames": fit.used,
        "drop_fit_rms_m": fit.rms_m,
        "acceleration_m_per_frame2": fit.acceleration,
        "vertical_std_deg": fit.vertical_std_deg,
    }
