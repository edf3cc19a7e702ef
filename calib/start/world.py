"""The world frame of a result: the static object's, the axis points', or the wand volume's.

Refinement works in the gauge of one fixed camera. The user's world frame is chosen here, in
this order (docs/conventions.md):
- a static object (L-frame) triangulated with the refined cameras: its own frame, z up;
- axis points (``axis.csv``): the origin point, z along ``+z`` (or x along ``+x``, y along
  ``+y``; with two axes given the first of z, x, y is exact and the other is made orthogonal);
  with one axis only, the next axis (x after z, y after x, z after y) is the first camera's
  image-right direction made orthogonal to it;
- the floor's plane (``floor.csv``) or gravity from a dropped object (``drop.csv``): z up, and
  the floor's centroid or the wand volume's as the origin (:mod:`wandcal.calib.start.vertical`);
- otherwise the wand volume's frame (:func:`volume_frame`): origin at the centroid of the wand
  midpoints (without a wand, of the single-point tracks' points), z up against the cameras'
  mean image-down direction, x along the gauge camera's image-right made level. Its origin
  lies inside the volume the cameras watch, not in a camera's focal plane as a camera's own
  centre would (a DLT export needs that, docs/formats.md); docs/decisions/0009.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.geometry import camera_centers, kabsch, undistort_by_camera, undistort_points
from wandcal.calib.rig import AxisObservations, Rig, StaticObservations, VerticalObservations
from wandcal.calib.start import vertical
from wandcal.calib.start.static import StaticPose
from wandcal.calib.triangulate import triangulate_points

AXIS_ORDER = ("+z", "+x", "+y")  # which given axis is kept exactly when several are
# the cameras agree on "down" when their mean image-down direction is at least this long (a ring of
# upright cameras tilted 60 degrees down still gives 0.5); below it, up is the gauge camera's own
MIN_UP_AGREEMENT = 0.25
# the gauge camera's image-right is used for x while it is at least this far from vertical (sin of
# ~6 degrees); a camera rolled onto its side gives x from its optical axis instead
MIN_LEVEL_RIGHT = 0.1


Reference = AxisObservations | VerticalObservations | None  # what sets the frame besides a static object


def world_frame(rig: Rig, R: np.ndarray, t: np.ndarray, gauge: int, static=None, static_poses=None,
                axis: Reference = None, wand: np.ndarray | None = None, points: np.ndarray | None = None):
    """The map into the user's world frame.

    Args:
        R, t: (N, 3, 3), (N, 3) refined poses in the gauge frame.
        static, static_poses: the static object's blobs and PnP poses, or None.
        axis: :class:`AxisObservations`, or :class:`VerticalObservations` (a floor or a drop), or None.
        points: (T, 3) the single-point tracks' refined points in the gauge frame, or None: the
            wand-only frame's origin when there is no wand.
        wand: (F, 2, 3) the refined wand ends in the gauge frame, or None. The frame must depend
            on nothing but these arguments: the pose uncertainty is propagated into it by
            differentiating this function (calib/solve/uncertainty.py).

    Returns:
        (Rw (3, 3), tw (3,), world): ``x_world = Rw x + tw``, a rigid map (the scale is the
        wand's, or left arbitrary, never invented); ``world`` describes the frame for the result.
    """
    if static_poses is not None and any(isinstance(p, StaticPose) for p in static_poses):
        fit = _static_fit(rig, static, static_poses, R, t)
        if fit is not None:
            Rw, tw, rms, used, scale, rms_scaled = fit
            return Rw, tw, {
                "frame": "static_object",
                "description": "the static object's own frame: its markers_m as given, z up, metres",
                "fit_rms_m": rms,
                "cameras_used": used,
                "marker_scale": scale,
                "scaled_fit_rms_m": rms_scaled,
            }
    if isinstance(axis, AxisObservations) and len(axis):
        fit = _axis_fit(rig, axis, R, t)
        if fit is not None:
            return fit
    Rw, tw, origin = volume_frame(R, t, gauge, wand, points)
    if isinstance(axis, VerticalObservations) and len(axis):
        found = vertical.vertical_fit(rig, axis, R, t)
        if found is not None:
            Rv, tv = vertical.vertical_frame(found, R, gauge, -Rw.T @ tw)
            return Rv, tv, vertical.details(found)
    cam = rig.cameras[gauge].id
    return Rw, tw, {
        "frame": "wand_volume",
        "description": f"the wand volume's frame: origin at the centroid of the {origin}, z up (against the "
        f"cameras' mean image-down direction), x along camera {cam!r}'s image-right made level, y = z x x; metres",
        "origin": origin,
        "x_camera": cam,
    }


def volume_frame(R: np.ndarray, t: np.ndarray, gauge: int, wand: np.ndarray | None = None,
                 points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, str]:
    """The wand volume's frame: a function of the poses and the wand (or points) alone, smooth
    away from the two fallbacks' thresholds.

    - origin: the centroid of the wand midpoints; without a wand, the median of ``points``; without either,
      the cameras' centroid moved along their mean optical axis by their RMS spread (a point the
      cameras look towards);
    - z: up, against the mean of the cameras' image-down directions (cameras stand upright); if
      they disagree (mean shorter than ``MIN_UP_AGREEMENT``), against the gauge camera's;
    - x: the gauge camera's image-right made orthogonal to z (its optical axis if it is rolled
      onto its side); y = z x x.

    Args:
        R, t: (N, 3, 3), (N, 3) poses in the gauge frame, world->camera.
        wand: (F, 2, 3) wand ends in the gauge frame, or None / empty.
        points: (T, 3) single-point tracks' points in the gauge frame, or None / empty.

    Returns:
        (Rw (3, 3), tw (3,), origin): ``x_world = Rw x + tw``; ``origin`` names what the origin
        is the centroid of.
    """
    if wand is not None and len(wand):
        centre, origin = np.asarray(wand, dtype=float).mean(axis=(0, 1)), "wand midpoints"
    elif points is not None and len(points):
        # the median: a few points triangulated from nearly parallel rays lie far off, and would
        # carry a mean with them (and the whole rig's coordinates) to the horizon
        centre, origin = np.median(np.asarray(points, dtype=float), axis=0), "single-point tracks' points (median)"
    else:
        C = camera_centers(R, t)
        spread = float(np.sqrt(np.mean(np.sum((C - C.mean(0)) ** 2, axis=1))))
        centre, origin = C.mean(0) + R[:, 2, :].mean(0) * spread, "cameras, moved along their mean optical axis"
    up = -R[:, 1, :].mean(0)  # rows of R are the camera axes in the gauge frame; row 1 is image-down
    if np.linalg.norm(up) < MIN_UP_AGREEMENT:
        up = -R[gauge, 1]
    z = up / np.linalg.norm(up)
    x = R[gauge, 0] - z * (R[gauge, 0] @ z)
    if np.linalg.norm(x) < MIN_LEVEL_RIGHT:
        x = R[gauge, 2] - z * (R[gauge, 2] @ z)
    x /= np.linalg.norm(x)
    Rw = np.stack([x, np.cross(z, x), z])  # rows: the world axes in the gauge frame
    return Rw, -Rw @ centre, origin


def apply(Rw: np.ndarray, tw: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray):
    """Poses and points under ``x_world = Rw x + tw``: (R, t, points) in the world frame."""
    # x_world = Rw x + tw  =>  x_cam = R Rw^T (x_world - tw) + t
    R_new = R @ Rw.T
    t_new = t - np.einsum("nij,j->ni", R_new, tw)
    return R_new, t_new, points @ Rw.T + tw


def _static_fit(rig: Rig, static: StaticObservations, static_poses, R, t):
    """Triangulate the identified static markers with the refined poses and fit the rigid map to
    their known coordinates. Returns (Rw, tw, rms_m, camera ids, the scale of a similarity fit
    (markers over triangulated: the wand's scale against the markers'), that fit's rms_m) or None."""
    markers = rig.static_markers
    if markers is None:
        return None
    usable = [c for c, p in enumerate(static_poses) if isinstance(p, StaticPose)]
    unique = [c for c in usable if static_poses[c].unique]
    for cams in ([unique] if len(unique) >= 2 else []) + [usable]:
        if len(cams) < 2:
            continue
        point, camera, xy = _static_views(rig, static, static_poses, cams)
        X = triangulate_points(R, t, point, camera, xy, len(markers))
        ok = np.all(np.isfinite(X), axis=1)
        if ok.sum() < 3:
            continue
        Rw, tw, _ = kabsch(X[ok], markers[ok])
        rms = float(np.sqrt(np.mean(np.sum((X[ok] @ Rw.T + tw - markers[ok]) ** 2, 1))))
        # the same fit with a scale: a wand length that disagrees with the markers' shows as one
        Rs, ts, scale = kabsch(X[ok], markers[ok], scale=True)
        rms_scaled = float(np.sqrt(np.mean(np.sum((scale * X[ok] @ Rs.T + ts - markers[ok]) ** 2, 1))))
        return Rw, tw, rms, [rig.cameras[c].id for c in cams], scale, rms_scaled
    return None


def _static_views(rig: Rig, static: StaticObservations, static_poses, cams: list[int]):
    """(marker index (K,), camera index (K,), normalised xy (K, 2)) of the identified static blobs."""
    point, camera, xy = [], [], []
    for c in cams:
        point.append(static_poses[c].labels)
        camera.append(np.full(len(static_poses[c].labels), c))
        xy.append(undistort_points(rig.cameras[c], static.for_camera(c)))
    return np.concatenate(point), np.concatenate(camera), np.concatenate(xy)


def static_fit_expectation(rig: Rig, static: StaticObservations, static_poses, R: np.ndarray, t: np.ndarray,
                           cameras_used: list[str]) -> dict | None:
    """What the static fit's RMS would be if the static blobs' noise alone moved the triangulated
    markers, from the blobs' own reprojection residuals (2K - 3M degrees of freedom, ~50 on an
    8-camera rig, against the fit's 3M - 6 = 6 for an L-frame of 4 markers).

    Returns {"static_blob_rms_px": the blobs' reprojection RMS against their triangulated markers
    (corrected for the fitted points), "expected_fit_rms_m": that noise's fit RMS}, or None when
    the blobs leave no degree of freedom. calib/solve/uncertainty.py takes the frame's noise from this
    when the fit agrees with it, and from the fit's own RMS when the markers sit off their given
    coordinates (a mis-measured or bent L-frame)."""
    ids = [c.id for c in rig.cameras]
    cams = [ids.index(c) for c in cameras_used]
    point, camera, xy = _static_views(rig, static, static_poses, cams)
    if rig.static_markers is None:
        return None
    M = len(rig.static_markers)
    X = triangulate_points(R, t, point, camera, xy, M)
    keep = np.all(np.isfinite(X[point]), axis=1)
    point, camera, xy = point[keep], camera[keep], xy[keep]
    used = np.unique(point)
    dof = 2 * len(point) - 3 * len(used)
    if dof < 1 or len(used) < 3:
        return None
    Xc = np.einsum("kij,kj->ki", R[camera], X[point]) + t[camera]
    proj = Xc[:, :2] / Xc[:, 2:]
    f = np.array([[c.K[0, 0], c.K[1, 1]] for c in rig.cameras])[camera]
    rms_px = float(np.sqrt(np.sum(((xy - proj) * f) ** 2) / dof))
    # each marker's information: sum over its views of J^T J, J the projection's 2x3 derivative in
    # pixels, over the blobs' variance
    x, y, z = proj[:, 0], proj[:, 1], Xc[:, 2]
    d = np.zeros((len(point), 2, 3))
    d[:, 0, 0] = d[:, 1, 1] = 1 / z
    d[:, 0, 2], d[:, 1, 2] = -x / z, -y / z
    J = f[:, :, None] * np.einsum("kab,kbc->kac", d, R[camera])
    info = np.zeros((M, 3, 3))
    np.add.at(info, point, np.einsum("kai,kaj->kij", J, J) / rms_px**2)
    spread = sum(float(np.trace(np.linalg.inv(info[m]))) for m in used)  # sum of the markers' variances
    n = len(used)
    return {"static_blob_rms_px": rms_px, "expected_fit_rms_m": float(np.sqrt(spread / n * (3 * n - 6) / (3 * n)))}


def axis_points(rig: Rig, axis: AxisObservations, R: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """Triangulate each axis role seen by two or more cameras: {role: (3,) point}."""
    roles = sorted(set(axis.role))
    point = np.array([roles.index(r) for r in axis.role])
    xy = undistort_by_camera(rig.cameras, axis.camera, axis.uv)
    X = triangulate_points(R, t, point, axis.camera, xy, len(roles))
    return {r: X[k] for k, r in enumerate(roles) if np.all(np.isfinite(X[k]))}


def _axis_fit(rig: Rig, axis: AxisObservations, R: np.ndarray, t: np.ndarray):
    pts = axis_points(rig, axis, R, t)
    given = [a for a in AXIS_ORDER if a in pts]
    if "origin" not in pts or not given:
        return None
    origin = pts["origin"]
    unit = {a: (pts[a] - origin) / np.linalg.norm(pts[a] - origin) for a in given}
    first = given[0]
    nxt = {"+z": "+x", "+x": "+y", "+y": "+z"}[first]
    if nxt in unit:
        second = unit[nxt]
    elif len(given) > 1:
        # the third axis given: the second follows from it by the right-hand rule
        third = unit[given[1]]
        second = np.cross(third, unit[first])
    else:
        second = R[0][0]  # the first camera's image-right direction, in the gauge frame
    second = second - unit[first] * (second @ unit[first])
    second /= np.linalg.norm(second)
    third = np.cross(unit[first], second)
    # rows of Rw are the world axes expressed in the gauge frame
    axes = {first: unit[first], nxt: second, {"+z": "+y", "+x": "+z", "+y": "+x"}[first]: third}
    Rw = np.stack([axes["+x"], axes["+y"], axes["+z"]])
    tw = -Rw @ origin
    residual = {a: float(np.linalg.norm(np.cross(unit[a], axes[a]))) for a in given}
    return Rw, tw, {
        "frame": "axis",
        "description": "origin at the axis origin point; " + ", ".join(f"{a} towards its axis point" for a in given)
        + " (the first exactly, the rest made orthogonal); metres",
        "axes_given": given,
        "axis_misalignment_rad": residual,
    }
