"""Judge fixed cameras against a capture: residuals, wand lengths, point tracks.

The report draws these for the capture a result was made from (:func:`evaluate_capture`: what a
report needs that a result does not hold, computed once); ``wandcal check`` judges each camera
against a fresh capture with :mod:`wandcal.calib.judge.bumps`. Nothing here moves a camera: the
poses are taken as given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.quality import OUTLIER_SIGMAS, outlier_mask
from wandcal.calib.observations import WandPairs, point_tracks
from wandcal.calib.rig import AxisObservations, PointObservations, Rig, WandObservations
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.start.world import axis_points
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

MAD_TO_SIGMA = 1.4826  # the MAD of Gaussian lengths times this is their standard deviation


@dataclass(frozen=True, eq=False)
class WandEvaluation:
    """Every labelled wand observation with the given poses.

    camera: (M,) camera index; frame: (M,) capture frame number; end: (M,) 0 or 1;
    uv: (M, 2) the raw pixel observed; residual_px: (M, 2) projected minus observed, in pixels of
    the undistorted image (normalised residual times the focal length); outlier: (M,) bool, more
    than :data:`wandcal.calib.judge.quality.OUTLIER_SIGMAS` robust sigmas; frames: (F,) frame numbers of the
    frames at least two cameras saw; wand_length: (F,) metres, each end triangulated on its own;
    dropped: camera-frames left out (``one_blob``, ``extra_blobs``).
    """

    camera: np.ndarray
    frame: np.ndarray
    end: np.ndarray
    uv: np.ndarray
    residual_px: np.ndarray
    outlier: np.ndarray
    frames: np.ndarray
    wand_length: np.ndarray
    dropped: dict

    def error_px(self) -> np.ndarray:
        """(M,) residual magnitudes, pixels."""
        return np.linalg.norm(self.residual_px, axis=1)


def labelled_pairs(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations) -> WandPairs:
    """The capture's wand ends (:func:`wandcal.calib.start.markerlabels.end_pairs`: a two-marker
    wand's two-blob camera-frames, a multi-marker wand's end markers) ordered consistently, by the
    given poses."""
    pairs = end_pairs(rig, wand)
    return label_ends(R, t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]


def evaluate_wand(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations) -> WandEvaluation:
    """Triangulate every wand frame with the given poses and measure each observation's residual.

    Args:
        rig: the cameras (intrinsics) and wand length.
        R, t: (N, 3, 3), (N, 3) world->camera poses, metres.
        wand: raw wand blobs of a capture.
    """
    return _evaluated_pairs(rig, R, t, labelled_pairs(rig, R, t, wand))[0]


def _evaluated_pairs(rig: Rig, R: np.ndarray, t: np.ndarray, pairs: WandPairs) -> tuple[WandEvaluation, np.ndarray]:
    """The labelled pairs' evaluation, and (2F, 3) their ends triangulated (NaN where fewer than
    two cameras saw one), world frame, metres."""
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames))
    focal = np.array([c.focal for c in rig.cameras])
    residual = reprojection_errors(R, t, point, camera, xy, X) * focal[camera]
    ok = np.all(np.isfinite(residual), axis=1)
    ends = X.reshape(-1, 2, 3)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    seen = np.isfinite(length)
    uv = np.concatenate([pairs.uv[:, 0], pairs.uv[:, 1]])
    err = np.linalg.norm(residual[ok], axis=1)
    return WandEvaluation(
        camera=camera[ok], frame=pairs.frames[point[ok] // 2], end=point[ok] % 2, uv=uv[ok], residual_px=residual[ok],
        outlier=outlier_mask(err) if len(err) else np.zeros(0, bool), frames=pairs.frames[seen],
        wand_length=length[seen], dropped=dict(pairs.dropped),
    ), X


@dataclass(frozen=True, eq=False)
class PointEvaluation:
    """Single-point tracks triangulated with given poses: cloud (T, 3) the points, world frame;
    per observation camera (Q,) index, uv (Q, 2) raw pixels, residual_px (Q, 2) projected minus
    observed, pixels, and outlier (Q,) bool, judged among all the rig's point residuals."""

    cloud: np.ndarray
    camera: np.ndarray
    uv: np.ndarray
    residual_px: np.ndarray
    outlier: np.ndarray


@dataclass(frozen=True, eq=False)
class CaptureEvaluation:
    """A capture's observations judged with a result's poses: what a report draws that the result
    does not hold.

    wand: every labelled wand observation's residual and each frame's length (None without a
    wand); trajectory: (T, 3) the wand's midpoint in each frame two cameras saw, world, and
    trajectory_frames: (T,) their frame numbers; points: the single-point tracks'; axis:
    {role: (3,)} the axis points triangulated, world.
    """

    wand: WandEvaluation | None
    trajectory: np.ndarray
    trajectory_frames: np.ndarray
    points: PointEvaluation
    axis: dict[str, np.ndarray]

    def wand_frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(F,) frame numbers, (F,) wand lengths in metres and (F,) bool: frames with an outlier
        observation or whose length is OUTLIER_SIGMAS robust sigmas off the median."""
        ev = self.wand
        if ev is None or not len(ev.frames):
            return np.zeros(0, int), np.zeros(0), np.zeros(0, bool)
        length = ev.wand_length
        dev = np.abs(length - np.median(length))
        sigma = MAD_TO_SIGMA * np.median(dev)
        bad = dev > OUTLIER_SIGMAS * max(sigma, 1e-12)
        bad |= np.isin(ev.frames, ev.frame[ev.outlier])
        return ev.frames, length, bad


def evaluate_capture(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations | None,
                     points: PointObservations | None = None, axis: AxisObservations | None = None) -> CaptureEvaluation:
    """Judge a capture's observations with fixed poses, labelling the wand ends once
    (:func:`labelled_pairs`): each observation's residual, the wand's path and lengths, the point
    tracks and axis points triangulated.

    Args:
        rig: the cameras (intrinsics), wand length (None: the wand is not judged) and static object.
        R, t: (N, 3, 3), (N, 3) world->camera poses, metres.
        wand, points, axis: the capture's raw observations, camera indices in ``rig`` order.

    Raises:
        CalibrationError: the wand ends cannot be labelled at these poses.
    """
    ev, trajectory, frames = None, np.zeros((0, 3)), np.zeros(0, int)
    if rig.wand_length is not None and wand is not None and len(wand):
        pairs = labelled_pairs(rig, R, t, wand)
        ev, X = _evaluated_pairs(rig, R, t, pairs)
        mid = X.reshape(-1, 2, 3).mean(axis=1)
        ok = np.all(np.isfinite(mid), axis=1)
        trajectory, frames = mid[ok], pairs.frames[ok]
    axis_pts = axis_points(rig, axis, R, t) if axis is not None and len(axis.role) else {}
    return CaptureEvaluation(ev, trajectory, frames, evaluate_points(rig, R, t, points),
                             {str(k): v for k, v in axis_pts.items()})


def evaluate_points(rig: Rig, R: np.ndarray, t: np.ndarray, points: PointObservations | None) -> PointEvaluation:
    """Single-point tracks triangulated with the given poses, and each observation's residual."""
    if points is None or not len(points):
        empty2 = np.zeros((0, 2))
        return PointEvaluation(np.zeros((0, 3)), np.zeros(0, int), empty2, empty2,
                               outlier_mask(np.linalg.norm(empty2, axis=1)))
    tracks = point_tracks(rig, points)
    X = triangulate_points(R, t, tracks.track, tracks.camera, tracks.xy, tracks.n_tracks)
    focal = np.array([c.focal for c in rig.cameras])
    res = reprojection_errors(R, t, tracks.track, tracks.camera, tracks.xy, X) * focal[tracks.camera]
    ok = np.all(np.isfinite(res), axis=1)
    cloud = X[np.all(np.isfinite(X), axis=1)]
    return PointEvaluation(cloud, tracks.camera[ok], tracks.uv[ok], res[ok], outlier_mask(np.linalg.norm(res[ok], axis=1)))
