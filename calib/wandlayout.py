"""A wand's marker layout (rig.json ``wand.markers_m``): checked, and put in the terms the model uses.

A collinear wand of 2-5 markers is described by each marker's position along its axis
(:func:`axial_offsets`): the wand model of ``ba`` places marker k at ``m + o_k d`` for the
frame's midpoint ``m`` and unit direction ``d`` (wandcal.calib.solve.wandmodel), the two-marker
wand being ``o = (-L/2, +L/2)``. A planar wand of 4-5 markers (a T, as Vicon's Active Wand) adds
each marker's offset across the axis in the wand's plane (:func:`plane_offsets`): marker k at
``m + o_k d + q_k e``, with ``e`` the in-plane unit vector normal to ``d``. The axis is always the
line through the two markers farthest apart (the "ends", which start the calibration as a
two-marker wand).
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError

MAX_MARKERS = 5  # the largest commercial wands (Vicon's Active Wand) carry five
MIN_SEPARATION_M = 1e-3  # markers nearer than a marker's own diameter (~1 cm) cannot be told apart;
# 1 mm is far below any real layout, so only a typo or a doubled row is refused
COLLINEAR_TOL_M = 1e-4  # a marker this far off the line through the end markers is off it (0.1 mm: a layout's
# printed precision), so the wand is planar; the same tolerance off the plane makes it three-dimensional
MIN_PLANAR_MARKERS = 4  # three markers off a line have up to four poses in one image (P3P): four pin it


def check_layout(markers: np.ndarray, where: str = "wand.markers_m") -> np.ndarray:
    """The layout (M, 3) metres as float, or a CalibrationError naming ``where`` and what to fix:
    2-5 finite markers, none coinciding, all on one line or (4 or more) in one plane."""
    m = np.asarray(markers, dtype=float)
    if m.ndim != 2 or m.shape[1] != 3 or not 2 <= len(m) <= MAX_MARKERS or not np.all(np.isfinite(m)):
        raise CalibrationError(f"{where} must be 2 to {MAX_MARKERS} finite [x, y, z] marker positions in metres, "
                               f"got {np.shape(markers)}")
    gaps = np.linalg.norm(m[:, None] - m[None], axis=2)
    np.fill_diagonal(gaps, np.inf)
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[i, j] < MIN_SEPARATION_M:
        raise CalibrationError(f"{where}: markers {min(i, j)} and {max(i, j)} coincide ({1000 * gaps[i, j]:.2f} mm "
                               "apart); give each marker's own position")
    if is_planar(m):
        if len(m) < MIN_PLANAR_MARKERS:
            raise CalibrationError(f"{where}: {len(m)} markers off one line ({1000 * off_axis(m).max():.1f} mm off it) "
                                   f"cannot be labelled from one image; a planar wand needs {MIN_PLANAR_MARKERS} or more "
                                   "markers, a collinear one all on a line")
        off = off_plane(m)
        if off.max() > COLLINEAR_TOL_M:
            plane = ", ".join(map(str, sorted([*_extremes(m), int(np.argmax(off_axis(m)))])))
            plane = " and ".join(plane.rsplit(", ", 1))
            raise CalibrationError(f"{where}: marker {int(np.argmax(off))} is {1000 * off.max():.1f} mm off the plane "
                                   f"through markers {plane}; give a collinear or a planar wand's markers")
    return m


def is_planar(markers: np.ndarray) -> bool:
    """Whether a checked layout (M, 3) has a marker off the line through its ends."""
    return bool(off_axis(markers).max() > COLLINEAR_TOL_M)


def off_plane(markers: np.ndarray) -> np.ndarray:
    """(M,) each marker's distance from the plane through the ends and the marker farthest off
    their line, metres."""
    a, b = _extremes(markers)
    c = int(np.argmax(off_axis(markers)))
    n = np.cross(markers[b] - markers[a], markers[c] - markers[a])
    return np.abs((markers - markers[a]) @ (n / np.linalg.norm(n)))


def plane_offsets(markers: np.ndarray) -> np.ndarray:
    """(M, 2) each marker's (along, across) position in the wand's plane, metres: along as
    :func:`axial_offsets`; across on the in-plane unit normal to the axis that points to the
    marker farthest off it (all 0 for a collinear wand)."""
    along = axial_offsets(markers)
    a, b = sorted(_extremes(markers))
    d = (markers[b] - markers[a]) / np.linalg.norm(markers[b] - markers[a])
    v = markers - 0.5 * (markers[a] + markers[b]) - along[:, None] * d
    c = int(np.argmax(np.linalg.norm(v, axis=1)))
    if np.linalg.norm(v[c]) <= COLLINEAR_TOL_M:
        return np.stack([along, np.zeros(len(markers))], axis=1)
    e = v[c] / np.linalg.norm(v[c])
    return np.stack([along, v @ e], axis=1)


def end_markers(markers: np.ndarray) -> tuple[int, int]:
    """The layout indices of the two markers farthest apart, lower first: end 0 and end 1."""
    a, b = _extremes(markers)
    return min(a, b), max(a, b)


def off_axis(markers: np.ndarray) -> np.ndarray:
    """(M,) each marker's distance from the line through the two markers farthest apart, metres."""
    a, b = _extremes(markers)
    d = (markers[b] - markers[a]) / np.linalg.norm(markers[b] - markers[a])
    v = markers - markers[a]
    return np.linalg.norm(v - (v @ d)[:, None] * d, axis=1)


def axial_offsets(markers: np.ndarray) -> np.ndarray:
    """(M,) each marker's position along the wand's axis from the midpoint of its two extreme
    markers, metres, in the layout's order; the axis points from the lower-numbered extreme
    marker to the other."""
    a, b = sorted(_extremes(markers))
    d = (markers[b] - markers[a]) / np.linalg.norm(markers[b] - markers[a])
    return (markers - 0.5 * (markers[a] + markers[b])) @ d


def span(markers: np.ndarray) -> float:
    """The distance between the two markers farthest apart, metres: the wand length."""
    a, b = _extremes(markers)
    return float(np.linalg.norm(markers[b] - markers[a]))


def _extremes(markers: np.ndarray) -> tuple[int, int]:
    gaps = np.linalg.norm(markers[:, None] - markers[None], axis=2)
    i, j = np.unravel_index(np.argmax(gaps), gaps.shape)
    return int(i), int(j)
