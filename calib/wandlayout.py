"""A wand's marker layout (rig.json ``wand.markers_m``): checked, and put in the terms the model uses.

A collinear wand of 2-5 markers is described by each marker's position along its axis
(:func:`axial_offsets`): the wand model of ``ba`` places marker k at ``m + o_k d`` for the
frame's midpoint ``m`` and unit direction ``d`` (wandcal.calib.solve.wandmodel), the two-marker
wand being ``o = (-L/2, +L/2)``.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError

MAX_MARKERS = 5  # the largest commercial wands (Vicon's Active Wand) carry five
MIN_SEPARATION_M = 1e-3  # markers nearer than a marker's own diameter (~1 cm) cannot be told apart;
# 1 mm is far below any real layout, so only a typo or a doubled row is refused
COLLINEAR_TOL_M = 1e-4  # a marker this far off the line through the end markers is off it (0.1 mm: a layout's
# printed precision), so the wand is planar


def check_layout(markers: np.ndarray, where: str = "wand.markers_m") -> np.ndarray:
    """The layout (M, 3) metres as float, or a CalibrationError naming ``where`` and what to fix:
    2-5 finite markers, none coinciding, all on one line (a planar layout such as a T is refused
    for now, naming it)."""
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
    if off_axis(m).max() > COLLINEAR_TOL_M:
        raise CalibrationError(f"{where}: the markers are not on one line ({1000 * off_axis(m).max():.1f} mm off it); "
                               "planar wands (a T) are not supported yet: give a collinear wand's markers")
    return m


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
