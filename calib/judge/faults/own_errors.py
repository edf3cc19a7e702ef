"""Each camera's own errors, with the points eliminated: its noise (and, in
:mod:`wandcal.calib.judge.faults.pose_steps`, a step in its pose).

A camera's residual in the solve holds the other cameras' errors too: each point is triangulated
from two to four views, so one camera's noise is spread over the points and shows in its
neighbours' residuals. Here the points are *eliminated* instead: with every pose held, each point
is fitted to all its views (weighted by each camera's noise), and what remains is tested with the
point's three columns projected out of the model (the Schur complement of bundle adjustment).
Every observation takes part: the wand's ends, every marker, and the point tracks, in frames seen by
only two cameras too (one epipolar degree of freedom each, where "triangulated by two others"
would need three views).

**Noise** (:func:`camera_noise`): each camera's variance of unit weight by variance components
(Förstner): ``sigma_c^2`` from its views' squared residuals over their redundancy ``rho_i`` (2 less
the hat matrix's trace), by the median (hand-digitised sessions carry gross outliers), iterated
with the weights; its standard error from the order statistics about the median. A camera is
noisy when its sigma stands above the other cameras' median by more than :data:`NOISE_LIMIT`, by
:data:`NOISE_Z` standard errors; cameras are named one at a time (:func:`noisy_cameras`).
docs/verdict.md gives the limits, docs/decisions/0035 how they were measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.start.labels import flatten
from wandcal.calib.triangulate import triangulate_points

TRIM_SIGMAS = 5.0  # an observation this many of its camera's sigmas off (for its redundancy) is an outlier
VARIANCE_ROUNDS = 6  # variance components: the sigmas settle to within 2% by the sixth round on the real sessions
# a camera's noise against the other cameras' median: 1.5 is where the verdict's noise criterion
# leaves "excellent" (wandcal.calib.judge.verdict.NOISE_RATIO); a camera is named noisy only when
# its ratio stands above it by NOISE_Z standard errors (one-sided 2%)
NOISE_LIMIT = 1.5
NOISE_Z = 2.0
MIN_NOISE_OBSERVATIONS = 30  # of a camera, for its sigma to be compared
MIN_REDUNDANCY = 0.5  # a view whose point hangs mostly on it says little of its camera's noise
# a large rig's views judged, per camera (whole points evenly spaced in the capture): 16 cameras of
# 2,500 frames hold 75,000 views, whose elimination takes a second; at 400 a camera's sigma is
# known to ~5% (far inside NOISE_LIMIT's margin) and a 0.3 degree knock moves 200 of them by 15
# of a 0.3 px noise's standard errors
VIEWS_PER_CAMERA = 400


@dataclass(frozen=True, eq=False)
class Views:
    """Every observation of the points: point (M,) in [0, P), camera (M,), xy (M, 2) normalised;
    time (M,) capture frame; timed (M,) bool: the observation has a time in the capture (the
    wand's ends; point tracks where there is no wand, or where they are in the wand's time:
    :func:`in_wand_time`)."""

    point: np.ndarray
    camera: np.ndarray
    xy: np.ndarray
    time: np.ndarray
    timed: np.ndarray
    n_points: int

    def without(self, drop: np.ndarray) -> Views:
        """The views where ``drop`` (M,) is false, points renumbered."""
        keep = ~drop
        used, point = np.unique(self.point[keep], return_inverse=True)
        return Views(point, self.camera[keep], self.xy[keep], self.time[keep], self.timed[keep], len(used))


@dataclass(frozen=True, eq=False)
class Eliminated:
    """The views with their points fitted to all cameras (poses held) and then projected out.

    views: the observations kept (outliers dropped, points of two views or more); sigma: (N,) each
    camera's noise, normalised units (NaN for a camera without views); r: (M, 2) residuals over
    their camera's sigma; J: (M, 2, 3) the point's columns, likewise; Ainv: (P, 3, 3) each point's
    inverse normal matrix; rho: (M,) each observation's redundancy; Xc: (M, 3) the point in the
    observation's camera frame, metres; kept: (M0,) bool over the views given, those kept."""

    views: Views
    sigma: np.ndarray
    r: np.ndarray
    J: np.ndarray
    Ainv: np.ndarray
    rho: np.ndarray
    Xc: np.ndarray
    kept: np.ndarray


@dataclass(frozen=True)
class Noise:
    """A camera's own noise: sigma_px, against ``others_px`` (the other cameras' median); ratio
    and its standard error; observations: how many."""

    sigma_px: float
    others_px: float
    ratio: float
    ratio_std: float
    observations: int


def in_wand_time(track_frames: np.ndarray, wand_frames: np.ndarray) -> np.ndarray:
    """(T,) bool: the point tracks at capture frames ``track_frames`` (T,) that share the wand's
    time, those within the span of its frames ``wand_frames`` (F,) (every one without a wand).
    points.csv numbers its frames on its own (docs/capture-format.md), and the importers number
    points from other recordings (easyWand's and DLTdv's background points) from the first power
    of ten above every wand frame: those have no time in the wand's capture, and a camera's pose
    when they were taken is its own (:func:`wandcal.calib.judge.faults.pose_steps.pose_step`)."""
    if not len(wand_frames):
        return np.ones(len(track_frames), bool)
    return (track_frames >= wand_frames.min()) & (track_frames <= wand_frames.max())


def views_of(labelled: WandPairs, tracks: PointTracks | None) -> Views:
    """Every wand end (both ends of every labelled pair) and every point-track observation, timed
    where it has a time in the capture (the wand's ends; the tracks :func:`in_wand_time`)."""
    parts = []
    if len(labelled):
        point, camera, xy = flatten(labelled)
        parts.append((point, camera, xy, labelled.frames[point // 2], True, 2 * len(labelled.frames)))
    if tracks is not None and len(tracks):
        timed = in_wand_time(tracks.frames, labelled.frames[labelled.frame])[tracks.track]
        parts.append((tracks.track, tracks.camera, tracks.xy, tracks.frames[tracks.track], timed, tracks.n_tracks))
    offset, cols = 0, []
    for point, camera, xy, time, has_time, n in parts:
        cols.append((point + offset, camera, xy, time, np.broadcast_to(has_time, len(point))))
        offset += n
    if not cols:
        z = np.zeros(0, np.int64)
        return Views(z, z, np.zeros((0, 2)), z, np.zeros(0, bool), 0)
    point, camera, xy, time, timed = (np.concatenate(c) for c in zip(*cols))
    views = Views(point, camera, xy, time.astype(np.int64), timed, offset)
    seen = np.bincount(point, minlength=offset)
    return views.without(seen[point] < 2)


def capped(views: Views, max_views: int) -> Views:
    """At most about ``max_views`` of the views: whole points, evenly spaced in their numbering
    (the wand's frames and the tracks come in capture order, so every part of the capture keeps
    its share). ``views`` itself when it holds no more."""
    if len(views.point) <= max_views or views.n_points == 0:
        return views
    n_keep = max(int(max_views * views.n_points / len(views.point)), 1)
    keep = np.zeros(views.n_points, bool)
    keep[np.linspace(0, views.n_points - 1, n_keep).astype(np.int64)] = True
    return views.without(~keep[views.point])


def _project(R: np.ndarray, t: np.ndarray, views: Views, X: np.ndarray, Rv: np.ndarray | None = None):
    """(Xc (M, 3), residual (M, 2) projected minus observed, proj (M, 2) the projection). Rv:
    (M, 3, 3) each view's rotation ``R[views.camera]``, where already gathered."""
    Rv = R[views.camera] if Rv is None else Rv
    Xc = np.einsum("mij,mj->mi", Rv, X[views.point]) + t[views.camera]
    proj = Xc[:, :2] / Xc[:, 2:]
    return Xc, proj - views.xy, proj


def _whitened_jacobian(rows: tuple[np.ndarray, np.ndarray, np.ndarray], proj: np.ndarray, z: np.ndarray,
                       w: np.ndarray) -> np.ndarray:
    """(M, 2, 3) the point's columns times the weights w (M,): the projection's derivative in the
    camera-frame point, (I_2 | -proj) / z, times the rotation (its ``rows`` R[0], R[1], R[2], each
    (M, 3)); row k is (R[k] - proj_k R[2]) / z."""
    s = (w / z)[:, None]
    J = np.empty((len(z), 2, 3))
    J[:, 0] = (rows[0] - proj[:, :1] * rows[2]) * s
    J[:, 1] = (rows[1] - proj[:, 1:] * rows[2]) * s
    return J


_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # a symmetric 3 x 3's six entries
_FULL = (0, 1, 2, 1, 3, 4, 2, 4, 5)  # its nine, row by row, as indices into the six


def _normal(J: np.ndarray, r: np.ndarray, point: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each point's normal matrix (P, 3, 3) and gradient (P, 3) from whitened J (M, 2, 3), r (M, 2):
    the six distinct entries of each view's J^T J summed by point, then mirrored."""
    A = np.stack([np.bincount(point, J[:, 0, i] * J[:, 0, j] + J[:, 1, i] * J[:, 1, j], n) for i, j in _UPPER], axis=1)
    b = np.stack([np.bincount(point, J[:, 0, i] * r[:, 0] + J[:, 1, i] * r[:, 1], n) for i in range(3)], axis=1)
    return A[:, _FULL].reshape(n, 3, 3), b


def _symmetric_inverse(A: np.ndarray) -> np.ndarray:
    """(P, 3, 3) the inverses of symmetric positive (semi)definite A (P, 3, 3) by cofactors over the
    determinant (the same inverse as an LU's to rounding where A is well conditioned; the ridge
    :func:`_fit` adds keeps it finite where it is not)."""
    a, b_, c = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    d, e, f = A[:, 1, 1], A[:, 1, 2], A[:, 2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b_ * f, b_ * e - c * d
    c11, c12, c22 = a * f - c * c, b_ * c - a * e, a * d - b_ * b_
    inv_det = 1 / (a * c00 + b_ * c01 + c * c02)
    six = np.stack([c00, c01, c02, c11, c12, c22], axis=1) * inv_det[:, None]
    return six[:, _FULL].reshape(len(A), 3, 3)


def _redundancy(J: np.ndarray, Ainv: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(M,) each view's redundancy 2 - trace(J Ainv J^T), J (M, 2, 3) whitened, Ainv (P, 3, 3) the
    points' inverse normal matrices (symmetric: v^T Ainv v from its six entries), point (M,)."""
    six = Ainv.reshape(len(Ainv), 9)[:, [0, 1, 2, 4, 5, 8]][point]
    trace = np.zeros(len(J))
    for k in range(2):
        v0, v1, v2 = J[:, k, 0], J[:, k, 1], J[:, k, 2]
        trace += (six[:, 0] * v0 * v0 + six[:, 3] * v1 * v1 + six[:, 5] * v2 * v2
                  + 2 * (six[:, 1] * v0 * v1 + six[:, 2] * v0 * v2 + six[:, 4] * v1 * v2))
    return 2 - trace


def _fit(R: np.ndarray, t: np.ndarray, views: Views, X: np.ndarray, sigma: np.ndarray, rounds: int = 3):
    """The points X (P, 3) refitted to all their views, weighted by 1/sigma: Gauss-Newton. Returns
    (X, Xc, whitened r, whitened J, Ainv, rho: (M,) each view's redundancy)."""
    w = 1 / sigma[views.camera]
    Rv = R[views.camera]
    rows = (np.ascontiguousarray(Rv[:, 0]), np.ascontiguousarray(Rv[:, 1]), np.ascontiguousarray(Rv[:, 2]))
    for k in range(rounds + 1):
        Xc, r, proj = _project(R, t, views, X, Rv)
        J = _whitened_jacobian(rows, proj, Xc[:, 2], w)
        r = r * w[:, None]
        A, b = _normal(J, r, views.point, views.n_points)
        # a point's normal matrix is well conditioned where two rays meet at an angle; the ridge
        # keeps a nearly parallel pair finite (it is then hardly tested, as it should be)
        Ainv = _symmetric_inverse(A + 1e-9 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(3))
        if k == rounds:
            return X, Xc, r, J, Ainv, _redundancy(J, Ainv, views.point)
        X = X - np.einsum("pij,pj->pi", Ainv, b)
    raise AssertionError("unreachable")


def _finite(views: Views, X: np.ndarray, origin: np.ndarray) -> tuple[Views, np.ndarray, np.ndarray]:
    """The views of the points X (P, 3) that are finite (a point triangulation left NaN is dropped
    with its views), and their ``origin`` (M,) indices."""
    ok = np.all(np.isfinite(X), axis=1)
    if ok.all():
        return views, X, origin
    return views.without(~ok[views.point]), X[ok], origin[ok[views.point]]


def eliminate(R: np.ndarray, t: np.ndarray, views: Views, sigma: np.ndarray | None = None,
              trim: bool = True, steps: int = 3) -> Eliminated:
    """The views' points fitted to all cameras with the poses R, t ((N, 3, 3), (N, 3)) held, each
    camera's noise by variance components, outliers (beyond :data:`TRIM_SIGMAS`) dropped. With
    ``trim`` False and ``sigma`` given, every view is kept and the sigmas are as given: a knocked
    camera's views after the knock are far off, and its step test keeps them
    (:func:`pose_step` trims under the step's model). steps: Gauss-Newton steps of each refit
    (a large rig's screen takes one: each point is seen by many cameras and starts near its fit)."""
    n_cams = len(R)
    rounds = VARIANCE_ROUNDS if trim or sigma is None else 0
    sigma = np.full(n_cams, 1e-3) if sigma is None else np.where(np.isfinite(sigma), sigma, 1e-3)
    X = triangulate_points(R, t, views.point, views.camera, views.xy, views.n_points)
    origin = np.arange(len(views.point))
    kept = np.zeros(len(views.point), bool)
    for _ in range(rounds):
        views, X, origin = _finite(views, X, origin)
        X, Xc, r, J, Ainv, rho = _fit(R, t, views, X, sigma, steps)
        e2 = np.sum(r**2, axis=1)
        count = np.bincount(views.camera, minlength=n_cams)
        scale = _robust_scale(e2, rho, views.camera, n_cams)
        sigma = np.where(count > 0, sigma * np.sqrt(scale), np.nan)
        bad = e2 > TRIM_SIGMAS**2 * np.maximum(rho, 1e-3) * np.where(count > 0, scale, 1.0)[views.camera]
        seen = np.bincount(views.point[~bad], minlength=views.n_points)
        drop = bad | (seen[views.point] < 2)
        if drop.any():
            keep_points = seen >= 2
            origin = origin[~drop]
            views = views.without(drop)
            X = X[keep_points]
    views, X, origin = _finite(views, X, origin)
    X, Xc, r, J, Ainv, rho = _fit(R, t, views, X, sigma, steps)
    kept[origin] = True
    return Eliminated(views, sigma, r, J, Ainv, rho, Xc, kept)


def unit_squares(e2: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(M,) each view's squared residual over its redundancy and over the median of chi-square
    with that many degrees of freedom (Wilson-Hilferty, within 3% at one and two): 1 in the median
    at the right sigma, whatever the view's redundancy; NaN where the redundancy is too small to say."""
    k = np.where(rho >= MIN_REDUNDANCY, rho, np.nan)
    return e2 / (k * (1 - 2 / (9 * k)) ** 3)


def _robust_scale(e2: np.ndarray, rho: np.ndarray, camera: np.ndarray, n_cams: int) -> np.ndarray:
    """(N,) each camera's variance over its current sigma^2: the median of :func:`unit_squares` (a
    minority of gross outliers, which hand-digitised sessions carry, leaves it alone); 1 without views."""
    runs, starts, counts = _sorted_by_camera(unit_squares(e2, rho), camera, n_cams)
    out = np.ones(n_cams)
    has = counts > 0
    out[has] = np.maximum(_run_medians(runs, starts[has], counts[has]), 1e-12)
    return out


def _sorted_by_camera(u: np.ndarray, camera: np.ndarray, n_cams: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(runs, starts (N,), counts (N,)): the finite values of u (M,) sorted by camera and, within
    a camera, by value; camera c's are ``runs[starts[c] : starts[c] + counts[c]]``. One sort for
    every camera, where a mask and a median per camera cost 128 passes over the views at 128."""
    ok = np.isfinite(u)
    u, camera = u[ok], camera[ok]
    order = np.lexsort((u, camera))
    counts = np.bincount(camera, minlength=n_cams)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return u[order], starts, counts


def _run_medians(runs: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Each run's median (counts > 0), as np.median gives it: the middle value, or the mean of the
    two middle values ((a + b) / 2, np.mean's sum over its count), to the last bit."""
    lo = runs[starts + (counts - 1) // 2]
    hi = runs[starts + counts // 2]
    return np.where(counts % 2 == 1, lo, (lo + hi) / 2)


def camera_noise(el: Eliminated, focal: np.ndarray) -> list[Noise | None]:
    """Each camera's own noise against the other cameras' median (None with too few views).
    focal: (N,) mean focal lengths, pixels."""
    v = el.views
    n = len(el.sigma)
    runs, starts, counts = _sorted_by_camera(unit_squares(np.sum(el.r**2, axis=1), el.rho), v.camera, n)
    rel = np.full(n, np.nan)  # each camera's sigma^2's relative standard error
    for cam in np.flatnonzero(counts >= MIN_NOISE_OBSERVATIONS):
        mine = runs[starts[cam] : starts[cam] + counts[cam]]
        m = len(mine)
        # the median's standard error from the order statistics a standard error either side of it
        lo, hi = int(np.floor(m / 2 - np.sqrt(m) / 2)), int(np.ceil(m / 2 + np.sqrt(m) / 2))
        median = float(_run_medians(mine, np.zeros(1, np.int64), np.array([m]))[0])
        rel[cam] = (mine[min(hi, m - 1)] - mine[max(lo, 0)]) / 2 / max(median, 1e-12)
    px = el.sigma * focal
    views_per = np.bincount(v.camera, minlength=n)
    out: list[Noise | None] = []
    for c in range(n):
        others = [k for k in range(n) if k != c and np.isfinite(rel[k])]
        if not np.isfinite(rel[c]) or len(others) < 2:
            out.append(None)
            continue
        ref = float(np.median(px[others]))
        ratio = float(px[c] / ref)
        # sigma's relative error is half sigma^2's; the others' median about that of their mean, times pi/2
        var = 0.25 * rel[c] ** 2 + 0.25 * float(np.mean(rel[others] ** 2)) / len(others) * np.pi / 2
        out.append(Noise(float(px[c]), ref, ratio, ratio * float(np.sqrt(var)), int(views_per[c])))
    return out


def noisy_cameras(R: np.ndarray, t: np.ndarray, views: Views, el: Eliminated, focal: np.ndarray,
                  out: list[int]) -> list[tuple[int, Noise]]:
    """The cameras whose own noise stands out, worst first, each named only while the noise of
    those named before it is left out (a point seen by two cameras shares its one degree of freedom
    between them: a noisy camera's partner looks noisy too, until it is left out); ``out``: cameras
    not to name (found at fault otherwise). el: :func:`eliminate` of ``views``."""
    found: list[tuple[int, Noise]] = []
    while True:
        standing = [(c, n) for c, n in enumerate(camera_noise(el, focal)) if n is not None and c not in out
                    and n.ratio - NOISE_LIMIT > NOISE_Z * n.ratio_std]
        if not standing:
            return found
        c, n = max(standing, key=lambda cn: (cn[1].ratio - NOISE_LIMIT) / cn[1].ratio_std)
        found.append((c, n))
        out = [*out, c]
        rest = views.without(np.isin(views.camera, [k for k, _ in found]))
        seen = np.bincount(rest.point, minlength=rest.n_points)
        rest = rest.without(seen[rest.point] < 2)
        if len(R) - len(found) < 3 or not len(rest.point):
            return found
        el = eliminate(R, t, rest, el.sigma)


def noise_at_limit(cam: str, n: Noise | None) -> dict | None:
    """A camera's own noise within :data:`NOISE_Z` standard errors of :data:`NOISE_LIMIT` but not
    beyond it by that (not named noisy, :func:`noisy_cameras`): the verdict's ``at_limit`` entry
    (wandcal.calib.judge.verdict.stability_entry's keys; value the ratio to the other cameras'
    median, std its standard error), or None when it is clear of the limit. Twice a camera's own
    noise stands at 1.1-1.7 times the others' on the real sparse sessions (decision 0058): a fault
    by the data's own measure only at the upper end, at the limit in between."""
    if n is None or not n.ratio_std > 0 or n.ratio + NOISE_Z * n.ratio_std < NOISE_LIMIT \
            or n.ratio - NOISE_LIMIT > NOISE_Z * n.ratio_std:
        return None
    return {"criterion": "own noise against the other cameras'", "camera": cam, "value": round(n.ratio, 3), "limit": NOISE_LIMIT,
            "std": round(n.ratio_std, 3), "unit": "x", "levels": ["good", "poor"],
            "own_noise_px": round(n.sigma_px, 3), "others_noise_px": round(n.others_px, 3)}


def noise_fault(cam: str, n: Noise) -> dict:
    return {"kind": "noise", "camera": cam, "evidence": {
        "own_noise_px": round(n.sigma_px, 3), "others_noise_px": round(n.others_px, 3), "ratio": round(n.ratio, 3),
        "ratio_std": round(n.ratio_std, 3)},
        "message": f"{cam}'s blob centres are {n.ratio:.1f} +- {n.ratio_std:.1f} times as noisy as the other cameras' "
                   f"({n.sigma_px:.2f} px against {n.others_px:.2f} px, each against points fitted to every camera "
                   "and weighted by its own noise) with no timing, lens or movement found: check its focus, exposure "
                   "and the blob detection settings"}
