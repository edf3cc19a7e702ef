"""A camera that moved during the capture: a step in its pose, with the points eliminated
(:mod:`wandcal.calib.judge.faults.own_errors`).

The camera's views with a time (the wand's ends; point tracks in the wand's time,
or all of them where there is no wand: :func:`wandcal.calib.judge.faults.own_errors.in_wand_time`)
are split at frame k, and its turn after k (three columns: a rotation about its centre) is
fitted beside its pose (six columns) and every camera's lens (four each, on that camera's views:
:func:`wandcal.calib.judge.faults.step_columns.every_lens`; another camera's lens error is a pattern in space, not a knock), all with the
points projected out; views without a time (background points from another recording) have a
turn of their own. An F test of one pose against two at the best k (:func:`pose_step`), outliers trimmed under the two-pose model, the F
measured against the timed views' own scatter (:func:`_timed_dispersion`) and divided by the
residuals' long-run variance in time (batch means), its p-value multiplied by the number of splits
tried (Bonferroni, the search's multiple testing). Which camera is named, from every
camera's test: :mod:`wandcal.calib.judge.faults.moved`. The turn the test can name at its split:
:func:`detectable_turn` (decision 0083). docs/verdict.md gives the limits, docs/decisions/0035, 0062 and 0076 how they
were measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.judge.faults.f_distribution import critical_f, f_survival
from wandcal.calib.judge.faults.own_errors import TRIM_SIGMAS, Eliminated, unit_squares
from wandcal.calib.judge.faults.step_columns import MIN_SIDE, every_lens, partner_columns, pose_columns, rows_of

MAX_SPLITS = 60  # candidate splits, evenly spaced in the camera's timed observations
TRIM_ROUNDS = 2  # outliers trimmed under the step's model, then the split searched again
MIN_BLOCKS = 4  # batch means of the residuals in time: fewer blocks say nothing of their correlation (shorter blocks then)
# a step is named at this family-wise false-alarm rate per camera (Bonferroni over the splits): a
# clean camera is called moved once in 10,000 (the clean real sessions: p >= 0.002; the knocks found: p <= 5e-5)
STEP_ALPHA = 1e-4


@dataclass(frozen=True)
class Step:
    """A step in a camera's pose: after capture frame ``frame`` it
    turned by ``degrees`` (+- degrees_std) and its centre moved ``mm`` (+- mm_std, with the turn
    fitted beside it); f_stat at the best split, p_value with the split search accounted for;
    explained: the share of the camera's residual beyond its pose the step explains;
    test_dof: the F's denominator degrees of freedom, splits: the splits searched (the p-value's
    Bonferroni factor); turn (3,), deg, and turn_cov (3, 3), deg^2: the turn in the camera's frame
    and its covariance as the test scales it (what :attr:`detectable_deg` reads); inflation and
    views_dof: the batch-means factor in turn_cov and the dof the views would have were they
    independent (test_dof is the smaller of it and the batches')."""

    frame: int
    degrees: float
    degrees_std: float
    mm: float
    mm_std: float
    f_stat: float
    p_value: float
    explained: float
    test_dof: float = float("inf")
    splits: int = 0
    turn: np.ndarray | None = field(default=None, compare=False, repr=False)
    turn_cov: np.ndarray | None = field(default=None, compare=False, repr=False)
    inflation: float = 1.0
    views_dof: float = float("inf")

    @property
    def critical_f(self) -> float:
        """The F the test names at: F(3, test_dof)'s upper STEP_ALPHA / splits point (nan without splits)."""
        return critical_f(3, self.test_dof, STEP_ALPHA / self.splits) if self.splits else float("nan")

    def detectable_along(self, axis: np.ndarray) -> float:
        """The turn, degrees, about ``axis`` (3,) (camera frame) that the test names at this split
        (:func:`detectable_turn`)."""
        return detectable_turn(self.turn_cov, axis, self.critical_f)

    @property
    def detectable_deg(self) -> float:
        """The turn about the step's own axis that the test names at this split: a knock below it
        is one the data cannot tell from the camera's own scatter in time (decision 0083)."""
        return float("nan") if self.turn is None else self.detectable_along(self.turn)


def pose_step(el: Eliminated, c: int, given: tuple[int, int] | None = None, at: int | None = None) -> Step | None:
    """Camera c's best step in its pose (see the module's docstring); None with too few timed views.
    given: (camera d, frame) puts d's two poses, split at that frame, into the base
    (:func:`partner_columns`): c's step beyond what d's move explains (:func:`explained_by`);
    at: the one split tested (no search, so no Bonferroni factor), a capture frame of c's."""
    v = el.views
    rows, own, proj = rows_of(el, c)
    turn, shift = pose_columns(el, c, rows, own, proj)
    lens = every_lens(el, rows)
    y = el.r[rows]
    mine = v.camera[rows] == c
    time, timed = v.time[rows], v.timed[rows]
    times = np.sort(time[mine & timed])
    if len(times) < 2 * MIN_SIDE:
        return None
    n_rows = 2 * len(rows)
    base = [turn.reshape(n_rows, 3), shift.reshape(n_rows, 3), lens.reshape(n_rows, lens.shape[2])]
    if (~timed[mine]).sum() >= MIN_SIDE:  # a pose of their own for the views without a time (see above)
        base.append(turn.reshape(n_rows, 3) * np.repeat(~timed, 2)[:, None])
    if given is not None:
        base.append(partner_columns(el, rows, *given))
    base_cols = np.concatenate(base, axis=1)
    step = turn.reshape(n_rows, 3)
    yv = y.ravel()
    candidates = np.unique(times[MIN_SIDE - 1 : len(times) - MIN_SIDE])
    if len(candidates) > MAX_SPLITS:
        candidates = candidates[np.linspace(0, len(candidates) - 1, MAX_SPLITS).astype(int)]
    if at is not None:
        candidates = np.array([at])
    # each round's split search depends on the views kept alone, and its trim on the split found alone:
    # a round that finds the split of the one before keeps the same views, and is that round again
    searched: dict[bytes, tuple | None] = {}
    trimmed: dict[int, np.ndarray] = {}
    keep = np.ones(len(rows), bool)
    for _ in range(TRIM_ROUNDS):
        best = _search_once(searched, keep, lambda kept: _best_split(base_cols, step, yv, time, timed, candidates,
                                                                     kept, el.rho[rows]))
        if best is None:
            return None
        if best[1] not in trimmed:
            trimmed[best[1]] = _kept(np.concatenate([base_cols, step * best[3]], axis=1), yv, el.rho[rows],
                                     v.point[rows])
        keep = trimmed[best[1]]
    best = _search_once(searched, keep, lambda kept: _best_split(base_cols, step, yv, time, timed, candidates, kept,
                                                                 el.rho[rows]))
    if best is None:
        return None
    f, k, rss1, mask, rss0, dof = best
    nb = base_cols.shape[1]
    k2 = np.repeat(keep, 2)
    model = np.concatenate([base_cols, step * mask], axis=1)
    coef, cov = _coef(model[k2], yv[k2], dof)
    e = (yv - model @ _solve(model[k2], yv[k2])).reshape(-1, 2)
    inflation = _inflation(e, mine & timed & keep, time, v.point[rows])
    ratio, dof_f = 1.0, dof
    if (keep & ~timed).any():  # the step is measured against the timed views' own scatter
        s2t, dof_f = _timed_dispersion(model, e, keep, timed, el.rho[rows])
        ratio = s2t / max(rss1 / dof, 1e-300)
    f /= ratio * inflation[0]
    cov = cov * (ratio * inflation[0])
    p = min(1.0, len(candidates) * f_survival(3, min(dof, dof_f, inflation[1]), f))
    deg, deg_std = np.degrees(np.linalg.norm(coef[nb:])), np.degrees(np.sqrt(np.trace(cov[nb:, nb:]) / 3))
    w_hat, turn_cov = np.degrees(coef[nb:]), np.degrees(np.degrees(cov[nb:, nb:]))
    coef, cov = _coef(np.concatenate([base_cols, step * mask, shift.reshape(n_rows, 3) * mask], axis=1)[k2], yv[k2],
                      dof - 3)
    mm, mm_std = 1000 * np.linalg.norm(coef[nb + 3:]), 1000 * np.sqrt(np.trace(cov[nb + 3:, nb + 3:]) / 3)
    return Step(k, float(deg), float(deg_std), float(mm), float(mm_std), float(f), float(p),
                float(1 - rss1 / rss0) if rss0 > 0 else 0.0, float(min(dof, dof_f, inflation[1])), len(candidates),
                w_hat, turn_cov, float(inflation[0]), float(min(dof, dof_f)))


def _search_once(searched: dict, keep: np.ndarray, search) -> tuple | None:
    """``search(keep)`` (:func:`_best_split` on the views ``keep`` (K,)), made once for each set of
    views kept: ``searched`` holds the answers by ``keep``'s bytes."""
    key = keep.tobytes()
    if key not in searched:
        searched[key] = search(keep)
    return searched[key]


# moved.explained_by's tests, bound here so that a bench wrapping pose_step (bench_real_subsamples.StepRecorder:
# each camera's own tests) does not take them for a camera's own
given_step = pose_step


def _timed_dispersion(A: np.ndarray, e: np.ndarray, keep: np.ndarray, timed: np.ndarray, rho: np.ndarray) -> tuple[float, float]:
    """The residual variance of the kept timed views alone, and its degrees of freedom: (s2, dof).
    A (2K, n) the step model's columns (whitened, points projected out), e (K, 2) its residuals on
    every view, keep and timed (K,) bool, rho (K,) each view's redundancy with its point fitted.
    dof: the timed views' redundancy less the columns' leverage on their rows (the diagonal of
    A (A^T A)^-1 A^T over the kept rows, summed over the timed ones).

    Why: a step's columns live on the timed views only, so its F is their scatter's to judge. Where
    a camera has a few wand frames beside hundreds of background points (Brown's hand-digitised
    sessions: 12-18 timed views against 130-370 untimed), the pooled variance is the background's
    and its degrees of freedom are the background's too: a turn fitted to three or four wand frames
    was tested at F(3, 500-1000) (decision 0062)."""
    k2 = np.repeat(keep, 2)
    scale = np.linalg.norm(A[k2], axis=0)
    scale[scale == 0] = 1.0
    As = A / scale
    Ginv = np.linalg.pinv(As[k2].T @ As[k2])
    t = keep & timed
    t2 = np.repeat(t, 2)
    lev = float(np.einsum("ri,ij,rj->", As[t2], Ginv, As[t2]))
    dof_t = max(float(rho[t].sum()) - lev, 1.0)
    return float(np.sum(e[t] ** 2)) / dof_t, dof_t


def _best_split(base: np.ndarray, step: np.ndarray, y: np.ndarray, time: np.ndarray, timed: np.ndarray,
                candidates: np.ndarray, keep: np.ndarray, rho: np.ndarray):
    """The split of the largest F over ``candidates`` on the views ``keep`` (K,): (F, frame, rss
    with the step, the step's row mask (2K, 1), rss without, the residual's degrees of freedom), or
    None when too few degrees of freedom are left. base (2K, b), step (2K, 3), y (2K,).

    Every split's normal equations from one pass (suffix sums over the views in time order of the
    step columns' products with the base, themselves and y), then solved as :func:`_rss` solves
    them: a split costs a (b + 3)^2 system, not a pass over the 2K rows (a 16-camera rig's camera
    has 40,000 rows of the points it sees, 60 splits and three trims)."""
    k2 = np.repeat(keep, 2)
    dof = float(rho[keep].sum()) - base.shape[1] - 3  # 2 per view, less 3 per point, less the columns
    if dof < 10:
        return None
    B, yk = base[k2], y[k2]
    nb = B.shape[1]
    G00, b0, yy = B.T @ B, B.T @ yk, float(yk @ yk)
    rss0 = _rss(B, yk)
    at = np.flatnonzero(keep & timed)
    at = at[np.argsort(time[at], kind="stable")]
    rows = np.stack([2 * at, 2 * at + 1], axis=1).ravel()
    Sr = step[rows]
    # per view (summed over its two rows): step^T [base | step | y], then suffix sums in time order
    # (the two rows' products added in one einsum, the sums run along the last, contiguous axis:
    # the same additions in the same order as a sum over the rows and a cumsum down the views)
    both = np.concatenate([base[rows], Sr, y[rows, None]], axis=1)
    prod = np.einsum("vmi,vmj->ijv", Sr.reshape(len(at), 2, 3), both.reshape(len(at), 2, nb + 4))
    suffix = np.zeros((3, nb + 4, len(at) + 1))
    np.cumsum(prod[:, :, ::-1], axis=2, out=suffix[:, :, : len(at)][:, :, ::-1])
    suffix = suffix.transpose(2, 0, 1)
    first = np.searchsorted(time[at], candidates, side="right")
    rss1 = _split_rss(G00, b0, yy, suffix[first], nb)
    f = ((rss0 - rss1) / 3) / np.maximum(rss1 / dof, 1e-300)
    best = None
    if len(candidates):
        i = int(np.argmax(f))
        best = (float(f[i]), int(candidates[i]), float(rss1[i]), None, rss0, dof)
    if best is None:
        return None
    mask = np.repeat(timed & (time > best[1]), 2)[:, None]
    return (best[0], best[1], best[2], mask, best[4], best[5])


def _split_rss(G00: np.ndarray, b0: np.ndarray, yy: float, sums: np.ndarray, nb: int) -> np.ndarray:
    """Every split's residual sum of squares with its step columns beside the base, (S,): the base's
    normal equations G00 (nb, nb), b0 (nb,) and y^T y = yy, and each split's step sums (S, 3, nb + 4)
    (step^T [base | step | y] over the views after it). The base is factored once (scaled, its
    pseudo-inverse cut as :func:`numpy.linalg.lstsq` cuts singular values) and each split adds its
    three columns by their Schur complement: a (3, 3) system a split, not an (nb + 3)^2 one (the
    base holds every camera's lens columns, decision 0076: ~520 wide at 128 cameras)."""
    s0 = np.sqrt(np.maximum(np.diag(G00), 0.0))
    s0[s0 == 0] = 1.0
    w, V = np.linalg.eigh(G00 / np.outer(s0, s0))
    ok = w > np.finfo(float).eps * len(w) * max(float(w.max(initial=0.0)), 0.0)
    P = (V[:, ok] / w[ok]) @ V[:, ok].T
    b0s = b0 / s0
    x0 = P @ b0s
    rss0 = yy - float(b0s @ x0)
    C = sums[:, :, :nb] / s0  # (S, 3, nb) the step columns' products with the scaled base
    schur = sums[:, :, nb:nb + 3] - np.einsum("sin,nm,sjm->sij", C, P, C, optimize=True)
    r = sums[:, :, nb + 3] - C @ x0
    s1 = np.sqrt(np.maximum(np.einsum("sii->si", schur), 0.0))
    s1[s1 == 0] = 1.0
    rs = r / s1
    gain = np.einsum("si,sij,sj->s", rs, np.linalg.pinv(schur / (s1[:, :, None] * s1[:, None, :]), rcond=1e-12), rs)
    return np.maximum(rss0 - gain, 0.0)


def _kept(A: np.ndarray, y: np.ndarray, rho: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(K,) the views whose points have no view beyond :data:`TRIM_SIGMAS` of the fit of y (2K,) on A (2K, n)."""
    e2 = np.sum((y - A @ _solve(A, y)).reshape(-1, 2) ** 2, axis=1)
    u = unit_squares(e2, rho)
    scale = float(np.nanmedian(u)) if np.isfinite(u).any() else 1.0
    bad = e2 > TRIM_SIGMAS**2 * np.maximum(rho, 1e-3) * scale
    return ~np.isin(point, point[bad])


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
    in time order, in blocks of about sqrt(K), and never fewer than :data:`MIN_BLOCKS` (shorter
    blocks then); a level's long-run variance is the block length times the block means' variance,
    over the views' own (1 for independent views; never taken below 1). e: (K, 2) residuals; the
    dof is the number of blocks less one. Fewer than 2 :data:`MIN_BLOCKS` views (two a block) say
    nothing of their correlation: (1, inf).

    Below 16 views sqrt(K) made fewer than four blocks, and the views were once taken as
    independent (dof inf): a camera of 12-15 views was tested at F(3, its timed dof), one of 16 at
    F(3, 3). Those are Brown's hand-digitised cameras of six or seven wand frames, whose clean
    subsamples stepped at p 7.5e-6 (decision 0067)."""
    idx = np.flatnonzero(own)
    idx = idx[np.lexsort((point[idx], time[idx]))]
    n = len(idx)
    if n < 2 * MIN_BLOCKS:
        return 1.0, np.inf
    blocks = max(n // max(int(np.ceil(np.sqrt(n))), 1), MIN_BLOCKS)
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


def detectable_turn(cov: np.ndarray | None, axis: np.ndarray, f_crit: float) -> float:
    """The turn, degrees, about ``axis`` (3,) that the step test names at its split (noise-free,
    50% power): the step's F is its Wald statistic over three, ``w^T Cov^-1 w / 3`` (with the timed
    scatter and the batch-means inflation the test applies), so a turn theta about the unit axis a
    reaches the critical F* (``f_crit``: F(3, dof) at STEP_ALPHA over the splits searched) at
    ``theta = sqrt(3 F* / a^T Cov^-1 a)``. cov: (3, 3) the turn's covariance, deg^2. Per axis, not
    the rms: a camera's turn about its optical axis is often far less certain than across it.
    With Brown's 7-24 shared wand frames the inflation's dof is 3 (four batches) and F* of F(3, 3)
    at 1e-5 is ~ 3000: the bound is ~ 100 standard deviations (decision 0083). nan without a
    covariance or an axis."""
    a = np.asarray(axis, float)
    if cov is None or not np.isfinite(f_crit) or not np.linalg.norm(a) > 0:
        return float("nan")
    a = a / np.linalg.norm(a)
    info = float(a @ np.linalg.pinv(cov) @ a)
    return float(np.sqrt(3 * f_crit / info)) if info > 0 else float("inf")
