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
from wandcal.calib.start.resection import resect_camera
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

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
KNOCK_ADVICE = "it has moved or its lens was touched; recalibrate it with --solve-only"
ANOTHER_RIG = "no knock explains it: the rig was rebuilt or this is another one"


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

    def around(self, c: int) -> Sightings:
        """The sightings (by every camera) of the points camera ``c`` saw, those points numbered
        0..K-1 in their order here; the rows keep their order."""
        in_c = np.zeros(self.n_points, bool)
        in_c[self.point[self.camera == c]] = True
        rows = in_c[self.point]
        number = np.cumsum(in_c) - 1
        return Sightings(number[self.point[rows]], self.camera[rows], self.xy[rows], int(number[-1]) + 1 if len(number) else 0,
                         int(in_c[: self.wand_points].sum()))


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


def leave_one_out_errors(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, c: int,
                         others: np.ndarray) -> np.ndarray:
    """(K,) camera c's errors, pixels, against points triangulated by the ``others`` (N,) bool
    cameras alone, over the points c and at least two of them saw."""
    return _leave_one_out(R, t, seen, focal, c, others)[0]


def _leave_one_out(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, c: int, others: np.ndarray,
                   rms_px: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """:func:`leave_one_out_errors`, and with ``rms_px`` :func:`expected_loo_scale` from the same
    triangulation (1.0 without)."""
    # only c's own points are triangulated, numbered 0..K-1 (every camera's check triangulating the
    # whole capture made `wandcal check` grow as cameras x frames; so did every per-point sum
    # sized to the whole capture's points, at 128 x 3000 of 2-4 cameras a frame)
    seen = seen.around(c)
    use = others[seen.camera]
    mine = seen.camera == c
    views = np.bincount(seen.point[use], minlength=seen.n_points)
    ok = (views >= 2)[seen.point]
    sel, own = use & ok, mine & ok
    X = triangulate_points(R, t, seen.point[sel], seen.camera[sel], seen.xy[sel], seen.n_points)
    r = reprojection_errors(R, t, seen.point[own], seen.camera[own], seen.xy[own], X) * focal[c]
    e = np.linalg.norm(r, axis=1)
    scale = 1.0 if rms_px is None else expected_loo_scale(R, t, seen, focal, c, X, sel, own, rms_px)
    return e[np.isfinite(e)], scale


def expected_loo_scale(R: np.ndarray, t: np.ndarray, seen: Sightings, focal: np.ndarray, c: int, X: np.ndarray,
                       sel: np.ndarray, own: np.ndarray, rms_px: np.ndarray) -> float:
    """How much larger than its own RMS camera c's leave-one-out errors are expected to be: the
    median over its points of sqrt(1 + the triangulation's own error, projected into c / rms_c^2).

    A point ``X`` triangulated by the other cameras' sightings ``sel`` alone carries their noise
    (each camera's per-axis variance rms_j^2 / 2 px^2, ``rms_px`` (N,) the result's reprojection
    RMS); projected into c's image (its sightings ``own``) it adds tr(J_c cov(X) J_c^T) to c's own
    rms_c^2. Two other cameras at a narrow angle (a 3-camera rig) make it several times c's own:
    1.0 when the others pin the point exactly.
    """
    if not own.any() or rms_px[c] <= 0:
        return 1.0
    focal = np.asarray(focal, float).reshape(len(R), -1).mean(axis=1)  # (N,) px; fx and fy alike here
    J = _projection_jacobians(R, t, seen.point[sel], seen.camera[sel], X)  # (K, 2, 3) normalised per metre
    weight = (focal[seen.camera[sel]] ** 2) / np.maximum(rms_px[seen.camera[sel]] ** 2 / 2, 1e-12)
    info = np.zeros((seen.n_points, 3, 3))
    np.add.at(info, seen.point[sel], weight[:, None, None] * np.einsum("kai,kaj->kij", J, J))
    pts = seen.point[own]
    Jc = _projection_jacobians(R, t, pts, seen.camera[own], X) * focal[c]
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(info[pts])
    extra = np.einsum("kai,kij,kaj->k", Jc, cov, Jc)
    ratio = np.sqrt(1.0 + extra[np.isfinite(extra)] / rms_px[c] ** 2)
    return float(np.median(ratio)) if len(ratio) else 1.0


def _projection_jacobians(R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray,
                          X: np.ndarray) -> np.ndarray:
    """(K, 2, 3) derivatives of each sighting's normalised image point by its 3D point."""
    return projection_derivative(np.einsum("kij,kj->ki", R[camera], X[point]) + t[camera]) @ R[camera]


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
    first = [_leave_one_out(R, t, seen, focal, c, np.arange(n) != c, rms) for c in range(n)]
    expected = None if rms is None else rms * np.array([scale for _, scale in first])

    def limits(errors: dict, agreeing: list[int]) -> np.ndarray:
        if expected is not None:
            ref = expected
        else:
            ref = np.full(n, float(np.median(np.concatenate([errors[c] for c in agreeing]))))
        return np.maximum(MOVED_FACTOR * ref, MOVED_MIN_PX)

    errors = {c: e for c, (e, _) in enumerate(first)}
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
        errors = {c: leave_one_out_errors(R, t, seen, focal, c, trusted & (np.arange(n) != c)) for c in range(n)}
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
