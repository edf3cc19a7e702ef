"""A pinhole camera looking through a flat window into a denser medium (air -> glass -> water):
points projected along the refracted ray, and pixels traced to their ray in the medium.

The window (:class:`FlatWindow`) is two parallel planes: its water-side face ``normal @ X ==
distance`` and its air-side face ``thickness`` nearer the camera; ``normal`` (unit) points from the
medium towards the camera. This is OpenPTV's multimedia model with one glass layer (its .ori
file's glass vector is ``normal * distance``, its ptv.par gives n1, n2, n3 and the thickness;
capture/formats/openptv.py converts them). Poses are wandcal's (docs/conventions.md): world->camera
``x_cam = R @ X + t`` in metres, the camera in the air.

Snell's law ``n_air sin(a_air) = n_glass sin(a_glass) = n_water sin(a_water)`` keeps the path in
the plane of the window's normal through the camera centre and the point, so a projection is one
unknown a point: the invariant ``k = n sin(a)``, found by Newton's method from the side where it
converges without overshoot (the radial reach is convex in k).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError

NEWTON_STEPS = 60  # the reach is convex in k and Newton starts above the root: it converges monotonically,
#                    quadratically near it; 60 steps is a cap the iteration stops well before
NEWTON_TOL = 1e-15  # |change of k| at which the iteration has converged (k <= 1: relative machine precision)


@dataclass(frozen=True, eq=False)
class FlatWindow:
    """A camera's flat window into the medium.

    normal: (3,) unit vector, world frame, from the medium towards the camera; distance: metres,
    the water-side face is ``normal @ X == distance``; thickness: metres, the glass between its
    faces (the air-side face is ``normal @ X == distance + thickness``); n_air, n_glass, n_water:
    refractive indices (the camera's medium, the window's, the observed medium's).
    """

    normal: np.ndarray
    distance: float
    thickness: float
    n_air: float = 1.0
    n_glass: float = 1.5
    n_water: float = 1.33

    def __post_init__(self) -> None:
        normal = np.asarray(self.normal, dtype=float).reshape(3)
        length = float(np.linalg.norm(normal))
        if not np.isfinite(length) or length == 0:
            raise CalibrationError(f"a flat window's normal must be a finite non-zero vector, got {self.normal!r}")
        indices = (self.n_air, self.n_glass, self.n_water)
        if not all(np.isfinite(n) and n > 0 for n in indices):
            raise CalibrationError(f"refractive indices must be positive numbers, got {indices!r}")
        if self.n_air > min(self.n_glass, self.n_water):
            # a ray out of a denser camera medium can be reflected whole at the window: not modelled
            raise CalibrationError(f"the camera's medium (n = {self.n_air}) must be the least dense of the three "
                                   f"(glass {self.n_glass}, water {self.n_water}); give n1 <= n2, n3")
        if not (np.isfinite(self.thickness) and self.thickness >= 0 and np.isfinite(self.distance)):
            raise CalibrationError(f"a flat window's distance and thickness must be finite, the thickness not negative "
                                   f"(got {self.distance!r}, {self.thickness!r})")
        object.__setattr__(self, "normal", normal / length)

    @property
    def indices(self) -> np.ndarray:
        """(3,) n_air, n_glass, n_water."""
        return np.array([self.n_air, self.n_glass, self.n_water])


def camera_height(window: FlatWindow, R: np.ndarray, t: np.ndarray) -> float:
    """The camera centre's distance from the window's air-side face, metres (positive: in the air)."""
    C = -R.T @ t
    return float(window.normal @ C - window.distance - window.thickness)


def project_through_window(window: FlatWindow, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Normalised image coordinates (N, 2) of points X (N, 3) in the medium, metres, seen along the
    refracted ray; NaN for a point not in the medium or behind the camera (R (3, 3), t (3,))."""
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    C = -R.T @ t
    n = window.normal
    h_air = float(n @ C) - window.distance - window.thickness
    if h_air <= 0:
        raise CalibrationError(f"the camera centre is {-h_air * 1e3:.1f} mm past the window's air-side face; the "
                               "window's normal must point from the medium towards the camera")
    depth = window.distance - X @ n  # (N,) below the water-side face
    radial = (X - C) - np.outer((X - C) @ n, n)
    r = np.linalg.norm(radial, axis=1)
    heights = np.stack([np.full(len(X), h_air), np.full(len(X), window.thickness), depth], axis=1)
    k = _invariant(heights, r, window.indices)
    sin_air = k / window.n_air
    with np.errstate(invalid="ignore", divide="ignore"):
        e = np.where(r[:, None] > 0, radial / np.where(r > 0, r, 1.0)[:, None], 0.0)
    direction = sin_air[:, None] * e - np.sqrt(1.0 - sin_air ** 2)[:, None] * n  # (N, 3) the ray in the air
    d_cam = direction @ R.T
    with np.errstate(invalid="ignore", divide="ignore"):
        xy = d_cam[:, :2] / d_cam[:, 2:3]
    xy[(depth <= 0) | ~(d_cam[:, 2] > 0)] = np.nan
    return xy


def _invariant(heights: np.ndarray, r: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """(N,) k = n sin(angle) of the refracted path whose legs of heights (N, 3) (air, glass, medium,
    along the normal) reach r (N,) sideways: sum_i h_i k / sqrt(n_i^2 - k^2) = r.

    The reach is increasing and convex in k on [0, n_air), so Newton's method started above the
    root (the air leg alone reaching r) comes down to it monotonically."""
    n2 = indices ** 2
    k = indices[0] * r / np.hypot(r, heights[:, 0])
    for _ in range(NEWTON_STEPS):
        root = np.sqrt(n2[None] - k[:, None] ** 2)  # (N, 3)
        reach = (heights * k[:, None] / root).sum(1)
        slope = (heights * n2[None] / root ** 3).sum(1)
        step = np.where(slope > 0, (reach - r) / np.where(slope > 0, slope, 1.0), 0.0)
        k = np.maximum(k - step, 0.0)
        if not np.nanmax(np.abs(step), initial=0.0) > NEWTON_TOL:
            break
    return k


def trace_into_medium(window: FlatWindow, R: np.ndarray, t: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rays in the medium of normalised image points xy (N, 2): (origins (N, 3) on the
    water-side face, metres; unit directions (N, 3) into the medium). NaN for a pixel whose ray
    does not reach the window."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    C = -R.T @ t
    n = window.normal
    v = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ R  # R^T [x, y, 1], rows
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (n @ C - window.distance - window.thickness) / -(v @ n)
        s = np.where(s > 0, s, np.nan)
    v_glass = _refract(v, n, window.n_air / window.n_glass)
    with np.errstate(invalid="ignore", divide="ignore"):
        s_glass = window.thickness / -(v_glass @ n)
    origin = C + s[:, None] * v + s_glass[:, None] * v_glass
    return origin, _refract(v_glass, n, window.n_glass / window.n_water)


def _refract(v: np.ndarray, normal: np.ndarray, ratio: float) -> np.ndarray:
    """Unit directions v (N, 3) refracted at a plane whose unit normal points back against them,
    ``ratio`` = n_from / n_to (Snell's law in vector form)."""
    cos_in = -(v @ normal)
    sin2_out = ratio ** 2 * (1.0 - cos_in ** 2)
    with np.errstate(invalid="ignore"):
        cos_out = np.sqrt(1.0 - sin2_out)
    return ratio * v + (ratio * cos_in - cos_out)[:, None] * normal


def nearest_to_rays(origin: np.ndarray, direction: np.ndarray, point: np.ndarray, n_points: int) -> np.ndarray:
    """(P, 3) each point's least-squares nearest position to its rays: ray m (origin (M, 3), unit
    direction (M, 3)) belongs to point ``point[m]`` (M,) in [0, n_points); NaN for a point with fewer
    than two rays or parallel ones. Minimises the sum of squared distances from the rays."""
    proj = np.eye(3)[None] - direction[:, :, None] * direction[:, None, :]  # (M, 3, 3) I - d d^T
    A = np.zeros((n_points, 3, 3))
    b = np.zeros((n_points, 3))
    np.add.at(A, point, proj)
    np.add.at(b, point, np.einsum("mij,mj->mi", proj, origin))
    out = np.full((n_points, 3), np.nan)
    ok = (np.bincount(point, minlength=n_points) >= 2) & (np.linalg.cond(A) < 1e12)
    out[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return out
