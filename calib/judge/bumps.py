"""Did a camera of a calibrated rig move? Each camera judged against a fresh capture with the
result's poses held (``wandcal check``; bump detection, as commercial mocap has it).

What a camera is judged on is every point of the capture that two other cameras triangulate:
the wand's end markers (a two-marker wand's, or a multi-marker or planar wand's ends,
:func:`wandcal.calib.start.markerlabels.end_pairs`) and the point tracks and labelled keypoints
of points.csv, as ``calibrate`` takes them. A camera that disagrees has moved, unless the
disagreement is one that no knock explains (:func:`check_rig`): most cameras disagreeing, or a
camera whose pose, placed again against the agreeing ones, lies farther from the result's than a
knock moves a camera or still misses its points. That is a rebuilt rig or a capture of another
one, and the answer is to calibrate afresh, not to re-solve a camera (docs/inputs.md).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.errors import Failure
from wandcal.calib.geometry import camera_centers, projection_derivative, rotation_angle
from wandcal.calib.observations import PointTracks, WandPairs, point_tracks
from wandcal.calib.rig import PointObservations, Rig, WandObservations
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.triangulate import reprojection_errors, triangulate_left_out, triangulate_points

MOVED_FACTOR = 3.0  # a camera whose leave-one-out error is 3x what is expected of it has moved
# ... and never below this: on clean data every leave-one-out error is a fraction of a pixel,
# and a few tenths more are noise, not a knock (1 px at 3 m is ~2 mm or 0.02 degrees at f = 1400)
MOVED_MIN_PX = 1.0
MIN_JUDGED_FRAMES = 10  # frames with two other cameras that a camera needs before it is judged (a point: half a frame)
# A knock turns a camera by a few degrees and shifts it by centimetres at most: a camera placed
# again against the agreeing ones further than this from the result's pose was not knocked, it
# is another camera or another rig (10 degrees is ~250 px at f = 1400 px: the issue's "moved by
# 300 px" was another rig)
BUMP_MAX_DEG = 10.0
BUMP_MAX_M = 0.2
# ... and a knocked camera placed again fits its points as it did before the knock: its median
# error then within this many times its limit (a touched lens leaves some error a pose cannot take)
BUMP_FIT_FACTOR = 3.0

# A capture's rig.json and a result's cameras are one rig when every shared camera has the same
# image size and its focal length and principal point agree within these: a refined focal
# length moves by a few per cent at most (docs/verdict.md), another camera's by far more
SAME_RIG_FOCAL = 0.1
SAME_RIG_PRINCIPAL = 0.1  # of the image's size
KNOCK_ADVICE = "it has moved or its lens was touched; recalibrate it with --solve-only"
ANOTHER_RIG = "no knock explains it: the rig was rebuilt or this is another one"


def rig_mismatches(calibrated: Rig, capture: Rig) -> list[str]:
    """Why ``capture``'s cameras are not the ``calibrated`` ones (empty when they are one rig):
    a camera the result does not have, another image size, or other intrinsics."""
    out = []
    for cam in capture.cameras:
        if cam.id not in calibrated.ids:
            out.append(f"the result has no camera {cam.id!r} (it has {', '.join(calibrated.ids)})")
            continue
        ref = calibrated.cameras[calibrated.index(cam.id)]
        if (cam.width, cam.height) != (ref.width, ref.height):
            out.append(f"{cam.id} is {cam.width}x{cam.height} px in the capture and {ref.width}x{ref.height} px in the result")
            continue
        focal = abs(cam.K[0, 0] / ref.K[0, 0] - 1)
        shift = np.hypot(cam.K[0, 2] - ref.K[0, 2], cam.K[1, 2] - ref.K[1, 2]) / max(cam.width, cam.height)
        if focal > SAME_RIG_FOCAL or shift > SAME_RIG_PRINCIPAL:
            out.append(f"{cam.id}'s intrinsics differ: focal {cam.K[0, 0]:.1f} against {ref.K[0, 0]:.1f} px, principal "
                       f"point ({cam.K[0, 2]:.0f}, {cam.K[1, 2]:.0f}) against ({ref.K[0, 2]:.0f}, {ref.K[1, 2]:.0f}) px")
    return out


@dataclass(frozen=True, eq=False)
class Sightings:
    """Observations of 3D points a camera is judged on: point (M,) index in [0, n_points),
    camera (M,), xy (M, 2) normalised; the wand's ends come first (2 F points: point 2 f + end),
    then the point tracks; ``wand_points``: how many points are the wand's."""

    point: np.ndarray
    camera: np.ndarray
    xy: np.ndarray
    n_points: int
    wand_points: int

    @classmethod
    def of(cls, pairs: WandPairs | None, tracks: PointTracks | None) -> Sightings:
        """The labelled wand ends (None: no wand) and the point tracks (None: none) together."""
        point, camera, xy = flatten(pairs) if pairs is not None else (np.zeros(0, np.int64), np.zeros(0, np.int64),
                                                                      np.zeros((0, 2)))
        n = 2 * len(pairs.frames) if pairs is not None else 0
        if tracks is None or not len(tracks):
            return cls(point, camera, xy, n, n)
        return cls(np.concatenate([point, tracks.track + n]), np.concatenate([camera, tracks.camera]),
                   np.concatenate([xy, tracks.xy]), n + tracks.n_tracks, n)


@dataclass(frozen=True)
class CameraCheck:
    """One camera against the others: ``rms_px`` and ``median_px`` of its leave-one-out errors
    over ``frames`` frames (a point seen with two others counts half a frame), and whether it
    ``moved`` (None: too few frames to judge). A moved camera placed again against the agreeing
    ones: ``turned_deg`` and ``shifted_m`` from the result's pose (None: not placed)."""

    id: str
    moved: bool | None
    rms_px: float | None
    median_px: float | None
    frames: int
    reason: str
    turned_deg: float | None = None
    shifted_m: float | None = None


@dataclass(frozen=True, eq=False)
class RigCheck:
    """The rig against a fresh capture: each camera's check, and ``rebuilt`` with why (empty when
    every disagreement is a knock a re-solve mends)."""

    cameras: list[CameraCheck]
    rebuilt: bool = False
    why: list[str] = field(default_factory=list)


def sightings(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations | None,
              points: PointObservations | None = None) -> Sightings:
    """The capture's wand ends (labelled at the given poses) and point tracks, as :class:`Sightings`."""
    pairs = None
    if wand is not None and len(wand) and rig.wand_length is not None:
        pairs = label_ends(R, t, end_pairs(rig, wand), np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    tracks = point_tracks(rig, points) if points is not None and len(points) else None
    return Sightings.of(pairs, tracks)


def _projection_jacobians(R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray,
                          X: np.ndarray) -> np.ndarray:
    """(K, 2, 3) derivatives of each sighting's normalised image point by its 3D point."""
    return projection_derivative(np.einsum("kij,kj->ki", R[camera], X[point]) + t[camera]) @ R[camera]


def everyone_left_out(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, trusted: np.ndarray,
                      rms_px: np.ndarray | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Each camera c's leave-one-out errors: [(K_c,) px] against points triangulated by the
    ``trusted`` (N,) bool cameras but c alone, over the points c and at least two of them saw; and
    with ``rms_px`` (N,) (the result's reprojection RMS) how much larger than its own RMS each
    camera's errors are expected to be, (N,) (ones without): the median over its points of
    sqrt(1 + the triangulation's own error, projected into c / rms_c^2) (:func:`_extra_errors`).
    Two other cameras at a narrow angle (a 3-camera rig) make it several times c's own: 1.0 when
    the others pin the point exactly.

    One triangulation serves every camera: each sighting's point is triangulated, as a point of
    its own, from the other trusted cameras' sightings of it. Each point's sums run over the same
    sightings in the same order as one camera at a time did, so the numbers are the same to the
    last digit; 128 calls of a few hundred points each were most of `wandcal check` at 128 cameras.
    """
    n = len(R)
    if not len(seen.point):
        return [np.zeros(0) for _ in range(n)], np.ones(n)
    X, of, mate = triangulate_left_out(R, t, seen.point, seen.camera, seen.xy, seen.n_points, trusted)
    views = np.bincount(of, minlength=len(seen.point))
    own = np.flatnonzero(views >= 2)
    cams = seen.camera[own]
    r = reprojection_errors(R, t, own, cams, seen.xy[own], X) * np.asarray(focal, float).reshape(n, -1)[cams]
    e = np.linalg.norm(r, axis=1)
    by_camera = np.argsort(cams, kind="stable")
    cuts = np.searchsorted(cams[by_camera], np.arange(n + 1))
    errors = [e[by_camera[cuts[c]:cuts[c + 1]]] for c in range(n)]
    errors = [v[np.isfinite(v)] for v in errors]
    if rms_px is None:
        return errors, np.ones(n)
    sel = views[of] >= 2
    extra = _extra_errors(R, t, seen, focal, X, of[sel], mate[sel], own, rms_px)
    scales = np.ones(n)
    for c in range(n):
        ratio = extra[by_camera[cuts[c]:cuts[c + 1]]]
        if len(ratio) and rms_px[c] > 0:
            ratio = np.sqrt(1.0 + ratio[np.isfinite(ratio)] / rms_px[c] ** 2)
            scales[c] = float(np.median(ratio)) if len(ratio) else 1.0
    return errors, scales


def _extra_errors(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, X: np.ndarray, of: np.ndarray,
                  mate: np.ndarray, own: np.ndarray, rms_px: np.ndarray) -> np.ndarray:
    """(K,) px^2: the triangulation's own error projected into each ``own`` (K,) sighting's camera c,
    tr(J_c cov(X) J_c^T). Its point ``X[own]`` is triangulated from the sightings ``mate`` (L,) of
    the other cameras (``of`` (L,): the own sighting each one serves), each carrying its camera's
    noise, per-axis variance rms_j^2 / 2 px^2 (``rms_px`` (N,)); ``focal`` (N,) or (N, 2) px."""
    focal = np.asarray(focal, float).reshape(len(R), -1).mean(axis=1)
    J = _projection_jacobians(R, t, of, seen.camera[mate], X)
    weight = (focal[seen.camera[mate]] ** 2) / np.maximum(rms_px[seen.camera[mate]] ** 2 / 2, 1e-12)
    JtJ = weight[:, None, None] * np.einsum("kai,kaj->kij", J, J)  # symmetric to the bit (a product commutes)
    info = np.empty((len(X), 3, 3))
    for i, j in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)):  # np.add.at's sums, in its order: one bincount an entry
        info[:, i, j] = info[:, j, i] = np.bincount(of, JtJ[:, i, j], minlength=len(X))
    Jc = _projection_jacobians(R, t, own, seen.camera[own], X) * focal[seen.camera[own]][:, None, None]
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(info[own])
    return np.einsum("kai,kij,kaj->k", Jc, cov, Jc)


def check_cameras(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations | None,
                  expected_rms_px: np.ndarray | None = None, points: PointObservations | None = None) -> list[CameraCheck]:
    """Find the cameras that moved since ``R, t`` were calibrated (:func:`check_rig`'s cameras)."""
    return check_rig(rig, R, t, wand, expected_rms_px, points).cameras


def check_rig(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations | None,
              expected_rms_px: np.ndarray | None = None, points: PointObservations | None = None) -> RigCheck:
    """Find the cameras that moved since ``R, t`` were calibrated, and tell a knock from another rig.

    Each camera is judged by its errors against points that the *other* cameras triangulate, so
    a knocked camera cannot hide by pulling the points towards itself. A knocked camera still
    spoils the others' triangulations (at 6 cameras a 1 degree knock lifts the others' errors
    six-fold), so only the worst camera is taken out at a time, and the rest are judged again
    without it, until every remaining one agrees.

    Args:
        R, t: (N, 3, 3), (N, 3) the result's world->camera poses, metres.
        wand, points: the fresh capture's raw wand blobs and point tracks (either may be None).
        expected_rms_px: (N,) each camera's reprojection RMS when it was calibrated (the result's
            ``reprojection_rms_px``); None to judge against the median camera instead.

    A camera has moved when its median leave-one-out error exceeds :data:`MOVED_FACTOR` times its
    expected RMS (or the agreeing cameras' median error) and :data:`MOVED_MIN_PX`. The rig is
    ``rebuilt`` when most cameras moved, or a moved camera placed again against the agreeing ones
    turns more than :data:`BUMP_MAX_DEG`, shifts more than :data:`BUMP_MAX_M` or still misses its
    points by :data:`BUMP_FIT_FACTOR` times its limit.
    """
    seen = sightings(rig, R, t, wand, points)
    focal = np.array([c.focal for c in rig.cameras])
    errors, trusted, limit = _judged(R, t, seen, focal, expected_rms_px)
    out = [_camera_check(cam.id, errors[c], bool(not trusted[c]), limit[c], seen.wand_points < seen.n_points)
           for c, cam in enumerate(rig.cameras)]
    moved = [c for c, chk in enumerate(out) if chk.moved]
    why = []
    if len(moved) > len(out) / 2:
        why.append(f"{len(moved)} of {len(out)} cameras disagree with the result")
    for c in moved:
        out[c], reason = _placed_again(out[c], R, t, seen, focal, c, trusted, limit[c])
        why += [reason] if reason else []
    if why:  # no camera to re-solve: say so where each one's reason would name --solve-only
        out = [dataclasses.replace(chk, reason=chk.reason.replace(KNOCK_ADVICE, ANOTHER_RIG)) for chk in out]
    return RigCheck(out, bool(why), why)


def _judged(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, expected_rms_px: np.ndarray | None):
    """({camera: (K,) leave-one-out errors px}, (N,) bool cameras still trusted, (N,) each one's limit px)."""
    n = len(R)
    trusted = np.ones(n, bool)
    # the result's RMS is each camera's error against points it helped place; against points the
    # others place alone it is larger by the triangulation's own error (from the first pass)
    rms = None if expected_rms_px is None else np.asarray(expected_rms_px, float)
    first, scales = everyone_left_out(R, t, seen, focal, trusted, rms)
    expected = None if rms is None else rms * scales

    def limits(errors: dict, agreeing: list[int]) -> np.ndarray:
        if expected is not None:
            ref = expected
        else:
            ref = np.full(n, float(np.median(np.concatenate([errors[c] for c in agreeing]))))
        return np.maximum(MOVED_FACTOR * ref, MOVED_MIN_PX)

    errors = dict(enumerate(first))
    while True:
        agreeing = [c for c in range(n) if trusted[c] and len(errors[c]) >= 2 * MIN_JUDGED_FRAMES]
        if len(agreeing) < 3:
            break
        limit = limits(errors, agreeing)
        excess = {c: np.median(errors[c]) / limit[c] for c in agreeing}
        worst = max(agreeing, key=lambda c: excess[c])
        if excess[worst] <= 1.0:
            break
        trusted[worst] = False
        errors = dict(enumerate(everyone_left_out(R, t, seen, focal, trusted)[0]))
    agreeing = [c for c in range(n) if trusted[c] and len(errors[c])]
    return errors, trusted, limits(errors, agreeing) if agreeing else np.full(n, MOVED_MIN_PX)


def _camera_check(cid: str, e: np.ndarray, distrusted: bool, limit: float, has_points: bool) -> CameraCheck:
    """One camera's verdict from its leave-one-out errors ``e`` (K,) px."""
    frames = len(e) // 2
    if frames < MIN_JUDGED_FRAMES:
        seen = (f"the wand or a point with two other cameras only {len(e)} times (each wand frame counts two)"
                if has_points else f"the wand with two other cameras in only {frames} frames")
        return CameraCheck(cid, None, None, None, frames, f"{cid} saw {seen}; wave the wand where {cid} and two others see it")
    rms, med = float(np.sqrt(np.mean(e**2))), float(np.median(e))
    is_moved = bool(distrusted or med > limit)
    reason = (f"{cid} disagrees with the others by {med:.2f} px (median; limit {limit:.2f} px): {KNOCK_ADVICE}"
              if is_moved else
              f"{cid} agrees with the others ({med:.2f} px median, limit {limit:.2f} px)")
    return CameraCheck(cid, is_moved, rms, med, frames, reason)


def _placed_again(check: CameraCheck, R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, c: int,
                  trusted: np.ndarray, limit: float) -> tuple[CameraCheck, str]:
    """A moved camera c resected against the points the trusted cameras triangulate: the check
    with how far it turned and shifted, and why it is no knock ('' when it is one)."""
    from wandcal.calib.start.resection import resect_camera  # only for a moved camera: a clean check never imports it

    others = trusted & (np.arange(len(R)) != c)
    use = others[seen.camera]
    X = triangulate_points(R, t, seen.point[use], seen.camera[use], seen.xy[use], seen.n_points)
    mine = (seen.camera == c) & np.all(np.isfinite(X[seen.point]), axis=1)
    pose = resect_camera(np.zeros((0, 2, 3)), np.zeros((0, 2, 2)), X[seen.point[mine]], seen.xy[mine],
                         float(focal[c].mean()))
    if isinstance(pose, Failure):
        return check, f"{check.id} fits no pose against the agreeing cameras ({pose})"
    Rc, tc = pose
    turned = float(np.degrees(rotation_angle(Rc, R[c])))
    shifted = float(np.linalg.norm(camera_centers(Rc[None], tc[None])[0] - camera_centers(R[c : c + 1], t[c : c + 1])[0]))
    R2, t2 = R.copy(), t.copy()
    R2[c], t2[c] = Rc, tc
    err = np.linalg.norm(reprojection_errors(R2, t2, seen.point[mine], seen.camera[mine], seen.xy[mine], X), axis=1)
    fit = float(np.median(err * focal[c].mean()))
    check = CameraCheck(**(vars(check) | {"turned_deg": turned, "shifted_m": shifted}))
    if turned > BUMP_MAX_DEG or shifted > BUMP_MAX_M:
        return check, (f"{check.id} placed again against the agreeing cameras is {turned:.1f} degrees and {shifted:.2f} m "
                       f"from the result's pose (a knock: up to {BUMP_MAX_DEG:.0f} degrees and {BUMP_MAX_M} m)")
    if fit > BUMP_FIT_FACTOR * limit:
        return check, (f"{check.id} placed again against the agreeing cameras still misses its points by {fit:.1f} px "
                       f"(median; a knocked camera's fit: under {BUMP_FIT_FACTOR * limit:.1f} px)")
    return check, ""
