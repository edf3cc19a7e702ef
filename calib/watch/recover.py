"""A moved camera re-solved without a wand: its pose fitted to the take's markers as the cameras
that did not move triangulate them. Scale and world frame are the standing calibration's: the
points are in its frame and the other cameras are held.

The markers are matched and triangulated again over the frames after the move with the moved
cameras' blobs left out (they confirm no match), and the moved camera's views of them are found by
a wide search (:mod:`wandcal.calib.watch.search`): a camera turned too far for the health test's
12 px gate is re-solved as well as one that still finds its markers, and a view is not kept or
dropped by how far the knock moved it (the 12 px gate at the standing pose kept the views that moved
least, and took a 1 deg turn for 0.5-0.8 deg, bench_watch_real). With the pose that fits them, the
markers are matched again with the camera among the held ones (:func:`confirmed_markers`): those two
held cameras see and it confirms are added, placed by the held cameras alone (on Brown's sessions,
20-30 markers become 45-85).

Its sigma (decision 0061) is the fit's own, each residual weighted by its covariance in blobs'
variances, ``I + Jx A^-1 Jx^T`` (its blob and the error of the point the held cameras triangulate,
A their information on it), plus the pose's wander: the spread, beyond their own fits, of the same
re-solve over spans of as many frames before the move, where the camera stood at its standing pose
(:data:`WANDER_BLOCKS`). A camera model a little off shows as a pose that depends on where in the
image the markers are, and the markers after a move are elsewhere than those the standing pose was
fitted to: on the real takes that part is 1-6 times the fit's own. A camera moved before the take
has no such span; its wander is the test's baseline's (:func:`wander_share`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.geometry import camera_centers, matrix_to_rotvec, rotation_angle, rotvec_to_matrix
from wandcal.calib.rig import Rig
from wandcal.calib.triangulate import refine_points
from wandcal.calib.watch.health import PARAMS, WINDOW_FRAMES, linearised, point_jacobian, solve_pose_change
from wandcal.calib.watch.match import match_frames
from wandcal.calib.watch.search import GATE_PX, SEARCH_DEG, rays, search_views
from wandcal.calib.watch.sequential import BASELINE_WINDOWS, CameraTest
from wandcal.calib.watch.take import PaddedFrames, TakeBlobs, pad_frames

STEPS = 5  # Gauss-Newton steps from the search's turn: converges in three
MIN_POINTS = 15  # 30 residuals for 6 unknowns; fewer fix no pose worth writing (its sigma says how well these do)
OUTLIER_PX = 1.5  # as health's: 5 sigma of 0.3 px
# or 5 of the blobs' sigma as the first fit finds it (the real takes' ~1 px of model error), if more:
# P(chi2_2 > 25) = 4e-6, a view past it is a blob taken for another
OUTLIER_SIGMAS = 5.0
SETTLE_FRAMES = 5 * WINDOW_FRAMES  # the re-solve waits this long after a knock completes (and uses the rest)
MIN_HELD = 3  # cameras that did not move: a marker is matched in two and confirmed in a third
# A knock turns a camera about its mount far more than it moves its centre: the centre is held to the
# standing one within this (1-sigma, each direction), and the turn fitted from few markers is not traded
# for a move (bench_watch_real: 0.3-0.7 deg off on clean real takes with the centre free, decision 0061)
CENTRE_PRIOR_MM = 2.0
WANDER_BLOCKS = 2  # re-solves before the move, each over as many frames as the one after it, that measure its wander


@dataclass(frozen=True, eq=False)
class Resolved:
    """A camera's pose re-solved from a take. R (3, 3), t (3,) world->camera; points: markers
    used; rms_px: their residual, pixels per axis (unweighted); center_std_mm, rotation_std_deg:
    1-sigma (root of the covariance's trace) of the centre and the orientation: the fit's own
    (residuals weighted by their points' error) and the pose's wander, each also apart
    (fit_rotation_std_deg, wander_rotation_std_deg); moved_mm, turned_deg: from the standing pose;
    searched: (marker, blob) pairs the wide search weighed; fit_cov: the fit's own covariance;
    model_blocks: the re-solves before the move that measured the wander (0: the test's baseline's)."""

    R: np.ndarray
    t: np.ndarray
    points: int
    rms_px: float
    center_std_mm: float
    rotation_std_deg: float
    moved_mm: float
    turned_deg: float
    fit_rotation_std_deg: float = float("nan")
    wander_rotation_std_deg: float = 0.0
    searched: int = 0
    fit_cov: np.ndarray | None = None  # (6, 6): omega rad (camera frame), dC m
    model_blocks: int = 0

    def with_wander(self, wander: np.ndarray, blocks: int) -> Resolved:
        """The same re-solve, its covariance the fit's and ``wander`` (6, 6), measured over ``blocks``."""
        assert self.fit_cov is not None
        cov = self.fit_cov + wander
        return replace(self, center_std_mm=float(np.sqrt(np.trace(cov[3:, 3:])) * 1000), rotation_std_deg=_deg(cov),
                       wander_rotation_std_deg=_deg(wander), model_blocks=blocks)


@dataclass(frozen=True)
class NotResolved:
    """Why a moved camera was not re-solved, and what to do (falsy)."""

    reason: str

    def __bool__(self) -> bool:
        return False


def resolve_camera(R0: np.ndarray, t0: np.ndarray, focal: float, X: np.ndarray, xy: np.ndarray, *,
                   start: np.ndarray | None = None, point_info: np.ndarray | None = None,
                   wander: float = 0.0) -> Resolved | None:
    """Fit a camera's pose to markers X (k, 3), metres, seen at normalised xy (k, 2), from its
    standing pose R0 (3, 3), t0 (3,) turned by ``start`` (3, 3) about its centre (none: not turned);
    None with fewer than :data:`MIN_POINTS` markers. point_info (k, 3, 3): the held cameras'
    information on each marker (``sum J_v^T J_v``, px^-2 m^2 in blobs' variances; none: exact
    markers). The centre is held near the standing one by a prior of :data:`CENTRE_PRIOR_MM` a
    direction. wander: the pose's wander as a share of a residual's variance (lambda of
    :func:`wander_share`), added to the fit's covariance as ``lambda k cov_fit`` (the module's note)."""
    if len(X) < MIN_POINTS:
        return None
    C0 = camera_centers(R0[None], t0[None])[0]
    R, C = (R0 if start is None else start @ R0).copy(), C0.copy()
    keep = np.ones(len(X), bool)
    s2 = 1.0  # px^2: the blobs' variance, as the fit finds it
    for step in range(STEPS):
        J, r = _weighted(R, C, focal, X, xy, point_info)
        if step == 1:  # drop markers the first fit does not explain (a blob taken for another), weighted
            d2 = (r ** 2).sum(1)  # a blob's sigma a coordinate from the median: |r|^2 ~ sigma^2 chi2_2, median 2 ln 2
            keep = d2 < max(OUTLIER_PX ** 2, OUTLIER_SIGMAS ** 2 * float(np.median(d2)) / (2 * np.log(2)))
        H, g = _prior(np.einsum("kpi,kpj->ij", J[keep], J[keep]), np.einsum("kpi,kp->i", J[keep], r[keep]), C - C0, s2)
        p = solve_pose_change(H, g)
        R = rotvec_to_matrix(p[:3]) @ R
        C = C + p[3:]
        s2 = max(float((r[keep] ** 2).sum() / max(2 * keep.sum() - PARAMS, 1)), 1e-6)
    J, r = (v[keep] for v in _weighted(R, C, focal, X, xy, point_info))
    raw = linearised(R, -R @ C, focal, X[keep], xy[keep])[1]
    s2 = float((r ** 2).sum() / max(2 * len(r) - PARAMS, 1))
    H, _ = _prior(np.einsum("kpi,kpj->ij", J, J), np.zeros(PARAMS), C - C0, s2)
    fit = s2 * np.linalg.pinv(H, rcond=1e-10, hermitian=True)
    cov = fit * (1 + wander * len(r))
    t = -R @ C
    return Resolved(R, t, int(keep.sum()), float(np.sqrt((raw ** 2).sum() / max(2 * len(raw), 1))),
                    float(np.sqrt(np.trace(cov[3:, 3:])) * 1000), _deg(cov), float(np.linalg.norm(C - C0) * 1000),
                    float(np.degrees(rotation_angle(R, R0))), _deg(fit), _deg(cov - fit), fit_cov=fit)


def _prior(H: np.ndarray, g: np.ndarray, dC: np.ndarray, s2: float) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations H (6, 6), g (6,) with the centre's prior (:data:`CENTRE_PRIOR_MM` a direction
    about the standing centre, dC (3,) metres from it), in the units of residuals of variance s2 px^2."""
    w = s2 / (CENTRE_PRIOR_MM / 1000) ** 2
    H, g = H.copy(), g.copy()
    H[3:, 3:] += w * np.eye(3)
    g[3:] -= w * dC
    return H, g


def _deg(cov: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(max(np.trace(cov[:3, :3]), 0.0))))


def _weighted(R, C, focal: float, X, xy, point_info) -> tuple[np.ndarray, np.ndarray]:
    """J (k, 2, 6), r (k, 2) of :func:`~wandcal.calib.watch.health.linearised`, each whitened by its
    covariance in blobs' variances, ``I + Jx A^-1 Jx^T`` (A: ``point_info``; none: I)."""
    J, r = linearised(R, -R @ C, focal, X, xy)
    if point_info is None:
        return J, r
    Jx = point_jacobian(R, -R @ C, focal, X)
    cov = np.eye(2) + Jx @ np.linalg.pinv(point_info, rcond=1e-12, hermitian=True) @ np.swapaxes(Jx, 1, 2)
    W = np.linalg.inv(np.linalg.cholesky(cov))  # W cov W^T = I
    return W @ J, np.einsum("kab,kb->ka", W, r)


def held_markers(rig: Rig, R: np.ndarray, t: np.ndarray, blobs: TakeBlobs, rows: np.ndarray,
                 moved: list[int]) -> tuple[PaddedFrames, np.ndarray, np.ndarray, np.ndarray]:
    """The blobs ``rows`` padded (every camera's), and the markers the cameras not in ``moved``
    match and triangulate among them: (padded, frame index (T,) into padded.frames, X (T, 3) metres,
    the held cameras' information on each (T, 3, 3), px^-2 m^2 in blobs' variances)."""
    padded = pad_frames(rig, blobs, rows)
    xy, row = padded.xy.copy(), padded.row.copy()
    xy[:, moved], row[:, moved] = np.nan, -1
    tracks = match_frames(rig, R, t, PaddedFrames(padded.frames, xy, row))
    p, cam = np.nonzero(tracks.views >= 0)
    return padded, np.searchsorted(padded.frames, tracks.frame), tracks.X, _information(rig, R, t, p, cam, tracks.X)


def resolve_moved(rig: Rig, R: np.ndarray, t: np.ndarray, blobs: TakeBlobs, c: int, since: int, moved: list[int], *,
                  before: int | None = None, wander: float = 0.0) -> Resolved | NotResolved:
    """Camera c re-solved from the take's frames ``since`` on (blobs sorted by frame, numbered by
    rank), the cameras ``moved`` (c among them) left out of the markers; R (C, 3, 3), t (C, 3) the
    standing poses. Its wander is measured by re-solving it the same way over up to
    :data:`WANDER_BLOCKS` spans of as many frames (or all there are) before ``before`` (the frame it
    moved at), where it stood at its standing pose; with none (moved before the take), ``wander`` (:func:`wander_share`)
    is used. A :class:`NotResolved` says why not."""
    if len(rig.cameras) - len(set(moved)) < MIN_HELD:
        return NotResolved(f"only {len(rig.cameras) - len(set(moved))} cameras held still, and a marker the take "
                           f"places needs {MIN_HELD}")
    end = int(blobs.frame[-1]) + 1 if len(blobs) else since
    completed = since if before is None else max(before, since - SETTLE_FRAMES)
    solved, since = _settled_solve(rig, R, t, blobs, c, moved, wander, (completed, since, end))
    if not isinstance(solved, Resolved) or before is None:
        return solved
    span = end - since
    length = max(min(span, before), 1)  # a take short before its move: one span of all it has
    blocks = [_searched(rig, R, t, blobs, c, (before - (b + 1) * length, before - b * length), moved, 0.0)
              for b in range(WANDER_BLOCKS) if before - (b + 1) * length >= 0]
    devs = [(camera_pose_vector(R[c], t[c], r.R, r.t), r.fit_cov) for r in blocks
            if isinstance(r, Resolved) and r.fit_cov is not None]
    if not devs:
        return solved
    return solved.with_wander(_wander_cov(devs), len(devs))


def _settled_solve(rig: Rig, R, t, blobs: TakeBlobs, c: int, moved: list[int], wander: float,
                   frames: tuple[int, int, int]) -> tuple[Resolved | NotResolved, int]:
    """Camera c re-solved from the frames (completed, since, end): from ``since`` (the move completed,
    at ``completed``, and settled), then again from the first window after ``completed`` that fits
    that pose better than the standing one (:func:`settled_from`). A take too short after ``since``
    is re-solved from ``completed`` when every window up to ``since`` fits that pose better. (The
    re-solve or why not, its first frame.)"""
    completed, since, end = frames
    solved = _searched(rig, R, t, blobs, c, (since, end), moved, wander)
    if completed >= since:
        return solved, since
    if not isinstance(solved, Resolved):
        early = _searched(rig, R, t, blobs, c, (completed, end), moved, wander)
        if isinstance(early, Resolved) and settled_from(rig, R, t, blobs, c, moved, early, (completed, since)) == completed:
            return early, completed
        return solved, since
    start = settled_from(rig, R, t, blobs, c, moved, solved, (completed, since))
    wider = _searched(rig, R, t, blobs, c, (start, end), moved, wander) if start < since else None
    return (wider, start) if isinstance(wider, Resolved) else (solved, since)


def _searched(rig: Rig, R, t, blobs: TakeBlobs, c: int, frames: tuple[int, int], moved: list[int],
              wander: float) -> Resolved | NotResolved:
    """Camera c re-solved from the frames ``frames`` (first, stop) by the wide search's views."""
    cid = rig.cameras[c].id
    rows = np.arange(*np.searchsorted(blobs.frame, frames))
    padded, fi, X, info = held_markers(rig, R, t, blobs, rows, moved)
    focal = float(rig.cameras[c].focal.mean())
    b_frame, slot = np.nonzero(np.isfinite(padded.xy[:, c, :, 0]))
    xy = _standing_xy(R[c], t[c], X)
    ahead = np.flatnonzero(np.isfinite(xy[:, 0]))
    views = search_views(rays(xy[ahead]), fi[ahead], padded.xy[b_frame, c, slot], b_frame, focal)
    views = replace(views, point=ahead[views.point])
    if len(views) < MIN_POINTS:
        return NotResolved(f"{len(views)} of the {len(X)} markers the others triangulated after its move were found in "
                           f"{cid}'s image (within {SEARCH_DEG:g} deg of where they were; {MIN_POINTS} needed): record "
                           "a longer take it sees")
    solved = resolve_camera(R[c], t[c], focal, X[views.point], views.xy, start=views.turn,
                            point_info=info[views.point], wander=wander)
    if solved is None:
        return NotResolved(f"under {MIN_POINTS} markers fit {cid}'s re-solved pose")
    X2, xy2, info2 = confirmed_markers(rig, R, t, padded, c, moved, (solved.R, solved.t))
    again = resolve_camera(R[c], t[c], focal, X2, xy2, start=solved.R @ R[c].T, point_info=info2, wander=wander)
    if again is not None and again.points > solved.points:
        solved = again
    return replace(solved, searched=views.candidates)


def confirmed_markers(rig: Rig, R, t, padded: PaddedFrames, c: int, moved: list[int],
                      pose: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The markers matched with camera c at its re-solved ``pose`` (R (3, 3), t (3,)) among the
    cameras that did not move and c: those c and two held cameras or more see, triangulated by the
    held ones alone (c confirms the match, its view does not place the point). (X (k, 3) metres,
    c's blob (k, 2) normalised, the held cameras' information on each (k, 3, 3), as :func:`held_markers`.)"""
    return confirmed_views(rig, R, t, padded, c, moved, pose)[:3]


def confirmed_views(rig: Rig, R, t, padded: PaddedFrames, c: int, moved: list[int],
                    pose: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`confirmed_markers` and each marker's frame (k,)."""
    others_moved = [m for m in moved if m != c]
    xy, row = padded.xy.copy(), padded.row.copy()
    xy[:, others_moved], row[:, others_moved] = np.nan, -1
    R2, t2 = R.copy(), t.copy()
    R2[c], t2[c] = pose
    tracks = match_frames(rig, R2, t2, PaddedFrames(padded.frames, xy, row))
    held = tracks.views.copy()
    held[:, c] = -1
    ok = (tracks.views[:, c] >= 0) & ((held >= 0).sum(1) >= 2)
    p, cam = np.nonzero(held[ok] >= 0)
    X = refine_points(R, t, p, cam, padded.xy_of(held[ok][p, cam]), tracks.X[ok])
    return X, padded.xy_of(tracks.views[ok, c]), _information(rig, R, t, p, cam, X), tracks.frame[ok]


def settled_from(rig: Rig, R, t, blobs: TakeBlobs, c: int, moved: list[int], solved: Resolved,
                 frames: tuple[int, int]) -> int:
    """The first frame of ``frames`` (moved_at, since) from which camera c stood at its re-solved
    pose (``solved``, fitted to the frames from ``since`` on) rather than its standing one: the
    earliest window (:data:`~wandcal.calib.watch.health.WINDOW_FRAMES`) from which every window up
    to ``since`` that holds a marker fits the re-solved pose better. A window's fit to a pose is
    the sum over the markers the held cameras place in it of the squared distance, pixels, from the
    marker's projection to c's nearest blob in its frame, capped at the search's gate
    (:data:`~wandcal.calib.watch.search.GATE_PX`; a marker with no blob there costs the cap): the
    log-likelihood of blobs with Gaussian noise and outliers spread evenly, so the comparison is the
    likelihood ratio of the two poses with even odds. Not a test against the re-solved pose's own
    scatter: a pose fitted to markers in one part of the image misses those elsewhere by several
    times the noise on the real takes (bench_watch_real's MultiCamSelfCal: 0.1 px about the fit,
    0.2-0.9 px in the windows before), far less than a knock the watch names moves them."""
    lo, since = frames
    rows = np.arange(*np.searchsorted(blobs.frame, frames))
    padded, fi, X, _ = held_markers(rig, R, t, blobs, rows, moved)
    focal = float(rig.cameras[c].focal.mean())
    blob_xy = padded.xy[fi, c]  # (T, S, 2): c's blobs in each marker's frame
    cost = [np.minimum(np.nanmin(np.sum((blob_xy - _standing_xy(Rc, tc, X)[:, None]) ** 2, axis=2), axis=1,
                                 initial=np.inf) * focal ** 2, GATE_PX ** 2)
             for Rc, tc in ((solved.R, solved.t), (R[c], t[c]))]
    frame = padded.frames[fi]
    start = since
    for w0 in range(since - WINDOW_FRAMES, lo - WINDOW_FRAMES, -WINDOW_FRAMES):
        sel = (frame >= max(w0, lo)) & (frame < w0 + WINDOW_FRAMES)
        if cost[0][sel].sum() > cost[1][sel].sum():  # a tie (no blob near either: no evidence) goes on
            break
        start = max(w0, lo)
    return start


def _information(rig: Rig, R, t, p: np.ndarray, cam: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(P, 3, 3) the cameras' information on points X (P, 3) from the views (point p (k,), camera cam (k,)),
    ``sum J_v^T J_v``, px^-2 m^2 in blobs' variances."""
    focal = np.array([camera.focal.mean() for camera in rig.cameras])
    Jv = point_jacobian(R[cam], t[cam], focal[cam], X[p])
    info = np.zeros((len(X), 3, 3))
    np.add.at(info, p, np.einsum("kai,kaj->kij", Jv, Jv))
    return info


def camera_pose_vector(R0: np.ndarray, t0: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(6,) the pose R, t (3, 3), (3,) from R0, t0: (omega (3,) radians, camera frame, ``R = exp(omega) R0``;
    dC (3,) metres, the centre's move), the parametrisation of :mod:`wandcal.calib.watch.health`."""
    C = camera_centers(np.stack([R0, R]), np.stack([t0, t]))
    return np.concatenate([matrix_to_rotvec(R @ R0.T), C[1] - C[0]])


def _wander_cov(devs: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """(6, 6) the spread of re-solves at the standing pose about it beyond their fits' own covariance
    (each dev: (6,) the re-solve's pose from the standing one, (6, 6) its fit's covariance), the
    negative part dropped."""
    d = np.array([v for v, _ in devs])
    extra = np.einsum("bi,bj->ij", d, d) / len(d) - np.mean([cov for _, cov in devs], axis=0)
    vals, vecs = np.linalg.eigh((extra + extra.T) / 2)
    return (vecs * np.maximum(vals, 0.0)) @ vecs.T


def _standing_xy(Rc: np.ndarray, tc: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(T, 2) normalised projections of X (T, 3) at the pose Rc, tc (points behind it: NaN)."""
    Xc = X @ Rc.T + tc
    return Xc[:, :2] / np.where(Xc[:, 2:] > 0, Xc[:, 2:], np.nan)


def wander_share(test: CameraTest) -> float:
    """lambda: how far a camera's pose wandered over the take's baseline beyond its noise, as a share
    of one residual's variance (the test's wander covariance is ``lambda (I_0 / n_0)^+``,
    :meth:`wandcal.calib.watch.sequential.CameraTest.wander`); 0 before the baseline is in."""
    base = test.baseline()
    if base is None:
        return 0.0
    per = base[1] / max(float(np.sum(test.n[:BASELINE_WINDOWS])), 1.0)
    rank = np.linalg.matrix_rank(per, hermitian=True)
    return float(np.trace(per @ test.wander(base)) / max(rank, 1))
