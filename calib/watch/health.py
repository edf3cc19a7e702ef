"""Each camera's residual against the markers the other cameras triangulate, window by window.

For camera c, a track seen by two cameras or more besides c is triangulated without c, projected
into c at its standing pose, and c's nearest blob within :data:`HEALTH_PX` (and :data:`CLEAR_RATIO`
times nearer than any other) is its view. The residual r (pixels) is linearised in a small change of
c's pose, ``r ~ J p`` with p = (omega (3,) radians: a turn about the camera's centre, camera frame;
dC (3,) metres: the centre's move, world frame): with ``x_c = R (X - C)``,
``dx_c = -[x_c]x omega - R dC`` and J = f P dx_c, P the Jacobian of (x/z, y/z). Each window of
:data:`WINDOW_FRAMES` frames fits p by least squares, drops residuals past :data:`OUTLIER_PX` from
the fit (a blob taken for another marker) and fits again; it keeps the normal equations (g = J^T r,
H = J^T J) of every frame's kept residuals, and the window's residual sum of squares about its fit.
Each residual and its J are first whitened by the residual's covariance in units of one blob's
variance, ``I + Jx A^-1 Jx^T`` (:func:`whitened`; A the other cameras' information on the point): where
two cameras fix a marker loosely, its error in this camera is not taken for this camera's (decision 0056).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from wandcal.calib.geometry import projection_derivative, sum_by
from wandcal.calib.rig import Rig
from wandcal.calib.triangulate import DAMPING, refine_points, solve_symmetric_3x3
from wandcal.calib.watch.match import CLEAR_RATIO, FRAME_GAP_PX, Tracks
from wandcal.calib.watch.take import PaddedFrames

HEALTH_PX = 12.0  # a camera turned by 0.5 deg (f = 1100 px) still finds its blobs; past it the camera is lost
OUTLIER_PX = 1.5  # 5 sigma of 0.3 px blob noise about the window's own fit
WINDOW_FRAMES = 10  # 0.1 s at 100 fps: ~400 residuals of a 40-marker take, the test's time step
PARAMS = 6  # omega (3) and dC (3)
# how a track a camera sees is triangulated without it (camera_windows' method)
Triangulation = Literal["refined", "downdated"]
LOOSE_POINT = 1.0  # a point's own error (variance, in blobs' variances) past which a residual is weighted down


@dataclass(frozen=True, eq=False)
class CameraWindows:
    """Per-frame and per-window normal equations of every camera's residuals.

    frames: (F,) frame numbers; g: (F, C, 6) J^T r (px^2 per rad and per m); H: (F, C, 6, 6)
    J^T J; n: (F, C) residuals kept (each a 2-vector); seen: (F, C) markers projected into the
    camera (whether or not a blob was found); sse: (F, C) squared residuals about their window's
    fit, px^2. obs: per camera (frame (k,), X (k, 3) the marker triangulated without it, metres,
    xy (k, 2) its blob, normalised) of the kept residuals, when asked for (the re-solve's data).
    """

    frames: np.ndarray
    g: np.ndarray
    H: np.ndarray
    n: np.ndarray
    seen: np.ndarray
    sse: np.ndarray
    obs: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None


def camera_windows(rig: Rig, R: np.ndarray, t: np.ndarray, padded: PaddedFrames, tracks: Tracks, *,
                   keep_obs: bool = False, cams: list[int] | None = None,
                   method: Triangulation = "refined") -> CameraWindows:
    """The residuals of every camera of a batch of frames against ``tracks`` (from
    :func:`wandcal.calib.watch.match.match_frames` over the same frames), at poses R (C, 3, 3), t (C, 3).
    ``cams``: the cameras measured (the others' rows left zero); all when None. ``method``: how a track
    a camera sees is triangulated without it: "refined", Gauss-Newton steps of its other views from the
    track's start (the watch's tests); "downdated", one step from the all-view point with that camera's
    own terms taken out of the normal equations summed once over every view (:func:`_downdated`: the
    attribution's hypotheses, decision 0102)."""
    n_f, n_c = len(padded.frames), len(R)
    g = np.zeros((n_f, n_c, PARAMS))
    H = np.zeros((n_f, n_c, PARAMS, PARAMS))
    n = np.zeros((n_f, n_c))
    seen = np.zeros((n_f, n_c))
    sse = np.zeros((n_f, n_c))
    obs = []
    f_of = np.searchsorted(padded.frames, tracks.frame)
    focal = np.array([cam.focal.mean() for cam in rig.cameras])
    every = _all_views(R, t, focal, padded, tracks, terms=method == "downdated")
    for c in range(n_c) if cams is None else cams:
        fi, X, xy, info = _leave_one_out(R, t, focal, padded, tracks, f_of, c, every)
        seen[:, c] = np.bincount(f_of[(tracks.views >= 0).sum(1) - (tracks.views[:, c] >= 0) >= 2], minlength=n_f)
        J, r = whitened(*linearised(R[c], t[c], focal[c], X, xy), point_jacobian(R[c], t[c], focal[c], X), info)
        JJ, Jr = np.einsum("kpi,kpj->kij", J, J), np.einsum("kpi,kp->ki", J, r)  # each residual's H and g
        keep, dev = _inliers(fi // WINDOW_FRAMES, J, r, JJ, Jr)
        fi, dev = fi[keep], dev[keep]
        g[:, c] = sum_by(fi, Jr[keep], n_f)
        H[:, c] = sum_by(fi, JJ[keep], n_f)
        n[:, c] = np.bincount(fi, minlength=n_f)
        sse[:, c] = np.bincount(fi, (dev ** 2).sum(1), minlength=n_f)
        obs.append((padded.frames[fi], X[keep], xy[keep]))
    return CameraWindows(padded.frames, g, H, n, seen, sse, obs if keep_obs else None)


@dataclass(frozen=True, eq=False)
class _AllViews:
    """Every track of two views or more triangulated from all its views, as :func:`_leave_one_out`
    triangulates it for each camera that does not see it (the same views in the same order, from the
    same start): X (T, 3) metres, NaN for a track of fewer views; info (T, 3, 3) its views'
    ``sum J_v^T J_v`` (:func:`_information`), pixels^2 a metre^2."""

    X: np.ndarray
    info: np.ndarray
    terms: _ViewTerms | None = None


@dataclass(frozen=True, eq=False)
class _ViewTerms:
    """Each view's terms of a track's Gauss-Newton normal equations at :class:`_AllViews`' point (its
    reprojection error in normalised coordinates, as :func:`~wandcal.calib.triangulate.refine_points`'),
    to be summed once and taken out one camera at a time (:func:`_downdated`). view (T, C): the index of
    track T's view in camera C (-1: none); A (M, 6): J_v^T J_v's distinct entries (00, 01, 02, 11, 12,
    22), metre^-2; g (M, 3): J_v^T r_v, metre^-1; their sums over each track's views A_sum (T, 6),
    g_sum (T, 3); focal2 (M,): the view's camera's focal length squared, pixels^2 (A in pixels)."""

    view: np.ndarray
    A: np.ndarray
    g: np.ndarray
    A_sum: np.ndarray
    g_sum: np.ndarray
    focal2: np.ndarray


def _all_views(R, t, focal: np.ndarray, padded: PaddedFrames, tracks: Tracks, *, terms: bool = False) -> _AllViews:
    """:class:`_AllViews` of a batch's tracks: one triangulation shared by every camera that does not
    see a track (about half the cameras a track; each triangulated it apart before); with ``terms``, each
    view's :class:`_ViewTerms` at it."""
    X = np.full((len(tracks), 3), np.nan)
    info = np.full((len(tracks), 3, 3), np.nan)
    ok = np.flatnonzero((tracks.views >= 0).sum(1) >= 2)
    p, cam = np.nonzero(tracks.views[ok] >= 0)
    xy = padded.xy_of(tracks.views[ok][p, cam])
    X[ok] = refine_points(R, t, p, cam, xy, tracks.X[ok])
    if not terms:
        info[ok] = _information(R, t, focal, p, cam, X[ok])
        return _AllViews(X, info)
    A, g = _view_terms(R, t, p, cam, xy, X[ok])
    focal2 = focal[cam] ** 2
    info[ok] = _symmetric(sum_by(p, A * focal2[:, None], len(ok)))  # _information's, from the same terms
    view = np.full(tracks.views.shape, -1)
    view[ok[p], cam] = np.arange(len(p))
    A_sum, g_sum = np.zeros((len(tracks), 6)), np.zeros((len(tracks), 3))
    A_sum[ok], g_sum[ok] = sum_by(p, A, len(ok)), sum_by(p, g, len(ok))
    return _AllViews(X, info, _ViewTerms(view, A, g, A_sum, g_sum, focal2))


def _view_terms(R, t, p: np.ndarray, cam: np.ndarray, xy: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 6) J_v^T J_v's distinct entries and (M, 3) J_v^T r_v of each view (point p (M,), camera cam
    (M,), normalised blob xy (M, 2)) of points X (P, 3): refine_points' normal equations, a view at a time."""
    Rv, Xp = R[cam], X[p]
    xc = np.einsum("mij,mj->mi", Rv, Xp) + t[cam]
    iz = 1.0 / xc[:, 2]
    u, v = xc[:, 0] * iz, xc[:, 1] * iz
    ax = (Rv[:, 0] - u[:, None] * Rv[:, 2]) * iz[:, None]  # d(x/z)/dX (M, 3)
    ay = (Rv[:, 1] - v[:, None] * Rv[:, 2]) * iz[:, None]
    pairs = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
    A = np.column_stack([ax[:, i] * ax[:, j] + ay[:, i] * ay[:, j] for i, j in pairs])
    g = ax * (u - xy[:, 0])[:, None] + ay * (v - xy[:, 1])[:, None]
    return A, g


def _downdated(every: _AllViews, terms: _ViewTerms, rows: np.ndarray, c: int) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) the tracks ``rows`` (k,) (each seen by camera c and two others) triangulated without c by
    one Gauss-Newton step from the all-view point, with c's terms taken out of the summed normal
    equations; (k, 3, 3) the others' information on them (pixels^2 a metre^2), at the all-view point.
    The all-view point is within a blob's error of the leave-one-out point, so the step's error is
    second order in that shift: about 1e-5 px on the residuals (decision 0102), against the refined
    triangulation's 1e-9."""
    v = terms.view[rows, c]
    A = terms.A_sum[rows] - terms.A[v]
    g = terms.g_sum[rows] - terms.g[v]
    a00, a01, a02, a11, a12, a22 = A.T
    damp = DAMPING * (a00 + a11 + a22) + 1e-300
    step = solve_symmetric_3x3(a00 + damp, a01, a02, a11 + damp, a12, a22 + damp, *g.T).T
    X = every.X[rows] - np.where(np.isfinite(step).all(1, keepdims=True), step, 0.0)
    info = every.info[rows] - _symmetric(terms.A[v] * terms.focal2[v, None])
    return X, info


def _symmetric(A: np.ndarray) -> np.ndarray:
    """(k, 3, 3) of the distinct entries (k, 6) (00, 01, 02, 11, 12, 22)."""
    return A[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)


def _leave_one_out(R, t, focal: np.ndarray, padded: PaddedFrames, tracks: Tracks, f_of, c: int, every: _AllViews):
    """(frame index (k,), X (k, 3), c's blob xy (k, 2), the others' information on X (k, 3, 3)) of
    the tracks two other cameras saw, triangulated without c, and c's blob found near their
    projection; focal (C,): each camera's mean focal length, pixels. A track c does not see is
    ``every``'s (its views are all the others'); only the ones c sees are triangulated again."""
    others = tracks.views.copy()
    others[:, c] = -1
    ok = (others >= 0).sum(1) >= 2
    again = ok & (tracks.views[:, c] >= 0)  # c's view is left out of these
    X = every.X.copy()
    terms = every.terms
    if terms is None:
        X[again] = _triangulated(R, t, padded, others[again], tracks.X[again])
    else:
        loo_info = every.info.copy()
        X[again], loo_info[again] = _downdated(every, terms, np.flatnonzero(again), c)
    rows = np.flatnonzero(ok)
    fi, xy, found = _nearest_blob(R[c], t[c], focal[c], padded, c, f_of[ok], X[ok])
    rows = rows[found]  # the tracks c's blob was found for
    if terms is not None:
        return fi[found], X[rows], xy[found], loo_info[rows]
    info = every.info[rows]
    mine = again[rows]
    p, cam = np.nonzero(others[rows[mine]] >= 0)
    info[mine] = _information(R, t, focal, p, cam, X[rows[mine]])
    return fi[found], X[rows], xy[found], info


def _triangulated(R, t, padded: PaddedFrames, views: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """(P, 3) tracks of views (P, C) (blob rows, -1 where none) triangulated from X0 (P, 3)."""
    p, cam = np.nonzero(views >= 0)
    return refine_points(R, t, p, cam, padded.xy_of(views[p, cam]), X0)


def _information(R, t, focal: np.ndarray, p: np.ndarray, cam: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(P, 3, 3) ``sum J_v^T J_v`` over the views (point p (M,), camera cam (M,)) of points X (P, 3),
    J_v (2, 3) the projection's derivative in the point, pixels a metre (:func:`point_jacobian`, by its
    components: the six distinct entries summed a view at a time, as the triangulation's own)."""
    table = np.concatenate([R.reshape(-1, 9), t, focal[:, None]], axis=1).T  # (13, C): R[3 i + j], t[i], focal
    r, Xp = np.take(table, cam, axis=1), np.take(X.T, p, axis=1)
    xc = [r[3 * i] * Xp[0] + r[3 * i + 1] * Xp[1] + r[3 * i + 2] * Xp[2] + r[9 + i] for i in range(3)]
    fz = r[12] / xc[2]
    u, v = xc[0] / xc[2], xc[1] / xc[2]
    ax = [(r[j] - u * r[6 + j]) * fz for j in range(3)]  # d(f x/z)/dX
    ay = [(r[3 + j] - v * r[6 + j]) * fz for j in range(3)]
    info = np.empty((len(X), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            info[:, i, j] = info[:, j, i] = np.bincount(p, ax[i] * ax[j] + ay[i] * ay[j], minlength=len(X))
    return info


def _nearest_blob(Rc, tc, focal: float, padded: PaddedFrames, c: int, f_idx, X):
    """c's blob nearest each point's projection within :data:`HEALTH_PX`, clearly the nearest:
    (frame index (P,), blob xy (P, 2), found (P,) bool)."""
    Xc = X @ Rc.T + tc
    found = np.zeros(len(X), bool)
    xy = np.full((len(X), 2), np.nan)
    fi, k, tree = padded.blob_tree(c, focal)
    ahead = np.isfinite(Xc[:, 2]) & (Xc[:, 2] > 0)
    if tree is None or not ahead.any():
        return f_idx, xy, found
    q = np.flatnonzero(ahead)
    proj = Xc[q, :2] / Xc[q, 2:3] * focal
    d, j = tree.query(np.column_stack([proj, f_idx[q] * FRAME_GAP_PX]), k=2, distance_upper_bound=CLEAR_RATIO * HEALTH_PX)
    near = (d[:, 0] < HEALTH_PX) & (d[:, 1] >= CLEAR_RATIO * d[:, 0])
    found[q[near]] = True
    xy[q[near]] = padded.xy[fi[j[near, 0]], c, k[j[near, 0]]]
    return f_idx, xy, found


def linearised(Rc, tc, focal: float, X, xy) -> tuple[np.ndarray, np.ndarray]:
    """(k, 2, 6) J and (k, 2) residuals r = blob - projection, pixels (the module's note)."""
    Xc = X @ Rc.T + tc
    iz = 1.0 / Xc[:, 2]
    u, v = Xc[:, 0] * iz, Xc[:, 1] * iz
    P = np.zeros((len(X), 2, 3))
    P[:, 0, 0] = P[:, 1, 1] = iz
    P[:, 0, 2], P[:, 1, 2] = -u * iz, -v * iz
    skew = np.zeros((len(X), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -Xc[:, 2], Xc[:, 1], -Xc[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = Xc[:, 2], -Xc[:, 1], Xc[:, 0]
    dx = np.concatenate([-skew, np.broadcast_to(-Rc, (len(X), 3, 3))], axis=2)  # (k, 3, 6)
    J = focal * np.einsum("kab,kbp->kap", P, dx)
    r = focal * (xy - np.column_stack([u, v]))
    return J, r


def point_jacobian(R, t, focal, X) -> np.ndarray:
    """(k, 2, 3) pixels per metre: the projection's derivative in the points X (k, 3) for cameras R
    (3, 3) or (k, 3, 3), t (3,) or (k, 3), focal a number or (k,)."""
    R = np.broadcast_to(R, (len(X), 3, 3))
    Xc = np.einsum("kij,kj->ki", R, X) + t
    return np.asarray(focal).reshape(-1, 1, 1) * (projection_derivative(Xc) @ R)


def whitened(J: np.ndarray, r: np.ndarray, Jx: np.ndarray, info: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """J (k, 2, 6) and r (k, 2) whitened by each residual's covariance in units of one blob's
    variance: ``I + Jx info^-1 Jx^T``, its own blob's noise and the error of the point the other
    cameras triangulated, projected into this camera (Jx (k, 2, 3), info (k, 3, 3): the others'
    ``sum J_v^T J_v``). Where two other cameras see a marker from nearly the same side, its depth is
    poorly fixed and its error projects into this camera as a large, slowly varying residual: the
    weight takes it down to what it says about this camera's pose. Only directions where the point's
    error passes the blob's own (``LOOSE_POINT``) are weighted: where the others fix the point well
    the residual is left as it is (with 12 cameras nearly every one; weighting those too moved a clean
    simulated take's statistic past the threshold, decision 0056)."""
    M = _projected_inverse(Jx, info)  # (k, 2, 2) Jx info^-1 Jx^T: the point's error in this camera
    a, b, d = M[:, 0, 0], M[:, 1, 0], M[:, 1, 1]
    half, h = (a - d) / 2, np.hypot((a - d) / 2, b)
    big, small = 1 + (a + d) / 2 + h, 1 + (a + d) / 2 - h  # the covariance's eigenvalues
    loose = np.flatnonzero(big > 1 + LOOSE_POINT)  # with many cameras few or none: the rest stay as they are
    if not len(loose):
        return J, r
    # cov^-1/2 where loose, 1 elsewhere, from the two eigenvalues: W = w_small I + (w_big - w_small) P, with
    # P = (cov - small I) / (big - small) the projector on the larger one's eigenvector (no eigen-decomposition)
    w_big = 1 / np.sqrt(big[loose])
    w_small = np.where(small[loose] > 1 + LOOSE_POINT, 1 / np.sqrt(small[loose]), 1.0)
    hl = h[loose]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(hl > 0, (w_big - w_small) / (2 * hl), 0.0)  # equal eigenvalues: W = w I
    W = np.empty((len(loose), 2, 2))
    W[:, 0, 0] = w_small + scale * (half[loose] + hl)
    W[:, 1, 1] = w_small + scale * (hl - half[loose])
    W[:, 0, 1] = W[:, 1, 0] = scale * b[loose]
    J, r = J.copy(), r.copy()
    J[loose] = W @ J[loose]
    r[loose] = np.einsum("kab,kb->ka", W, r[loose])
    return J, r


def _projected_inverse(Jx: np.ndarray, info: np.ndarray) -> np.ndarray:
    """(k, 2, 2) ``Jx info^+ Jx^T`` of Jx (k, 2, 3) and symmetric info (k, 3, 3), by the adjugate; a
    system whose smallest eigenvalue may be under 1e-9 of its largest by the pseudo-inverse (rcond 1e-12)."""
    a, b, c = info[:, 0, 0], info[:, 0, 1], info[:, 0, 2]
    d, e, f = info[:, 1, 1], info[:, 1, 2], info[:, 2, 2]
    adj = np.empty_like(info)
    adj[:, 0, 0], adj[:, 0, 1], adj[:, 0, 2] = d * f - e * e, c * e - b * f, b * e - c * d
    adj[:, 1, 1], adj[:, 1, 2], adj[:, 2, 2] = a * f - c * c, b * c - a * e, a * d - b * b
    adj[:, 1, 0], adj[:, 2, 0], adj[:, 2, 1] = adj[:, 0, 1], adj[:, 0, 2], adj[:, 1, 2]
    det = a * adj[:, 0, 0] + b * adj[:, 0, 1] + c * adj[:, 0, 2]
    trace = a + d + f
    well = det > 1e-9 * trace ** 3  # then the smallest eigenvalue > det / trace^2 > 1e-9 of the largest
    inv = np.empty_like(info)
    inv[well] = adj[well] / det[well, None, None]
    if not well.all():
        inv[~well] = np.linalg.pinv(info[~well], rcond=1e-12, hermitian=True)
    return Jx @ inv @ np.swapaxes(Jx, 1, 2)


def _inliers(window: np.ndarray, J: np.ndarray, r: np.ndarray, JJ: np.ndarray,
             Jr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,) residuals within :data:`OUTLIER_PX` of their window's least-squares pose change (fitted
    twice: the second time without the first fit's outliers), and (k, 2) each residual about the fit
    (J (k, 2, 6), r (k, 2); JJ (k, 6, 6) and Jr (k, 6) each residual's J^T J and J^T r)."""
    keep = np.ones(len(r), bool)
    dev = r
    if not len(r):
        return keep, dev
    wins, w_of = np.unique(window, return_inverse=True)
    for _ in range(2):
        p = solve_pose_change(sum_by(w_of[keep], JJ[keep], len(wins)), sum_by(w_of[keep], Jr[keep], len(wins)))
        dev = r - np.einsum("kpi,ki->kp", J, p[w_of])
        keep = np.hypot(dev[:, 0], dev[:, 1]) < OUTLIER_PX
    return keep, dev


def solve_pose_change(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(..., 6) least-squares pose changes of normal equations H (..., 6, 6), g (..., 6); a
    direction the markers do not fix (too few of them) gets no change (pseudo-inverse)."""
    return np.einsum("...ij,...j->...i", np.linalg.pinv(H, rcond=1e-10, hermitian=True), g)
