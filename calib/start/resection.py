"""Resection of one camera against the points that cameras already placed triangulate: wand
ends (whose order in the new camera is unknown: both matchings are candidates and RANSAC keeps
the right one) and single-point tracks.

The work is capped: a subsample of frames and tracks, each triangulated by at most a few of the
earliest-placed cameras that see it.
"""

from __future__ import annotations

import cv2
import numpy as np

from wandcal.calib.errors import Failure
from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.start.chain import Views, spread
from wandcal.calib.start.labels import flatten, labelled_ends
from wandcal.calib.triangulate import triangulate_points

MAX_RESECT_FRAMES = 100  # wand frames per resection (400 candidate matches): enough for a start
MAX_RESECT_TRACKS = 300  # point tracks per resection
MAX_TRIANGULATING_VIEWS = 3  # placed cameras that triangulate a point: enough for a start, and cheap to label
MIN_RESECT_POINTS = 12  # PnP has six unknowns; twice as many points let RANSAC reject wrong matchings
RESECT_THRESHOLD_PX = 4.0  # a start tolerates a few pixels
RESECT_CONFIDENCE = 0.9999
RESECT_ITERATIONS = 2000
UNPLACED = np.iinfo(np.int64).max


def placed_points(
    pairs: WandPairs, points: PointTracks | None, views: Views, R: np.ndarray, t: np.ndarray, rank: np.ndarray, c: int,
    wand_length: float | None, *, placed_views: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points the placed cameras triangulate that camera c sees (capped subsamples).

    Args:
        pairs, points, views: the observations (normalised coordinates) and their tables.
        R: (N, 3, 3), t: (N, 3) poses; only placed cameras' are used.
        rank: (N,) order in which the cameras were placed, ``UNPLACED`` for the others.
        c: the camera.
        wand_length: metres, to settle two-view wand frames (:func:`wandcal.calib.start.labels.label_ends`), or None.
        placed_views: how many placed cameras see each wand frame (F,) and track (T,), when the
            caller keeps the counts (else counted here).

    Returns:
        Wand ends (S, 2, 3) metres with c's blobs of those frames (S, 2, 2) in arbitrary order,
        and track points (K, 3) metres with c's observations (K, 2); finite points only.
    """
    placed = rank != UNPLACED
    seen_w, seen_t = views.wand >= 0, views.track >= 0
    views_w, views_t = placed_views if placed_views is not None else (seen_w[:, placed].sum(1), seen_t[:, placed].sum(1))
    frames = spread(np.flatnonzero(seen_w[:, c] & (views_w >= 2)), MAX_RESECT_FRAMES)
    ends = _triangulate_ends(pairs, views.wand[frames], R, t, rank, wand_length)
    ends_xy = pairs.xy[views.wand[frames, c]]
    keep = np.all(np.isfinite(ends), axis=(1, 2))
    tracks = spread(np.flatnonzero(seen_t[:, c] & (views_t >= 2)), MAX_RESECT_TRACKS)
    if points is None or len(tracks) == 0:  # no tracks without points (camera_views)
        return ends[keep], ends_xy[keep], np.zeros((0, 3)), np.zeros((0, 2))
    local, rows = _first_views(views.track[tracks], rank)
    X = triangulate_points(R, t, local, points.camera[rows], points.xy[rows], len(tracks))
    xy = points.xy[views.track[tracks, c]]
    ok = np.all(np.isfinite(X), axis=1)
    return ends[keep], ends_xy[keep], X[ok], xy[ok]


def resect_camera(
    ends: np.ndarray, ends_xy: np.ndarray, X: np.ndarray, xy: np.ndarray, focal_px: float
) -> tuple[np.ndarray, np.ndarray] | Failure:
    """Camera pose (R (3, 3), t (3,)) from :func:`placed_points`' output: P3P inside RANSAC on
    both matchings of every wand frame's ends and on the tracks, then Levenberg-Marquardt on the
    inliers. (SQPnP on each RANSAC sample, the resection this replaced, was four times slower for the
    same start.)"""
    have = 2 * len(ends) + len(X)
    if have < MIN_RESECT_POINTS:
        return Failure(f"resection: {have} triangulated points, {MIN_RESECT_POINTS} needed")
    W = np.ascontiguousarray(np.concatenate([ends[:, 0], ends[:, 1], ends[:, 0], ends[:, 1], X]), dtype=np.float64)
    img = np.concatenate([ends_xy[:, 0], ends_xy[:, 1], ends_xy[:, 1], ends_xy[:, 0], xy])
    img = np.ascontiguousarray(img, dtype=np.float64).reshape(-1, 1, 2)
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        W, img, np.eye(3), None, iterationsCount=RESECT_ITERATIONS, reprojectionError=RESECT_THRESHOLD_PX / focal_px,
        confidence=RESECT_CONFIDENCE, flags=cv2.SOLVEPNP_AP3P,
    )
    found = 0 if inliers is None or not ok else len(inliers)
    if found < MIN_RESECT_POINTS:
        return Failure(f"resection: only {found} points fit one pose, {MIN_RESECT_POINTS} needed")
    inl = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(W[inl], img[inl], np.eye(3), None, rvec, tvec)
    return rotvec_to_matrix(rvec), np.asarray(tvec, dtype=float).ravel()


def _triangulate_ends(
    pairs: WandPairs, table: np.ndarray, R: np.ndarray, t: np.ndarray, rank: np.ndarray, wand_length: float | None
) -> np.ndarray:
    """(S, 2, 3) wand ends of the frames whose rows of ``views.wand`` are ``table`` (S, N),
    triangulated by placed cameras after ordering their ends consistently; metres."""
    if len(table) == 0:
        return np.zeros((0, 2, 3))
    local, rows = _first_views(table, rank)
    sub = WandPairs(local, pairs.camera[rows], pairs.xy[rows], pairs.uv[rows], np.arange(len(table)))
    labelled, _, ends = labelled_ends(R, t, sub, rank != UNPLACED, wand_length)
    if ends is not None and len(labelled) == len(sub):  # the labelling's own triangulation of these pairs
        return ends
    point, camera, xy = flatten(labelled)
    return triangulate_points(R, t, point, camera, xy, 2 * len(table)).reshape(-1, 2, 3)


def _first_views(table: np.ndarray, rank: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each row of ``table`` (S, N) (observation indices, -1 where unseen), the observations
    of the first-placed cameras that see it, at most ``MAX_TRIANGULATING_VIEWS``: returns their
    row of the table (K,) and observation index (K,)."""
    key = np.where(table >= 0, rank[None, :], UNPLACED)
    cols = np.argsort(key, axis=1, kind="stable")[:, :MAX_TRIANGULATING_VIEWS]
    obs = np.take_along_axis(table, cols, axis=1)
    use = np.take_along_axis(key, cols, axis=1) != UNPLACED
    local = np.broadcast_to(np.arange(len(table))[:, None], obs.shape)[use]
    return local, obs[use]
