"""Each camera's own errors, with the points eliminated: its noise, and a step in its pose (moved).

A camera's residual in the solve holds the other cameras' errors too: each point is triangulated
from two to four views, so one camera's noise is spread over the points and shows in its
neighbours' residuals, and a knocked camera's step shows in theirs. Here the points are
*eliminated* instead: with every pose held, each point is fitted to all its views (weighted by each
camera's noise), and what remains is tested with the point's three columns projected out of the
model (the Schur complement of bundle adjustment). Every observation takes part: the wand's ends,
every marker, and the point tracks, in frames seen by only two cameras too (one epipolar degree of
freedom each, where "triangulated by two others" would need three views).

- **Noise** (:func:`camera_noise`): each camera's variance of unit weight by variance components
  (Förstner): ``sigma_c^2 = sum_c |r_i|^2 / sum_c rho_i`` over its observations, ``rho_i`` their
  redundancy (2 less the hat matrix's trace), iterated with the weights; its standard error from
  the spread of the observations' contributions (the delta method of the ratio), so a heavy tail
  widens it. A camera is noisy when its sigma stands above the other cameras' median by more than
  :data:`NOISE_LIMIT`, by :data:`NOISE_Z` standard errors.
- **A step in the pose** (:func:`pose_step`): the camera's observations with a time are split at
  frame k, and its turn after k (three columns: a rotation about its centre) is fitted beside its
  pose (six columns), both with the points projected out: an F test of one pose against two at the
  best k, its p-value multiplied by the number of splits tried (Bonferroni, the search's multiple
  testing). Observations without a time (background points digitised once) go with either side,
  whichever fits: the two sides are tested as two more splits.

A camera is named only when removing it explains the disagreement (:func:`moved_faults`): with its
observations left out, no other camera shows a step; else its step is the other camera's spread
through the points. docs/verdict.md gives the limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.start.labels import flatten
from wandcal.calib.triangulate import triangulate_points

TRIM_SIGMAS = 5.0  # an observation this many of its camera's sigmas off (for its redundancy) is an outlier
MIN_BLOCKS = 4  # batch means of the residuals in time: fewer blocks say nothing of their correlation
TRIM_ROUNDS = 2  # outliers trimmed under the step's model, then the split searched again
VARIANCE_ROUNDS = 6  # variance components: the sigmas settle to within 2% by the sixth round on the real sessions
MIN_SIDE = 6  # timed views of the camera on either side of a split: three wand frames, more than the step's three columns can fit alone
MAX_SPLITS = 60  # candidate splits, evenly spaced in the camera's timed observations
# a step is named at this family-wise false-alarm rate per camera (Bonferroni over the splits): a
# clean camera is called moved once in 10,000 (the clean real sessions: p >= 0.002; the knocks found: p <= 5e-5)
STEP_ALPHA = 1e-4
# a camera's noise against the other cameras' median: 1.5 is where the verdict's noise criterion
# leaves "excellent" (wandcal.calib.judge.verdict.NOISE_RATIO); a camera is named noisy only when
# its ratio stands above it by NOISE_Z standard errors (one-sided 2%)
NOISE_LIMIT = 1.5
NOISE_Z = 2.0
MIN_NOISE_OBSERVATIONS = 30  # of a camera, for its sigma to be compared
MIN_REDUNDANCY = 0.5  # a view whose point hangs mostly on it says little of its camera's noise


@dataclass(frozen=True, eq=False)
class Views:
    """Every observation of the points: point (M,) in [0, P), camera (M,), xy (M, 2) normalised;
    time (M,) capture frame; timed (M,) bool: the observation has a time (the wand's ends; point
    tracks only where there is no wand: a moving marker, not background points digitised once)."""

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


@dataclass(frozen=True)
class Step:
    """A step in a camera's pose: after capture frame ``frame`` (or before it, ``after`` False) it
    turned by ``degrees`` (+- degrees_std) and its centre moved ``mm`` (+- mm_std, with the turn
    fitted beside it); f_stat at the best split, p_value with the split search accounted for;
    explained: the share of the camera's residual beyond its pose the step explains."""

    frame: int
    after: bool
    degrees: float
    degrees_std: float
    mm: float
    mm_std: float
    f_stat: float
    p_value: float
    explained: float


def views_of(labelled: WandPairs, tracks: PointTracks | None) -> Views:
    """Every wand end (both ends of every labelled pair) and every point-track observation."""
    parts = []
    if len(labelled):
        point, camera, xy = flatten(labelled)
        parts.append((point, camera, xy, labelled.frames[point // 2], True, 2 * len(labelled.frames)))
    if tracks is not None and len(tracks):
        parts.append((tracks.track, tracks.camera, tracks.xy, tracks.frames[tracks.track], not len(labelled),
                      tracks.n_tracks))
    offset, cols = 0, []
    for point, camera, xy, time, has_time, n in parts:
        cols.append((point + offset, camera, xy, time, np.full(len(point), has_time)))
        offset += n
    if not cols:
        z = np.zeros(0, np.int64)
        return Views(z, z, np.zeros((0, 2)), z, np.zeros(0, bool), 0)
    point, camera, xy, time, timed = (np.concatenate(c) for c in zip(*cols))
    views = Views(point, camera, xy, time.astype(np.int64), timed, offset)
    seen = np.bincount(point, minlength=offset)
    return views.without(seen[point] < 2)


def _project(R: np.ndarray, t: np.ndarray, views: Views, X: np.ndarray):
    """(Xc (M, 3), residual (M, 2) projected minus observed, D (M, 2, 3) the projection's derivative
    in the camera-frame point)."""
    Xc = np.einsum("mij,mj->mi", R[views.camera], X[views.point]) + t[views.camera]
    z = Xc[:, 2]
    proj = Xc[:, :2] / z[:, None]
    D = np.zeros((len(z), 2, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1 / z
    D[:, :, 2] = -proj / z[:, None]
    return Xc, proj - views.xy, D


def _normal(J: np.ndarray, r: np.ndarray, point: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each point's normal matrix (P, 3, 3) and gradient (P, 3) from whitened J (M, 2, 3), r (M, 2)."""
    JtJ = np.einsum("mki,mkj->mij", J, J).reshape(len(J), 9)
    Jtr = np.einsum("mki,mk->mi", J, r)
    A = np.stack([np.bincount(point, JtJ[:, k], n) for k in range(9)], axis=1).reshape(n, 3, 3)
    b = np.stack([np.bincount(point, Jtr[:, k], n) for k in range(3)], axis=1)
    return A, b


def _fit(R: np.ndarray, t: np.ndarray, views: Views, X: np.ndarray, sigma: np.ndarray, rounds: int = 3):
    """The points X (P, 3) refitted to all their views, weighted by 1/sigma: Gauss-Newton. Returns
    (X, Xc, whitened r, whitened J, Ainv, rho: (M,) each view's redundancy)."""
    w = 1 / sigma[views.camera]
    for k in range(rounds + 1):
        Xc, r, D = _project(R, t, views, X)
        J = np.einsum("mij,mjk->mik", D, R[views.camera]) * w[:, None, None]
        r = r * w[:, None]
        A, b = _normal(J, r, views.point, views.n_points)
        # a point's normal matrix is well conditioned where two rays meet at an angle; the ridge
        # keeps a nearly parallel pair finite (it is then hardly tested, as it should be)
        Ainv = np.linalg.inv(A + 1e-9 * np.trace(A, axis1=1, axis2=2)[:, None, None] * np.eye(3))
        if k == rounds:
            return X, Xc, r, J, Ainv, 2 - np.einsum("mki,mij,mkj->m", J, Ainv[views.point], J)
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
              trim: bool = True) -> Eliminated:
    """The views' points fitted to all cameras with the poses R, t ((N, 3, 3), (N, 3)) held, each
    camera's noise by variance components, outliers (beyond :data:`TRIM_SIGMAS`) dropped. With
    ``trim`` False and ``sigma`` given, every view is kept and the sigmas are as given: a knocked
    camera's views after the knock are far off, and its step test keeps them
    (:func:`pose_step` trims under the step's model)."""
    n_cams = len(R)
    rounds = VARIANCE_ROUNDS if trim or sigma is None else 0
    sigma = np.full(n_cams, 1e-3) if sigma is None else np.where(np.isfinite(sigma), sigma, 1e-3)
    X = triangulate_points(R, t, views.point, views.camera, views.xy, views.n_points)
    origin = np.arange(len(views.point))
    kept = np.zeros(len(views.point), bool)
    for _ in range(rounds):
        views, X, origin = _finite(views, X, origin)
        X, Xc, r, J, Ainv, rho = _fit(R, t, views, X, sigma)
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
    X, Xc, r, J, Ainv, rho = _fit(R, t, views, X, sigma)
    kept[origin] = True
    return Eliminated(views, sigma, r, J, Ainv, rho, Xc, kept)


def _unit(e2: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(M,) each view's squared residual over its redundancy and over the median of chi-square
    with that many degrees of freedom (Wilson-Hilferty, within 3% at one and two): 1 in the median
    at the right sigma, whatever the view's redundancy; NaN where the redundancy is too small to say."""
    k = np.where(rho >= MIN_REDUNDANCY, rho, np.nan)
    return e2 / (k * (1 - 2 / (9 * k)) ** 3)


def _robust_scale(e2: np.ndarray, rho: np.ndarray, camera: np.ndarray, n_cams: int) -> np.ndarray:
    """(N,) each camera's variance over its current sigma^2: the median of :func:`_unit` (a
    minority of gross outliers, which hand-digitised sessions carry, leaves it alone); 1 without views."""
    u = _unit(e2, rho)
    out = np.ones(n_cams)
    for c in range(n_cams):
        mine = u[(camera == c) & np.isfinite(u)]
        if len(mine):
            out[c] = max(float(np.median(mine)), 1e-12)
    return out


def camera_noise(el: Eliminated, focal: np.ndarray) -> list[Noise | None]:
    """Each camera's own noise against the other cameras' median (None with too few views).
    focal: (N,) mean focal lengths, pixels."""
    v = el.views
    n = len(el.sigma)
    u = _unit(np.sum(el.r**2, axis=1), el.rho)
    rel = np.full(n, np.nan)  # each camera's sigma^2's relative standard error
    for c in range(n):
        mine = np.sort(u[(v.camera == c) & np.isfinite(u)])
        m = len(mine)
        if m < MIN_NOISE_OBSERVATIONS:
            continue
        # the median's standard error from the order statistics a standard error either side of it
        lo, hi = int(np.floor(m / 2 - np.sqrt(m) / 2)), int(np.ceil(m / 2 + np.sqrt(m) / 2))
        rel[c] = (mine[min(hi, m - 1)] - mine[max(lo, 0)]) / 2 / max(float(np.median(mine)), 1e-12)
    px = el.sigma * focal
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
        out.append(Noise(float(px[c]), ref, ratio, ratio * float(np.sqrt(var)), int((v.camera == c).sum())))
    return out


def _rows_of(el: Eliminated, c: int):
    """Every view of the points camera c sees: (rows (K,) view indices, own (K,) c's view of each
    row's point, proj) where proj(G) takes c's columns G (K, 2, n) (whitened, zero where the row is
    not c's) to the same with the points projected out: ``G_i [i is c's] - J_i Ainv J_c^T G_c``,
    what fitting each point again takes away."""
    v = el.views
    mine = np.flatnonzero(v.camera == c)
    at = np.full(v.n_points, -1)
    at[v.point[mine]] = mine
    rows = np.flatnonzero(at[v.point] >= 0)
    own = at[v.point[rows]]
    is_own = rows == own

    def proj(G: np.ndarray) -> np.ndarray:
        u = np.einsum("kmi,kmj->kij", el.J[own], G)
        out = -np.einsum("kmi,kij,kjl->kml", el.J[rows], el.Ainv[v.point[rows]], u)
        out[is_own] += G[is_own]
        return out
    return rows, own, proj


def _pose_columns(el: Eliminated, c: int, rows: np.ndarray, own: np.ndarray, proj) -> tuple[np.ndarray, np.ndarray]:
    """Camera c's pose columns over ``rows`` (:func:`_rows_of`), whitened, the points projected out:
    (turn (K, 2, 3) about its centre, shift (K, 2, 3) of its position in its own frame)."""
    Xc = el.Xc[own]
    cross = np.zeros((len(own), 3, 3))  # d(exp(w) Xc)/dw = -[Xc]x
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 0] = Xc[:, 2], -Xc[:, 1], -Xc[:, 2]
    cross[:, 1, 2], cross[:, 2, 0], cross[:, 2, 1] = Xc[:, 0], Xc[:, 1], -Xc[:, 0]
    D = _derivative(Xc) / el.sigma[c]
    return proj(np.einsum("kij,kjl->kil", D, cross)), proj(D)


def _derivative(Xc: np.ndarray) -> np.ndarray:
    """(K, 2, 3) the normalised projection's derivative in the camera-frame point Xc (K, 3)."""
    z = Xc[:, 2]
    D = np.zeros((len(z), 2, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1 / z
    D[:, 0, 2] = -Xc[:, 0] / z**2
    D[:, 1, 2] = -Xc[:, 1] / z**2
    return D


def _fdtrc(q: int, dof: float, f: float) -> float:
    from scipy.special import fdtrc  # scipy.special only: scipy.stats costs half a second to import

    return float(fdtrc(q, dof, f))


def _lens_columns(el: Eliminated, c: int, rows: np.ndarray, own: np.ndarray, proj) -> np.ndarray:
    """(K, 2, 4) camera c's lens columns (focal length, k1, principal point) with the points projected out."""
    xy = el.Xc[own][:, :2] / el.Xc[own][:, 2:]
    r2 = np.sum(xy**2, axis=1, keepdims=True)
    G = np.stack([xy, xy * r2, np.broadcast_to([1.0, 0.0], xy.shape), np.broadcast_to([0.0, 1.0], xy.shape)],
                 axis=2) / el.sigma[c]
    return proj(G)


def pose_step(el: Eliminated, c: int) -> Step | None:
    """Camera c's best step in its pose (see the module's docstring); None with too few timed views."""
    v = el.views
    rows, own, proj = _rows_of(el, c)
    turn, shift = _pose_columns(el, c, rows, own, proj)
    lens = _lens_columns(el, c, rows, own, proj)
    y = el.r[rows]
    mine = v.camera[rows] == c
    time, timed = v.time[rows], v.timed[rows]
    times = np.sort(time[mine & timed])
    if len(times) < 2 * MIN_SIDE:
        return None
    n_rows = 2 * len(rows)
    base = [turn.reshape(n_rows, 3), shift.reshape(n_rows, 3), lens.reshape(n_rows, 4)]
    if (~timed[mine]).sum() >= MIN_SIDE:  # a pose of their own for the views without a time (see above)
        base.append(turn.reshape(n_rows, 3) * np.repeat(~timed, 2)[:, None])
    base_cols = np.concatenate(base, axis=1)
    step = turn.reshape(n_rows, 3)
    yv = y.ravel()
    candidates = np.unique(times[MIN_SIDE - 1 : len(times) - MIN_SIDE])
    if len(candidates) > MAX_SPLITS:
        candidates = candidates[np.linspace(0, len(candidates) - 1, MAX_SPLITS).astype(int)]
    keep = np.ones(len(rows), bool)
    for _ in range(TRIM_ROUNDS):
        best = _best_split(base_cols, step, yv, time, timed, candidates, keep, el.rho[rows])
        if best is None:
            return None
        keep = _kept(np.concatenate([base_cols, step * best[3]], axis=1), yv, el.rho[rows], v.point[rows])
    best = _best_split(base_cols, step, yv, time, timed, candidates, keep, el.rho[rows])
    if best is None:
        return None
    f, k, rss1, mask, rss0, dof = best
    nb = base_cols.shape[1]
    k2 = np.repeat(keep, 2)
    coef, cov = _coef(np.concatenate([base_cols, step * mask], axis=1)[k2], yv[k2], dof)
    inflation = _inflation((yv - np.concatenate([base_cols, step * mask], axis=1) @ _coef_full(base_cols, step * mask, yv, k2))
                           .reshape(-1, 2), mine & timed & keep, time, v.point[rows])
    f /= inflation[0]
    cov = cov * inflation[0]
    p = min(1.0, len(candidates) * _fdtrc(3, min(dof, inflation[1]), f))
    deg, deg_std = np.degrees(np.linalg.norm(coef[nb:])), np.degrees(np.sqrt(np.trace(cov[nb:, nb:]) / 3))
    coef, cov = _coef(np.concatenate([base_cols, step * mask, shift.reshape(n_rows, 3) * mask], axis=1)[k2], yv[k2],
                      dof - 3)
    mm, mm_std = 1000 * np.linalg.norm(coef[nb + 3:]), 1000 * np.sqrt(np.trace(cov[nb + 3:, nb + 3:]) / 3)
    return Step(k, True, float(deg), float(deg_std), float(mm), float(mm_std), float(f), float(p),
                float(1 - rss1 / rss0) if rss0 > 0 else 0.0)


def _best_split(base: np.ndarray, step: np.ndarray, y: np.ndarray, time: np.ndarray, timed: np.ndarray,
                candidates: np.ndarray, keep: np.ndarray, rho: np.ndarray):
    """The split of the largest F over ``candidates`` on the views ``keep`` (K,): (F, frame, rss
    with the step, the step's row mask (2K, 1), rss without, the residual's degrees of freedom), or
    None when too few degrees of freedom are left. base (2K, b), step (2K, 3), y (2K,)."""
    k2 = np.repeat(keep, 2)
    dof = float(rho[keep].sum()) - base.shape[1] - 3  # 2 per view, less 3 per point, less the columns
    if dof < 10:
        return None
    rss0 = _rss(base[k2], y[k2])
    best = None
    for k in candidates:
        mask = np.repeat(timed & (time > k), 2)[:, None]
        rss1 = _rss(np.concatenate([base, step * mask], axis=1)[k2], y[k2])
        f = ((rss0 - rss1) / 3) / max(rss1 / dof, 1e-300)
        if best is None or f > best[0]:
            best = (f, int(k), rss1, mask, rss0, dof)
    return best


def _kept(A: np.ndarray, y: np.ndarray, rho: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(K,) the views whose points have no view beyond :data:`TRIM_SIGMAS` of the fit of y (2K,) on A (2K, n)."""
    e2 = np.sum((y - A @ _solve(A, y)).reshape(-1, 2) ** 2, axis=1)
    u = _unit(e2, rho)
    scale = float(np.nanmedian(u)) if np.isfinite(u).any() else 1.0
    bad = e2 > TRIM_SIGMAS**2 * np.maximum(rho, 1e-3) * scale
    return ~np.isin(point, point[bad])


def _coef_full(base: np.ndarray, step: np.ndarray, y: np.ndarray, k2: np.ndarray) -> np.ndarray:
    """The coefficients of y on [base | step] fitted on the rows k2 (2K,)."""
    return _solve(np.concatenate([base, step], axis=1)[k2], y[k2])


def _solve(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares of y (K,) on A (K, n) by the scaled normal equations (n x n, n <= 20: a tall
    lstsq costs a hundred times more)."""
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    return np.linalg.lstsq(As.T @ As, As.T @ y, rcond=None)[0] / scale


def _inflation(e: np.ndarray, own: np.ndarray, time: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    """How much a step's variance grows because residuals run on in time, and the degrees of
    freedom that estimate has: (inflation, dof). A tracked marker's misfit (the lens model's, where
    it crosses the image) is alike from one frame to the next, so an F test that takes views as
    independent would see steps in a clean camera. Batch means: camera c's timed views ``own`` (K,)
    in time order, in blocks of about sqrt(K); a level's long-run variance is the block length
    times the block means' variance, over the views' own (1 for independent views; never taken
    below 1). e: (K, 2) residuals; the dof is the number of blocks less one."""
    idx = np.flatnonzero(own)
    idx = idx[np.lexsort((point[idx], time[idx]))]
    n = len(idx)
    blocks = n // max(int(np.ceil(np.sqrt(n))), 1)
    if blocks < MIN_BLOCKS:
        return 1.0, np.inf
    size = n // blocks
    a = e[idx[: blocks * size]].reshape(blocks, size, 2)
    long_run = size * float(np.mean(np.sum(a.mean(axis=1) ** 2, axis=1)))
    return max(long_run / max(float(np.mean(np.sum(a**2, axis=2))), 1e-300), 1.0), float(blocks - 1)


def _rss(A: np.ndarray, y: np.ndarray) -> float:
    """The residual sum of squares of y (K,) on the columns A (K, n), by the scaled normal equations."""
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    x = np.linalg.lstsq(As.T @ As, As.T @ y, rcond=None)[0]
    return max(float(y @ y - (As.T @ y) @ x), 0.0)


def _coef(A: np.ndarray, y: np.ndarray, dof: float) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of y (K,) on A (K, n): the coefficients and their covariance (residual variance over dof)."""
    scale = np.linalg.norm(A, axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    Ginv = np.linalg.pinv(As.T @ As)
    x = Ginv @ (As.T @ y)
    s2 = float(np.sum((y - As @ x) ** 2)) / max(dof, 1.0)
    return x / scale, s2 * Ginv / np.outer(scale, scale)


def _steps(R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated) -> list[Step | None]:
    """Every camera's best step: its own views all kept (a knocked camera's later views are far
    off; each step test trims under its own model), the other cameras' outliers as ``trimmed``
    (:func:`eliminate` of ``views``) dropped them."""
    out: list[Step | None] = []
    for c in range(len(R)):
        mine = views.camera == c
        if not mine.any():
            out.append(None)
            continue
        el = eliminate(R, t, views.without(~(trimmed.kept | mine)), trimmed.sigma, trim=False)
        out.append(pose_step(el, c) if (el.views.camera == c).any() else None)
    return out


def _found(step: Step | None) -> bool:
    return step is not None and step.p_value < STEP_ALPHA


def moved_camera(R: np.ndarray, t: np.ndarray, views: Views, trimmed: Eliminated) -> tuple[int, Step] | None:
    """The camera that moved during the capture, and its step; None when no camera's step is
    significant, or none explains the others' (with its views left out, another still steps).
    trimmed: :func:`eliminate` of ``views``."""
    steps = _steps(R, t, views, trimmed)
    found = sorted((s.p_value, c, s) for c, s in enumerate(steps) if s is not None and s.p_value < STEP_ALPHA)
    for _, c, step in found:
        rest = views.without(views.camera == c)
        seen = np.bincount(rest.point, minlength=rest.n_points)
        rest = rest.without(seen[rest.point] < 2)
        if not any(_found(s) for k, s in enumerate(_steps(R, t, rest, eliminate(R, t, rest, trimmed.sigma))) if k != c):
            return c, step
    return None


def own_error_faults(ids: list[str], R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None,
                     focal: np.ndarray) -> tuple[list[dict], list[dict]]:
    """(moved, noisy): the camera that moved during the capture, and the cameras whose own noise
    stands out (``{"kind", "camera", "message", "evidence"}``; the moved camera is not also noisy).
    ids: (N,) camera ids; R, t: (N, 3, 3), (N, 3) poses, metres; focal: (N,) mean focal lengths, pixels."""
    views = views_of(labelled, tracks)
    if not len(views.point):
        return [], []
    el = eliminate(R, t, views)
    moved = moved_camera(R, t, views, el)
    out_moved = [] if moved is None else [_moved_fault(ids[moved[0]], moved[1])]
    return out_moved, [_noise_fault(ids[c], n) for c, n in noisy_cameras(R, t, views, el, focal,
                                                                           [] if moved is None else [moved[0]])]


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


def _moved_fault(cam: str, s: Step) -> dict:
    return {"kind": "moved", "camera": cam, "evidence": {
        "frame": s.frame, "degrees": round(s.degrees, 3), "degrees_std": round(s.degrees_std, 3),
        "centre_mm": round(s.mm, 2), "centre_std_mm": round(s.mm_std, 2), "f_stat": round(s.f_stat, 1),
        "p_value": float(f"{s.p_value:.3g}"), "explained_share": round(s.explained, 3)},
        "message": f"{cam} moved during the capture: after frame {s.frame} it is turned by {s.degrees:.2f} +- "
                   f"{s.degrees_std:.2f} degrees against its pose before (its centre {s.mm:.0f} +- {s.mm_std:.0f} mm), "
                   f"where the other cameras agree; fix its mount and calibrate again, or re-solve it from the frames "
                   f"after {s.frame} alone (keep only those of {cam}'s rows and run calibrate --from RESULT "
                   f"--solve-only {cam})"}


def _noise_fault(cam: str, n: Noise) -> dict:
    return {"kind": "noise", "camera": cam, "evidence": {
        "own_noise_px": round(n.sigma_px, 3), "others_noise_px": round(n.others_px, 3), "ratio": round(n.ratio, 3),
        "ratio_std": round(n.ratio_std, 3)},
        "message": f"{cam}'s blob centres are {n.ratio:.1f} +- {n.ratio_std:.1f} times as noisy as the other cameras' "
                   f"({n.sigma_px:.2f} px against {n.others_px:.2f} px, each against points fitted to every camera "
                   "and weighted by its own noise) with no timing, lens or movement found: check its focus, exposure "
                   "and the blob detection settings"}
