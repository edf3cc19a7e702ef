"""The injectors of bench/real_faults.py: each returns a real session with one fault in its inputs
(rig.json's intrinsics, a camera's samples shifted in time, turned after a knock, made noisier; the
wand's length; a subsample), the truth known. bench/real_faults.py's table says what each fault is
and how it is scored; its names are importable from there too.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from wandcal.calib.geometry import distort_points, rotvec_to_matrix, undistort_points
from wandcal.calib.rig import PointObservations, WandObservations

if TYPE_CHECKING:
    from bench.real_faults import Session

PRINCIPAL_SHIFT = 0.02  # of the image's width: 51 px on Brown's 2560 px, 13 px on Ushichka's 640
K1_WHERE_NONE = -0.15  # "k1 off" on a lens rig.json gives none: a moderate barrel distortion
NOISE_FACTOR = 3.0  # the camera's noise in all, against its own
SUBSAMPLE_SHARE = 0.6


def _with_camera(session: Session, c: int, **changes) -> Session:
    cams = list(session.rig.cameras)
    cams[c] = replace(cams[c], **changes)
    return replace(session, rig=replace(session.rig, cameras=tuple(cams)))


def with_focal(session: Session, c: int, factor: float) -> Session:
    """rig.json gives camera c ``factor`` times its focal length (the images unchanged)."""
    K = session.rig.cameras[c].K.copy()
    K[0, 0] *= factor
    K[1, 1] *= factor
    return _with_camera(session, c, K=K)


def without_k1(session: Session, c: int) -> Session:
    """rig.json leaves camera c's k1 out (0), or gives it :data:`K1_WHERE_NONE` where it had none."""
    dist = np.array(session.rig.cameras[c].dist, float)
    dist[0] = 0.0 if abs(dist[0]) > 1e-9 else K1_WHERE_NONE
    return _with_camera(session, c, dist=dist)


def with_principal(session: Session, c: int, share: float = PRINCIPAL_SHIFT) -> Session:
    """rig.json moves camera c's principal point by ``share`` of its width, right and down."""
    cam = session.rig.cameras[c]
    K = cam.K.copy()
    K[0, 2] += share * cam.width
    K[1, 2] += share * cam.width
    return _with_camera(session, c, K=K)


def _shift_rows(frame: np.ndarray, uv: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """One camera's samples (frame (B,), uv (B, 2); one or two blobs a frame) as a camera
    ``offset`` frames late would record them (docs/result-format.md's sign: its frame k exposed
    at the others' k + offset): at frame k the blobs of time k + offset, linear between its own
    samples at the frames around it (each blob paired with the nearer one of the next frame);
    frames without both neighbours are left out."""
    by_frame: dict[int, np.ndarray] = defaultdict(list)
    for f, p in zip(frame.tolist(), uv):
        by_frame[f].append(p)
    frames_out, uv_out = [], []
    lo_shift = int(np.floor(-offset))
    w = -offset - lo_shift  # time k + offset lies between frames k - lo_shift - 1 and k - lo_shift
    for k in sorted(by_frame):
        a, b = by_frame.get(k - lo_shift - 1), by_frame.get(k - lo_shift)
        if w == 0:
            blobs = [np.asarray(p) for p in by_frame.get(k - lo_shift, [])]
        elif a is None or b is None or len(a) != len(b):
            continue
        else:
            blobs = []
            for p in b:
                q = min(a, key=lambda q: float(np.linalg.norm(np.asarray(q) - p)))
                blobs.append((1 - w) * np.asarray(p) + w * np.asarray(q))  # w of the way back towards frame k-lo-1
        for p in blobs:
            frames_out.append(k)
            uv_out.append(p)
    return np.array(frames_out, np.int64), np.array(uv_out, float).reshape(-1, 2)


def _replace_rows(obs, c: int, frame: np.ndarray, uv: np.ndarray):
    other = obs.camera != c
    merged = {"frame": np.concatenate([obs.frame[other], frame]),
              "camera": np.concatenate([obs.camera[other], np.full(len(frame), c)]),
              "uv": np.concatenate([obs.uv[other], uv])}
    if isinstance(obs, PointObservations):
        return PointObservations(**merged, point=None)
    return WandObservations(**merged)


def late(session: Session, c: int, offset: float) -> Session:
    """Camera c ``offset`` frames late (negative: early; docs/result-format.md): its wand (and a
    moving point's) samples at frame k are those of time k + offset (:func:`_shift_rows`). Only frames the shifted camera
    still has in the original's range are kept."""
    out = session
    if len(session.wand):
        mine = session.wand.camera == c
        f, uv = _shift_rows(session.wand.frame[mine], session.wand.uv[mine], offset)
        out = replace(out, wand=_replace_rows(session.wand, c, f, uv))
    if session.moving_points and session.points is not None:
        mine = session.points.camera == c
        f, uv = _shift_rows(session.points.frame[mine], session.points.uv[mine], offset)
        out = replace(out, points=_replace_rows(session.points, c, f, uv))
    return out


def observations_of(session: Session) -> list[tuple[str, object]]:
    """(name, observations) of the session's wand and points, those it has."""
    return [(name, obs) for name in ("wand", "points") if (obs := getattr(session, name)) is not None and len(obs)]


def timed_observations(session: Session) -> list[tuple[str, object]]:
    """(name, observations) of the session's samples that have a time: its wand's, and its point
    tracks' where they are one moving marker (static background points are digitised once)."""
    timed: list[tuple[str, object]] = [("wand", session.wand)] if len(session.wand) else []
    if session.moving_points and session.points is not None:
        timed.append(("points", session.points))
    return timed


def rebuilt(obs, kept: np.ndarray | None = None, *, camera: np.ndarray | None = None):
    """Observations of obs's own type (wand or points) with the rows ``kept`` (all by default) and
    the cameras ``camera`` (obs's own by default; rows as obs's)."""
    kept = np.ones(len(obs.frame), bool) if kept is None else kept
    camera = obs.camera if camera is None else camera
    if isinstance(obs, PointObservations):
        return PointObservations(obs.frame[kept], camera[kept], obs.uv[kept],
                                 point=None if obs.point is None else obs.point[kept])
    return WandObservations(obs.frame[kept], camera[kept], obs.uv[kept])


def _rotated(cam, uv: np.ndarray, Rk: np.ndarray) -> np.ndarray:
    """(B, 2) raw pixels uv of camera ``cam`` after it turned by Rk (camera frame): each ray
    undistorted, rotated, projected and distorted again."""
    xy = undistort_points(cam, uv)
    ray = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ Rk.T
    return distort_points(cam, ray[:, :2] / ray[:, 2:])


def knock_frame(obs, c: int) -> float:
    """Where camera c is knocked: the middle of its frames (obs: its wand's or moving point's
    observations) that another camera sees too, those a calibration can use (all of its frames
    where no other camera shares one). Brown's cameras have blobs in 28-40 frames, of which only
    8-24 are shared: the middle of all of them (frame 15-70) put the knock before every shared
    frame but one, so that the wand's frames were all turned against the background points' pose
    and nothing moved within the capture (decision 0067)."""
    mine = obs.camera == c
    shared = mine & np.isin(obs.frame, obs.frame[~mine])
    return float(np.median(obs.frame[shared if shared.any() else mine]))


def knocked(session: Session, c: int, degrees: float, seed: int) -> Session:
    """Camera c knocked by ``degrees`` about a random axis after the middle of its wand frames (or
    of its moving point's) that another camera sees too (:func:`knock_frame`): its later samples
    seen through the turned camera. Static background points (digitised once) keep the pose before."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    cam = session.rig.cameras[c]
    out = session
    at = None
    for name, obs in timed_observations(session):
        mine = obs.camera == c
        if at is None:
            at = knock_frame(obs, c)
        after = mine & (obs.frame > at)
        uv = obs.uv.copy()
        uv[after] = _rotated(cam, obs.uv[after], Rk)
        moved = PointObservations(obs.frame, obs.camera, uv, point=obs.point) if name == "points" else \
            WandObservations(obs.frame, obs.camera, uv)
        out = replace(out, **{name: moved})
    return out


def noisy(session: Session, c: int, noise_px: float, seed: int, factor: float = NOISE_FACTOR) -> Session:
    """Camera c's observations (wand and points) with Gaussian noise added per axis so that its
    noise in all is ``factor`` times its own ``noise_px``."""
    rng = np.random.default_rng(seed)
    extra = noise_px * np.sqrt(factor**2 - 1)
    out = session
    for name, obs in observations_of(session):
        uv = obs.uv.copy()
        mine = obs.camera == c
        uv[mine] += rng.normal(0, extra, (int(mine.sum()), 2))
        changed = PointObservations(obs.frame, obs.camera, uv, point=obs.point) if name == "points" else \
            WandObservations(obs.frame, obs.camera, uv)
        out = replace(out, **{name: changed})
    return out


def wand_off(session: Session, factor: float) -> Session:
    """rig.json gives the wand ``factor`` times its length."""
    return replace(session, rig=replace(session.rig, wand_length=session.rig.wand_length * factor))


def subsample(session: Session, seed: int, share: float = SUBSAMPLE_SHARE) -> Session:
    """A random ``share`` of the wand's frames and of the points' frames (each a track)."""
    rng = np.random.default_rng(seed)
    out = session
    for name, obs in observations_of(session):
        frames = np.unique(obs.frame)
        kept = np.isin(obs.frame, frames[rng.random(len(frames)) < share])
        changed = PointObservations(obs.frame[kept], obs.camera[kept], obs.uv[kept],
                                    point=None if obs.point is None else obs.point[kept]) if name == "points" else \
            WandObservations(obs.frame[kept], obs.camera[kept], obs.uv[kept])
        out = replace(out, **{name: changed})
    return out
