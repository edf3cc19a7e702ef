"""A sequential test that names a camera that moved: a window-limited generalised likelihood ratio
(GLR) on each camera's pose change, and a fit that tells a slow drift from a knock.

Each window w of a camera gives the normal equations (g_w, H_w) of its residuals in a small change
p of its pose (:mod:`wandcal.calib.watch.health`) and its own residual variance s_w^2 (about the
window's fit, shrunk toward the baseline's by :data:`PRIOR_DOF`). Windows are weighted by 1 / s_w^2
(a window whose blobs are noisier, e.g. many markers' images merged, counts for less). The first
:data:`BASELINE_WINDOWS` windows fix the camera's reference p_0 (its standing pose's own small error
shows there) and its covariance I_0^+. After that, for every start k among the last
:data:`GLR_WINDOWS` windows, the change since k is ``d_k = I_k^+ G_k - p_0`` (I_k, G_k: H / s^2 and
g / s^2 summed from k on), with covariance ``I_k^+ + I_0^+``; with no change ``S_k = d_k^T cov^+ d_k``
is chi-square with 6 degrees of freedom. The test alarms when some ``S_k`` passes
:data:`GLR_THRESHOLD`, the change moves the camera's images by :data:`MIN_SHIFT_PX` or more (a
change too small to matter, however sure, is no alarm), and the change **persists**: its windows'
first half and last half, each of :data:`PERSIST_WINDOWS` windows or more, each show a change past
the same threshold on their own: the alarm's statistic is
``min(S_k, S of the first half, S of the last half)``. The k of the largest S_k (persistent or not) is when it moved.

Why the persistence: in clean simulated takes the alarms were not a slow creep but bursts of one to
three windows (10-30 frames) in which a few residuals of high leverage (merged or near-merged
markers' images) are off together, often with the window's residual rms up from 0.33 to 0.40-0.43
px: 24 alarms in 100,000 frames at chi2_6 > 50. A knock stays; a burst does not (decision 0054).

The threshold: 100,000 frames of 12 cameras are 120,000 camera-windows, each testing 30 starts;
P(chi2_6 > 50) = 3e-9 leaves ~0.01 false alarms in all of them were the tests independent (they are
not: neighbouring starts share data, so fewer). bench/bench_watch.py counts them in 100,000 clean frames.

Drift or knock: after an alarm the change's windows are fitted by a ramp from s to e and constant
after it, ``d_w = a clip((w - s) / (e - s), 0, 1)`` over a grid of s and e (e = s is a step); a
best fit longer than :data:`KNOCK_FRAMES` whose step fits worse by :data:`DRIFT_MARGIN` is a drift.
s runs from :data:`GLR_WINDOWS` before the GLR's k to the alarm's window: a knock late in a window
shows little there (its moved residuals fall outside that window's fit), the GLR's k may be that
window, and a step held to start there lost to a ramp over it (a real camera turned 1 deg named as
drifting; decision 0063).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.watch.health import PARAMS, WINDOW_FRAMES, solve_pose_change

BASELINE_WINDOWS = 20  # 200 frames: the reference pose change and sigma, ~8000 residuals
GLR_WINDOWS = 30  # starts tested: a change up to 300 frames old (the detection goal)
GLR_THRESHOLD = 50.0  # chi2_6 tail 3e-9: see the module's note
MIN_SHIFT_PX = 0.05  # a change that moves the camera's images less than this (rms) is not reported
PERSIST_WINDOWS = 3  # each half of an alarm's change spans this many windows or more: longer than the 1-3 window
#                      bursts of clean takes; a 0.2 deg knock is named ~35 frames after it, inside the goal's 300
PEAK_FLOOR = 20.0  # starts with S_k past this (chi2_6 tail 3e-3) are checked for persistence: the margin's floor
WANDER_BLOCK = 5  # windows a block: the baseline's 20 give 4 blocks, 50 frames each, to see the pose wander
PRIOR_DOF = 50  # a window's residual variance is shrunk toward the baseline's as if by this many residuals
#                 (~750 in a window of 40 markers: barely; a window of few markers: its variance not trusted alone)
KNOCK_FRAMES = 2 * WINDOW_FRAMES  # a move completed within this is a knock
DRIFT_MARGIN = 25.0  # chi2 units: the ramp must fit this much better than the best step to be a drift
RCOND = 1e-10


@dataclass
class Alarm:
    """A camera found moved. camera: its index; window: the test's window index of the alarm;
    frame: the first frame of the window it moved in; statistic: max_k S_k; change: (6,) the pose
    change since it moved (omega radians, dC metres); detected_frame: the last frame of the alarm's window;
    one_of: the other cameras the take cannot tell from this one as the one that moved (none: it is named
    alone; :mod:`wandcal.calib.watch.attribute`); settled: named by the attribution's second look (its test
    has no markers of the group it was weighed with from the alarm on, so its knock is dated at ``frame``)."""

    camera: int
    frame: int
    detected_frame: int
    statistic: float
    change: np.ndarray
    one_of: tuple[int, ...] = ()
    settled: bool = False

    @property
    def rotation_deg(self) -> float:
        return float(np.degrees(np.linalg.norm(self.change[:3])))

    @property
    def translation_mm(self) -> float:
        return float(np.linalg.norm(self.change[3:]) * 1000)


@dataclass
class CameraTest:
    """The running test of one camera: its baseline and its windows' normal equations."""

    g: list[np.ndarray] = field(default_factory=list)  # every window's (6,) g
    H: list[np.ndarray] = field(default_factory=list)  # every window's (6, 6) H
    sse: list[float] = field(default_factory=list)
    n: list[float] = field(default_factory=list)
    start: list[int] = field(default_factory=list)  # every window's first frame
    alarm: Alarm | None = None
    peak: float = 0.0  # the largest S_k of a persistent change seen (a clean take's margin below the threshold)
    raw: float = 0.0  # the last :meth:`glr`'s largest S_k, persistent or not (which camera moved, when several alarm)
    since: int = 0  # the first window a change may start at (a camera cleared by the attribution: after its windows then)
    _wander: np.ndarray | None = field(default=None, repr=False)  # :meth:`wander`, once the baseline is in
    _base: tuple[np.ndarray, np.ndarray, float, np.ndarray] | None = field(default=None, repr=False)  # baseline + I_0^+

    def add(self, g: np.ndarray, H: np.ndarray, sse: float, n: float, start: int) -> None:
        self.g.append(g)
        self.H.append(H)
        self.sse.append(sse)
        self.n.append(n)
        self.start.append(start)

    def mark(self) -> int:
        """How many windows the test holds (for :meth:`rewind`)."""
        return len(self.g)

    def rewind(self, windows: int) -> None:
        """Forget every window after the first ``windows`` (the caller raises no alarm in between)."""
        for values in (self.g, self.H, self.sse, self.n, self.start):
            del values[windows:]
        if windows < BASELINE_WINDOWS:
            self._wander = self._base = None

    def baseline(self) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(p_0 (6,), I_0 (6, 6) (px^-2 weighted information), sigma^2 px^2 pooled) once
        :data:`BASELINE_WINDOWS` windows are in."""
        if len(self.g) < BASELINE_WINDOWS:
            return None
        if self._base is None:  # its windows do not change once in (but by :meth:`rewind`)
            s2 = self._pooled_variance(BASELINE_WINDOWS)
            wt = self._weights(0, BASELINE_WINDOWS, s2)
            I0 = np.einsum("w,wij->ij", wt, np.array(self.H[:BASELINE_WINDOWS]))
            p0 = solve_pose_change(I0, np.einsum("w,wi->i", wt, np.array(self.g[:BASELINE_WINDOWS])))
            self._base = (p0, I0, s2, _pinv(I0))
        return self._base[:3]

    def _baseline_cov(self) -> np.ndarray:
        """(6, 6) I_0^+ (once :meth:`baseline` is in)."""
        assert self._base is not None
        return self._base[3]

    def _pooled_variance(self, windows: int) -> float:
        n = np.array(self.n[:windows])
        dof = max(float(np.maximum(2 * n - PARAMS, 0).sum()), 1.0)  # a window its fit takes whole leaves none
        return float(np.sum(self.sse[:windows]) / dof)

    def _weights(self, first: int, end: int, s2: float) -> np.ndarray:
        """(end - first,) 1 / s_w^2 of windows first..end-1, px^-2: each window's own residual
        variance about its fit, shrunk toward the baseline's ``s2`` by :data:`PRIOR_DOF`."""
        n = np.array(self.n[first:end])
        dof = np.maximum(2 * n - PARAMS * (n > 0), 0.0)
        return (dof + PRIOR_DOF) / (np.array(self.sse[first:end]) + PRIOR_DOF * s2)

    def wander(self, base: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
        """(6, 6) how far the camera's apparent pose wanders on a clean take beyond its noise, as a
        covariance: lambda (I_0 / n_0)^+, lambda (px^2) the image shift of the baseline's blocks of
        :data:`WANDER_BLOCK` windows about their mean that their own noise does not explain (0 when
        it explains it all). Real takes need it: a camera model a little off (its lens, the others'
        triangulation) shows as a pose that depends on where in the image the markers are, and a
        test on noise alone names that as a move when the markers go elsewhere (bench_watch_real)."""
        if self._wander is None:
            p0, I0, _ = base
            s2 = self._pooled_variance(BASELINE_WINDOWS)
            wt = self._weights(0, BASELINE_WINDOWS, s2)
            H, g = np.array(self.H[:BASELINE_WINDOWS]) * wt[:, None, None], np.array(self.g[:BASELINE_WINDOWS]) * wt[:, None]
            blocks = np.arange(BASELINE_WINDOWS) // WANDER_BLOCK
            Ib = np.array([H[blocks == b].sum(0) for b in np.unique(blocks)])
            gb = np.array([g[blocks == b].sum(0) for b in np.unique(blocks)])
            n0 = max(float(np.sum(self.n[:BASELINE_WINDOWS])), 1.0)
            per = I0 / n0  # information of one residual, px^-2 (weighted)
            lam = between_blocks(Ib, gb, per)
            self._wander = lam * np.linalg.pinv(per, rcond=RCOND, hermitian=True)
        return self._wander

    def _change(self, first: int, end: int, base: tuple[np.ndarray, np.ndarray, float]) -> float:
        """S of the change since the baseline over windows first..end-1 alone."""
        p0, _, s2 = base
        wt = self._weights(first, end, s2)
        Iw_inv = _pinv(np.einsum("w,wij->ij", wt, np.array(self.H[first:end])))
        d = np.einsum("ij,j->i", Iw_inv, np.einsum("w,wi->i", wt, np.array(self.g[first:end]))) - p0
        cov = Iw_inv + self._baseline_cov() + self.wander(base)
        return float(d @ _pinv(cov) @ d)

    def _persistent(self, k: int, end: int, base: tuple[np.ndarray, np.ndarray, float]) -> float:
        """The smaller S of the change since window k over its first half and its last half apart
        (each :data:`PERSIST_WINDOWS` windows or more; 0 when the windows are too few)."""
        if end - k < 2 * PERSIST_WINDOWS:
            return 0.0
        mid = k + (end - k) // 2
        return min(self._change(k, mid, base), self._change(mid, end, base))

    def statistic_of(self, change: np.ndarray, first: int) -> float:
        """The statistic a pose change ``change`` (6,) alone would give over windows ``first``.. (noise-free:
        the non-centrality of :meth:`glr`'s S at start ``first``, with its covariance; an unnamed move
        below the threshold by this is below what the camera's noise and wander let the test see)."""
        base = self.baseline()
        if base is None or first >= len(self.g):
            return 0.0
        cov = self._change_cov(first, len(self.g), base)
        return float(change @ _pinv(cov) @ change)

    def _change_cov(self, first: int, end: int, base: tuple[np.ndarray, np.ndarray, float]) -> np.ndarray:
        """(6, 6) the covariance of a change since the baseline fitted over windows first..end-1: that
        fit's own, the baseline's and the pose's wander (as :meth:`_change` adds them)."""
        wt = self._weights(first, end, base[2])
        return _pinv(np.einsum("w,wij->ij", wt, np.array(self.H[first:end]))) + self._baseline_cov() + self.wander(base)

    def smallest_turn_deg(self) -> float:
        """Degrees: the smallest turn about the camera's centre, along its worst axis, that the test names
        as often as not over the take's last :data:`GLR_WINDOWS` windows: the turn whose non-centrality
        (:meth:`statistic_of`, the smaller of the whole span's and each half's, as the alarm needs each
        to pass) is :func:`median_detected`. "This take can see turns of X deg or more on this camera";
        a smaller one is below what its noise and wander let any test at this false-alarm rate see.
        NaN before the test has a span after its baseline of :data:`PERSIST_WINDOWS` windows a half."""
        base = self.baseline()
        end = len(self.g)
        first = max(BASELINE_WINDOWS, end - GLR_WINDOWS)
        if base is None or end - first < 2 * PERSIST_WINDOWS:
            return float("nan")
        mid = first + (end - first) // 2
        weakest = np.inf
        for lo, hi in ((first, end), (first, mid), (mid, end)):
            cov = self._change_cov(lo, hi, base)
            weakest = min(weakest, float(np.linalg.eigvalsh(_pinv(cov)[:3, :3])[0]))  # per rad^2, the worst axis
        return float(np.degrees(np.sqrt(median_detected() / weakest))) if weakest > 0 else float("inf")

    def glr(self, last: int | None = None) -> tuple[float, int, np.ndarray]:
        """(the largest S_k of a persistent change, the k of the largest S_k, d_k (6,)) over the
        starts before window ``last`` (all windows by default); the module's note."""
        base = self.baseline()
        end = len(self.g) if last is None else last
        first = max(BASELINE_WINDOWS, end - GLR_WINDOWS, self.since)
        if base is None or end <= first:
            return 0.0, end, np.zeros(PARAMS)
        p0, _, s2 = base
        wt = self._weights(first, end, s2)
        G = np.cumsum((np.array(self.g[first:end]) * wt[:, None])[::-1], axis=0)[::-1]  # G[k]: windows k.. summed
        Ik = np.cumsum((np.array(self.H[first:end]) * wt[:, None, None])[::-1], axis=0)[::-1]
        Ik_inv = _pinv(Ik)
        d = np.einsum("kij,kj->ki", Ik_inv, G) - p0
        cov = Ik_inv + self._baseline_cov() + self.wander(base)
        S = np.einsum("ki,kij,kj->k", d, _pinv(cov), d)
        Hk = np.cumsum(np.array(self.H[first:end])[::-1], axis=0)[::-1]
        count = np.cumsum(np.array(self.n[first:end])[::-1])[::-1]  # residuals from each start on
        shift = np.sqrt(np.einsum("ki,kij,kj->k", d, Hk, d) / np.maximum(count, 1))  # rms image move, px
        S = np.where(shift >= MIN_SHIFT_PX, S, 0.0)
        k = int(np.argmax(S))
        self.raw = float(S[k])
        # min(S_k, its halves' S): past GLR_THRESHOLD is an alarm; below it, a clean take's margin
        alarm = max((min(float(S[i]), self._persistent(first + int(i), end, base)) for i in np.flatnonzero(S > PEAK_FLOOR)),
                    default=0.0)
        self.peak = max(self.peak, alarm)
        return alarm, first + k, d[k]


def between_blocks(Ib: np.ndarray, gb: np.ndarray, per: np.ndarray) -> float:
    """lambda >= 0: the variance between blocks' poses beyond their noise, as the image shift of one
    residual (``lambda per^+``), by the Paule-Mandel (Q-profile) moment estimator: the lambda at which
    the blocks' scatter about their mean, each block weighted by the inverse of its noise and the
    wander, ``(Ib^+ + lambda per^+)^-1``, equals its degrees of freedom (the blocks' ranks less
    :data:`PARAMS`); 0 when their noise explains it all. Ib (B, 6, 6), gb (B, 6): the blocks'
    weighted normal equations; per (6, 6): one residual's information. A block with a few residuals
    (a rank-deficient Ib) counts for what it fixes: its weight is ``Ib - Ib (Ib + per / lambda)^-1 Ib``."""
    scale = np.abs(Ib).max(axis=(1, 2), initial=0.0)
    ranks = [int((np.linalg.eigvalsh(block) > RCOND * m).sum()) if m > 0 else 0 for block, m in zip(Ib, scale)]
    dof = sum(ranks) - PARAMS
    if dof <= 0:
        return 0.0
    base = float(np.einsum("bi,bij,bj->", gb, _pinv(Ib), gb))  # sum of gb Ib^+ gb

    def scatter(lam: float) -> float:  # the weighted scatter Q(lambda)
        M = _pinv(Ib + per / lam) if lam > 0 else np.zeros_like(Ib)
        V = Ib - Ib @ M @ Ib  # each block's weight
        u = gb - np.einsum("bij,bjk,bk->bi", Ib, M, gb)  # V_b p_b
        mean = _pinv(V.sum(0)) @ u.sum(0)
        return base - float(np.einsum("bi,bij,bj->", gb, M, gb)) - 2 * mean @ u.sum(0) + mean @ V.sum(0) @ mean

    if scatter(0.0) <= dof:
        return 0.0
    lo, hi = 0.0, 1.0
    for _ in range(60):  # Q falls with lambda: bracket, then bisect
        if scatter(hi) <= dof:
            break
        lo, hi = hi, 4 * hi
    for _ in range(50):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if scatter(mid) > dof else (lo, mid)
    return hi


@functools.cache
def median_detected() -> float:
    """The non-centrality at which S, non-central chi-square with :data:`PARAMS` degrees of freedom,
    passes :data:`GLR_THRESHOLD` half the time (~44.8): a move whose own statistic is below it is
    missed more often than named, at the false-alarm rate the threshold holds."""
    from scipy.optimize import brentq
    from scipy.stats import ncx2

    return float(brentq(lambda nc: ncx2.sf(GLR_THRESHOLD, PARAMS, nc) - 0.5, 1e-6, 10 * GLR_THRESHOLD))


def _pinv(A: np.ndarray) -> np.ndarray:
    """The pseudo-inverse of symmetric A (..., 6, 6), as :func:`solve_pose_change` takes it (rcond :data:`RCOND`)."""
    return np.linalg.pinv(A, rcond=RCOND, hermitian=True)


def classify(test: CameraTest, alarm: Alarm) -> tuple[str, int, int, np.ndarray]:
    """("knock" or "drift", first frame, frames the move took, (6,) the full change) of an alarmed
    camera, from every window it has (the module's note)."""
    base = test.baseline()
    assert base is not None
    p0 = base[0]
    n_w = len(test.g)
    g = np.array(test.g[BASELINE_WINDOWS:])
    H = np.array(test.H[BASELINE_WINDOWS:])
    k_alarm = test.start.index(alarm.frame) - BASELINE_WINDOWS
    # the window the alarm was raised in: a move starts no later, but may start after the GLR's k (a
    # window the move began in late shows it little: its moved residuals fall outside the window's fit)
    k_det = int(np.flatnonzero(np.array(test.start[BASELINE_WINDOWS:]) <= alarm.detected_frame)[-1])
    w = np.arange(n_w - BASELINE_WINDOWS, dtype=float)
    gd = g - np.einsum("wij,j->wi", H, p0)  # normal equations of the change since the baseline
    durations = np.unique(np.r_[0, np.round(np.geomspace(1, max(2 * len(w), 2), 16))]).astype(int)
    best: tuple[float, int, int, np.ndarray] = (-np.inf, 0, 0, np.zeros(PARAMS))
    step = best
    for s in range(max(0, k_alarm - GLR_WINDOWS), max(k_alarm, k_det) + 1):
        for dur in durations:
            rho = np.clip((w - s + 1) / max(dur, 1), 0, 1) if dur else (w >= s).astype(float)
            A = np.einsum("w,wij->ij", rho ** 2, H)
            b = np.einsum("w,wi->i", rho, gd)
            a = solve_pose_change(A, b)
            gain = float(a @ b)  # the fit's reduction of the residual sum of squares, px^2
            if gain > best[0]:
                best = (gain, s, int(dur), a)
            if dur == 0 and gain > step[0]:
                step = (gain, s, 0, a)
    gain, s, dur, a = best
    frames = dur * WINDOW_FRAMES
    drift = frames > KNOCK_FRAMES and (gain - step[0]) / _scatter(base[2], H, gd, step[0]) > DRIFT_MARGIN
    if frames > KNOCK_FRAMES and not drift:  # a knock: when it moved and by how much, the best step's
        _, s, dur, a = step
    return ("drift" if drift else "knock"), test.start[BASELINE_WINDOWS + s], frames if drift else 0, a


def _scatter(s2: float, H: np.ndarray, gd: np.ndarray, explained: float) -> float:
    """px^2: the variance a model of the windows' pose changes is judged against: the residuals' own
    ``s2``, scaled by the windows' scatter about the model when they scatter more (the reduced
    chi-square of the lack of fit, as in a quasi-likelihood or Birge-ratio test). ``H`` (W, 6, 6),
    ``gd`` (W, 6): each window's normal equations of the change since the baseline; ``explained``: the
    model's gain, px^2. Each window's own fit gains ``gd_w^T H_w^+ gd_w``; what the model leaves of
    their sum, over the windows' ranks less :data:`PARAMS`, is the scatter per degree of freedom. On a
    real take the camera's apparent pose wanders window to window beyond the blobs' noise (a camera
    model a little off, :meth:`CameraTest.wander`), and a ramp bent to that wander beat a step by
    more than :data:`DRIFT_MARGIN` noise units (a real camera turned 0.3 deg named as drifting from
    the baseline's end, decision 0079); in a simulated take the ratio is ~1 and nothing changes."""
    per_window = float(np.einsum("wi,wij,wj->", gd, _pinv(H), gd))
    scale = np.abs(H).max(axis=(1, 2), initial=0.0)
    dof = sum(int((np.linalg.eigvalsh(h) > RCOND * m).sum()) for h, m in zip(H, scale) if m > 0) - PARAMS
    if dof <= 0:
        return s2
    return s2 * max((per_window - explained) / s2 / dof, 1.0)
