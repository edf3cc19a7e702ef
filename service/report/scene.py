"""What the page's 3D rig view draws besides the cameras: the wand's samples in the world, the
single-point tracks, the axis points and the static object's markers, and the volume they fill.

The result holds the cameras only; the samples come from its capture, triangulated with the
result's poses by calib (:func:`wandcal.calib.judge.evaluate.evaluate_capture`). No matplotlib.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.evaluate import evaluate_capture
from wandcal.capture.folder import Capture
from wandcal.capture.result_file import ResultFile
from wandcal.service.report.analysis import aligned_observations

SCENE_FORMAT = "wandcal-scene/1"
# Samples sent to the page: a browser draws 4000 points at once without effort, and a trail that
# dense already shows every gap in the volume; a longer capture is thinned evenly over its frames.
MAX_SAMPLES = 4000
# The volume is the box of the middle 98% of the samples on each axis: a stray triangulation
# (a reflection seen by two cameras) does not stretch it.
VOLUME_PERCENTILES = (1, 99)
DECIMALS = 4  # 0.1 mm in metres: far below the calibration's own error, and a short document


def scene(result: ResultFile, capture: Capture | None) -> dict:
    """The 3D samples of a result's capture (``wandcal-scene/1``), world frame, metres (or the
    result's arbitrary unit).

    Returns:
        ``{"format", "wand": [[x, y, z], ...] (the wand's midpoint per frame, at most
        MAX_SAMPLES), "wand_frames": the number of frames before thinning, "points": single-point
        tracks, "axis": {role: [x, y, z]}, "static_markers": [[x, y, z], ...] (only when the
        world is the static object's frame), "volume": {"min", "max"} or None}``. Without a
        capture every list is empty and the volume None.

    Raises:
        CaptureFormatError: the capture is not the one the result came from.
    """
    empty = {"format": SCENE_FORMAT, "wand": [], "wand_frames": 0, "points": [], "axis": {},
             "static_markers": [], "volume": None}
    if capture is None:
        return empty
    rig, wand, points, axis = aligned_observations(result, capture)
    try:
        found = evaluate_capture(rig, result.R, result.t, wand, points, axis)
    except CalibrationError:  # wand ends that do not label at these poses: the scene without the wand's path
        found = evaluate_capture(rig, result.R, result.t, None, points, axis)
    trail, cloud, axis_pts = found.trajectory, found.points.cloud, found.axis
    world = result.doc.get("world") or {}
    static = rig.static_markers if world.get("frame") == "static_object" and rig.static_markers is not None else None
    samples = np.vstack([trail, cloud])
    volume = None
    if len(samples):
        lo, hi = np.percentile(samples, VOLUME_PERCENTILES, axis=0)
        volume = {"min": _rounded(lo), "max": _rounded(hi)}
    return empty | {
        "wand": _rounded(_thinned(trail)), "wand_frames": len(trail), "points": _rounded(_thinned(cloud)),
        "axis": {k: _rounded(v) for k, v in axis_pts.items()},
        "static_markers": _rounded(static) if static is not None else [], "volume": volume,
    }


def _thinned(points: np.ndarray) -> np.ndarray:
    """At most MAX_SAMPLES of ``points``, evenly spread over them (the frames' order kept)."""
    if len(points) <= MAX_SAMPLES:
        return points
    return points[np.linspace(0, len(points) - 1, MAX_SAMPLES).round().astype(int)]


def _rounded(values) -> list:
    return np.round(np.asarray(values, float), DECIMALS).tolist()
