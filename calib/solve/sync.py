"""Sub-frame time offsets and rate differences (drift) of cameras without a trigger.

After the whole-frame search (:mod:`wandcal.calib.start.timing`) each camera's frames are on the
reference camera's clock to within a frame. What is left is modelled per camera c as

    phi_c(f) = phase_c + drift_c (f - centre_c)        (frames)

camera c's frame numbered f showing the wand at the reference instant f + phi_c(f). The
observations are brought to the reference instants by **resampling the camera's own track in
time**: the blob of each wand end at frame ``f - phi_c(f)``, interpolated from its neighbouring
frames (a cubic through four, a line through two where the track has gaps). The wand moves
smoothly at 100 fps, so the interpolation error is far below the blob noise.

The offsets are estimated by Gauss-Newton with the cameras' poses held and the wand ends free:
each observation's residual r (observed minus projected, pixels) moves with phi by
``dr/dphi = -v`` (v the blob's image velocity, pixels a frame), and the ends, eliminated per
point (a 3x3 Schur complement each), take up what a common shift of all cameras would explain,
so the reference camera is held at phi = 0. The covariance of (phase, drift) is
sigma^2 S^-1, S the reduced normal matrix and sigma the residuals' RMS per degree of freedom:
SE(phase) ~ sigma_px / (|v|_rms sqrt(n)) (docs/sync.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.triangulate import triangulate_points

MAX_ITERATIONS = 8  # Gauss-Newton steps; from within a frame it settles in 3-4
STEP_TOLERANCE = 1e-4  # frames: far below any standard error
MAX_STEP = 1.0  # frames a step may move an offset: the interpolant's slope is trusted that far
OUTLIER_LIMIT = 4.0  # robust sigmas: an observation beyond is left out of a step (chi2 with 2 dof: 3e-4 of clean ones)
MIN_OUTLIER_PX = 1.0  # never cut closer than this, so a clean rig keeps all its observations
SMALL = 1e-9  # an instant within this of a frame is that frame
# wand frames a fit uses: at 0.3 px and 2 m/s, 800 frames fix an offset to ~0.002 frame, 25 times
# finer than needed, in a quarter of the time all 2,500 of a 16-camera capture take
MAX_FIT_FRAMES = 800


def spread_frames(n_frames: int, most: int) -> np.ndarray:
    """At most ``most`` of the frame indices 0 .. n_frames - 1, evenly spaced."""
    if n_frames <= most:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, most).round().astype(np.int64))


@dataclass(frozen=True, eq=False)
class Timing:
    """Each camera's offset model, phi_c(f) = phase[c] + drift[c] (f - centre[c]) frames.

    phase: (N,) frames; drift: (N,) frames a frame (ppm x 1e-6); centre: (N,) frame numbers;
    cov: (N, 2, 2) covariance of (phase, drift); sigma_px: the residuals' RMS per degree of
    freedom; used: (N,) observations each camera gave to the fit.
    """

    phase: np.ndarray
    drift: np.ndarray
    centre: np.ndarray
    cov: np.ndarray
    sigma_px: float
    used: np.ndarray
    iterations: int = 0

    def offset_at(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) phi_c(f[c]) and its standard error, frames, at frame numbers f (N,)."""
        d = np.asarray(f, dtype=float) - self.centre
        value = self.phase + self.drift * d
        var = self.cov[:, 0, 0] + 2 * d * self.cov[:, 0, 1] + d**2 * self.cov[:, 1, 1]
        return value, np.sqrt(np.maximum(var, 0.0))


def zero_timing(n: int, pairs: WandPairs) -> Timing:
    """No sub-frame offset or drift; centres at each camera's mean frame."""
    return Timing(np.zeros(n), np.zeros(n), _centres(pairs, n), np.zeros((n, 2, 2)), 0.0, np.zeros(n, np.int64))


def fit_timing(
    R: np.ndarray, t: np.ndarray, pairs: WandPairs, focal: np.ndarray, reference: int, drift: bool = False,
    start: Timing | None = None, max_frames: int = MAX_FIT_FRAMES, max_iterations: int = MAX_ITERATIONS,
) -> Timing:
    """Estimate each camera's sub-frame offset (and drift) with the poses held.

    Args:
        R: (N, 3, 3), t: (N, 3) world->camera poses, metres.
        pairs: labelled wand pairs (ends in the same order across the cameras of a frame) on the
            reference clock to within a frame, **not** resampled.
        focal: (N, 2) focal lengths, pixels (residuals are weighed in pixels).
        reference: the camera held at phi = 0.
        drift: also estimate each camera's rate difference.
        start: the model to start from; default zero.
        max_frames: wand frames the fit uses, spread over the recording (all frames' tracks
            still serve the interpolation).
        max_iterations: Gauss-Newton steps at most.
    """
    n = len(R)
    model = start or zero_timing(n, pairs)
    k = 2 if drift else 1
    free = np.ones(n, bool)
    free[reference] = False
    tracks = _Tracks(pairs, n)
    rows = np.flatnonzero(np.isin(pairs.frame, spread_frames(len(pairs.frames), max_frames)))
    sub = pairs.subset(rows)
    cov = np.zeros((n, 2, 2))
    sigma, used, iterations = 0.0, np.zeros(n, np.int64), 0
    for iterations in range(1, max_iterations + 1):
        xy, vel, keep, _ = tracks.resample(model, rows)
        S, rhs, sigma, used = _normal_equations(R, t, sub, xy, vel, keep, focal, model.centre, k)
        cols = np.flatnonzero(np.repeat(free, k))
        Sf = S[np.ix_(cols, cols)]
        Sf = Sf + np.eye(len(cols)) * SMALL * max(np.trace(Sf), 1.0)  # a camera with a still wand: no information
        step = np.zeros(n * k)
        step[cols] = np.linalg.solve(Sf, rhs[cols])
        step = np.clip(step, -MAX_STEP, MAX_STEP).reshape(n, k)
        phase = model.phase + step[:, 0]
        drift_ = model.drift + (step[:, 1] if drift else 0.0)
        inv = np.zeros((n * k, n * k))
        inv[np.ix_(cols, cols)] = np.linalg.inv(Sf) * sigma**2
        cov = np.zeros((n, 2, 2))
        for c in range(n):
            cov[c, :k, :k] = inv[c * k : c * k + k, c * k : c * k + k]
        model = Timing(phase, drift_, model.centre, cov, sigma, used, iterations)
        if np.abs(step).max() < STEP_TOLERANCE:
            break
    return model


def resample(pairs: WandPairs, timing: Timing) -> tuple[WandPairs, np.ndarray]:
    """The pairs brought to the reference instants (module docstring), and keep (P,) bool: the
    rows whose neighbouring frames let them be resampled (the others are left out)."""
    n = int(pairs.camera.max()) + 1 if len(pairs) else 0
    xy, _, keep, uv = _Tracks(pairs, max(n, len(timing.phase))).resample(timing)
    out = WandPairs(pairs.frame, pairs.camera, xy, uv, pairs.frames, pairs.dropped).subset(keep)
    return out, keep


def _centres(pairs: WandPairs, n: int) -> np.ndarray:
    f = pairs.frames[pairs.frame].astype(float)
    count = np.bincount(pairs.camera, minlength=n)
    return np.bincount(pairs.camera, f, minlength=n) / np.maximum(count, 1)


class _Tracks:
    """Each camera's wand ends over time, in an order continuous from frame to frame.

    Camera c's ends at consecutive frames are matched by proximity (a frame moves an end a few
    pixels, the two ends lie tens to hundreds apart), so end e of pair row p is the track's end
    ``e ^ parity[p]``.
    """

    def __init__(self, pairs: WandPairs, n: int) -> None:
        self.pairs = pairs
        f = pairs.frames[pairs.frame]
        self.first = int(f.min()) if len(f) else 0
        span = int(f.max()) - self.first + 1 if len(f) else 0
        self.table = np.full((span + 2, n), -1, np.int64)  # a spare row each side: neighbours past the ends are absent
        self.table[f - self.first + 1, pairs.camera] = np.arange(len(pairs))
        self.parity = np.zeros(len(pairs), bool)
        order = np.lexsort((f, pairs.camera))
        cam, fs, xy = pairs.camera[order], f[order], pairs.xy[order]
        nxt = (cam[1:] == cam[:-1]) & (fs[1:] == fs[:-1] + 1)
        same = np.linalg.norm(xy[1:] - xy[:-1], axis=2).sum(1)
        cross = np.linalg.norm(xy[1:] - xy[:-1, ::-1], axis=2).sum(1)
        flip = np.concatenate([[False], nxt & (cross < same)])
        # parity accumulates along each camera's frames; across a gap it restarts (no neighbour uses it)
        run = np.concatenate([[0], np.cumsum(~np.concatenate([[False], nxt])[1:])])
        parity = np.cumsum(flip) % 2
        start_parity = np.zeros(run.max() + 1, np.int64)
        first_of_run = np.concatenate([[True], ~nxt])
        start_parity[run[first_of_run]] = parity[first_of_run] - flip[first_of_run]
        self.parity[order] = ((parity - start_parity[run]) % 2).astype(bool)

    def resample(self, timing: Timing, rows: np.ndarray | None = None):
        """(xy (Q, 2, 2), velocity (Q, 2, 2) normalised units a frame, keep (Q,), uv (Q, 2, 2))
        of the pair rows ``rows`` (Q,) (default all)."""
        p = self.pairs if rows is None else self.pairs.subset(rows)
        parity = self.parity if rows is None else self.parity[rows]
        f = p.frames[p.frame].astype(float)
        phi = timing.phase[p.camera] + timing.drift[p.camera] * (f - timing.centre[p.camera])
        tau = f - phi - self.first + 1
        i0 = np.floor(tau + SMALL).astype(np.int64)
        u = np.clip(tau - i0, 0.0, 1.0)
        u[u < SMALL] = 0.0
        span = len(self.table)
        idx = i0[:, None] + np.arange(-1, 3)[None, :]  # (P, 4) frames i0-1 .. i0+2
        inside = (idx >= 0) & (idx < span)
        window = np.where(inside, self.table[np.clip(idx, 0, span - 1), p.camera[:, None]], -1)
        xy = np.zeros((len(p), 2, 2))
        uv = np.zeros((len(p), 2, 2))
        vel = np.zeros((len(p), 2, 2))
        keep = np.ones(len(p), bool)
        for e in range(2):
            # row q's end e is the track's end e ^ parity[p], whichever frame holds it
            end = np.repeat((parity ^ bool(e)).astype(np.int64)[:, None], 4, axis=1)
            pts = self._track(window, end, self.pairs.xy)
            raw = self._track(window, end, self.pairs.uv)
            value, slope, ok = _interpolate(pts, u)
            xy[:, e], vel[:, e] = value, slope
            uv[:, e] = _interpolate(raw, u)[0]
            keep &= ok
        return xy, vel, keep, uv

    def _track(self, rows: np.ndarray, end: np.ndarray, what: np.ndarray) -> np.ndarray:
        """(P, 4, 2) the track end ``end`` (P, 4) (in the track's continuous order) at each row of
        ``rows`` (P, 4), NaN where absent."""
        ok = rows >= 0
        r = np.where(ok, rows, 0)
        e = end ^ self.parity[r]
        out = what[r, e]
        return np.where(ok[..., None], out, np.nan)


def _interpolate(pts: np.ndarray, u: np.ndarray):
    """Value and slope (per frame) at i0 + u from samples at i0-1 .. i0+2 (P, 4, 2).

    The value is the cubic through the four where all four are there, else the line through
    i0 and i0 + 1, else at u = 0 the sample itself. The slope is the secant over the outer two,
    (p[i0+2] - p[i0-1]) / 3, else the nearest secant there is: a slope taken from the same
    samples as the value would share their noise, and the offset regressed on it would be
    biased (by sigma^2 / |v|^2 x 0.5 frame at u = 0, 0.001-0.003 frame at 0.3 px); the cubic's
    outer weights are small and nearly equal, so its value and this slope hardly share any.
    Returns (value, slope, ok)."""
    uu = u[:, None]
    w = np.stack([-uu * (uu - 1) * (uu - 2) / 6, (uu + 1) * (uu - 1) * (uu - 2) / 2,
                  -(uu + 1) * uu * (uu - 2) / 2, (uu + 1) * uu * (uu - 1) / 6], axis=1)  # Lagrange weights (P, 4, 1)
    have = np.isfinite(pts[..., 0])
    filled = np.where(have[..., None], pts, 0.0)
    cubic = have.all(1)
    line = have[:, 1] & have[:, 2]
    value = np.where(cubic[:, None], (w * filled).sum(1), filled[:, 1] + uu * (filled[:, 2] - filled[:, 1]))
    at_frame = (u == 0) & have[:, 1] & ~line
    value = np.where(at_frame[:, None], filled[:, 1], value)
    slope = np.where((have[:, 0] & have[:, 3])[:, None], (filled[:, 3] - filled[:, 0]) / 3, 0.0)
    for lo, hi in ((1, 3), (0, 2), (1, 2), (0, 1)):
        fill = ~(have[:, 0] & have[:, 3]) & have[:, lo] & have[:, hi] & np.all(slope == 0, axis=1)
        slope = np.where(fill[:, None], (filled[:, hi] - filled[:, lo]) / (hi - lo), slope)
    ok = cubic | line | at_frame
    return value, slope, ok


def _normal_equations(R, t, pairs: WandPairs, xy, vel, keep, focal, centre, k):
    """The reduced normal equations of the offsets, wand ends eliminated: S (Nk, Nk), rhs (Nk,),
    the residuals' sigma (pixels) and the observations each camera gave."""
    n = len(R)
    F = len(pairs.frames)
    rows = np.flatnonzero(keep)
    point = np.concatenate([pairs.frame[rows] * 2, pairs.frame[rows] * 2 + 1])
    cam = np.concatenate([pairs.camera[rows], pairs.camera[rows]])
    obs = np.concatenate([xy[rows, 0], xy[rows, 1]])
    v = np.concatenate([vel[rows, 0], vel[rows, 1]])
    fr = np.concatenate([pairs.frames[pairs.frame[rows]]] * 2).astype(float)
    X = triangulate_points(R, t, point, cam, obs, 2 * F)
    ok = np.isfinite(X[point]).all(1)
    Xc = np.einsum("mij,mj->mi", R[cam], np.where(ok[:, None], X[point], 0.0)) + t[cam]
    z = Xc[:, 2]
    z = np.where(np.abs(z) > SMALL, z, SMALL)
    proj = Xc[:, :2] / z[:, None]
    fc = focal[cam]
    r = (obs - proj) * fc
    e = np.linalg.norm(r, axis=1)
    # each camera's own robust sigma: a camera still out of time has larger residuals, and they
    # are the signal, not outliers
    limit = np.full(n, MIN_OUTLIER_PX)
    for c in range(n):
        mine = ok & (cam == c)
        if mine.any():
            limit[c] = max(OUTLIER_LIMIT * np.sqrt(np.median(e[mine] ** 2) / (2 * np.log(2))), MIN_OUTLIER_PX)
    ok &= e <= limit[cam]
    views = np.bincount(point[ok], minlength=2 * F)
    ok &= views[point] >= 2
    Rc = R[cam]
    A = np.stack([(Rc[:, 0] - proj[:, :1] * Rc[:, 2]) * fc[:, :1], (Rc[:, 1] - proj[:, 1:] * Rc[:, 2]) * fc[:, 1:]], 1)
    A /= z[:, None, None]  # (M, 2, 3) d proj / dX, pixels a metre
    g = -v * fc  # (M, 2) d r / d phase, pixels a frame
    G = g[:, :, None] * (np.stack([np.ones(len(fr)), fr - centre[cam]], 1)[:, None, :k])  # (M, 2, k)
    A, G, r, point, cam = A[ok], G[ok], r[ok], point[ok], cam[ok]
    used = np.bincount(cam, minlength=n)
    M = len(r)
    # per point: H = sum A^T A (3x3); B[p, c] = sum A^T G (3 x k); ar = sum A^T r
    H = _sums(point, np.einsum("mai,maj->mij", A, A), 2 * F)
    B = _sums(point * n + cam, np.einsum("mai,mak->mik", A, G), 2 * F * n).reshape(2 * F, n, 3, k)
    ar = _sums(point, np.einsum("mai,ma->mi", A, r), 2 * F)
    D = _sums(cam, np.einsum("mak,mal->mkl", G, G), n)
    gr = _sums(cam, np.einsum("mak,ma->mk", G, r), n)
    seen = np.bincount(point, minlength=2 * F) >= 2
    Hinv = np.linalg.inv(H[seen] + np.eye(3) * SMALL)
    Bs = B[seen].transpose(0, 2, 1, 3).reshape(-1, 3, n * k)  # (Ps, 3, Nk), columns camera-major
    W = np.einsum("pij,pjq->piq", Hinv, Bs)
    S = -np.einsum("piq,pir->qr", Bs, W)
    for c in range(n):
        S[c * k : c * k + k, c * k : c * k + k] += D[c]
    rhs = -gr.ravel() + np.einsum("piq,pi->q", W, ar[seen])
    dof = max(2 * M - 3 * int(seen.sum()) - n * k, 1)
    sigma = float(np.sqrt(np.sum(r**2) / dof))
    return S, rhs, sigma, used


def _sums(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, ...) the sums of ``values`` (M, ...) by ``index`` (M,): one bincount a component."""
    flat = values.reshape(len(values), -1)
    out = np.stack([np.bincount(index, flat[:, j], minlength=size) for j in range(flat.shape[1])], axis=1)
    return out.reshape(size, *values.shape[1:])
