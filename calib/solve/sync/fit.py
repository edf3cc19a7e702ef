"""Sub-frame time offsets and rate differences (drift) of cameras without a trigger.

After the whole-frame search (:mod:`wandcal.calib.start.frame_offsets`) each camera's frames are on the
reference camera's clock to within a frame. What is left is modelled per camera c as

    phi_c(f) = phase_c + drift_c (f - centre_c)        (frames)

camera c's frame numbered f showing the wand at the reference instant f + phi_c(f). The
observations are brought to the reference instants by **resampling the camera's own track in
time** (:mod:`wandcal.calib.solve.sync.tracks`): the blob of each wand end at frame ``f - phi_c(f)``,
interpolated from its neighbouring frames. The wand moves smoothly at 100 fps, so the
interpolation error is far below the blob noise.

The offsets are estimated by Gauss-Newton with the wand ends free and the cameras' poses held or
refined alongside (gauge pinned by a faint damping, and each pose step cleared of it):
each observation's residual r (observed minus projected, pixels) moves with phi by
``dr/dphi = -v`` (v the blob's image velocity, pixels a frame), and the ends, eliminated per
point (a 3x3 Schur complement each), take up what a common shift of all cameras would explain,
so the reference camera is held at phi = 0. The covariance of (phase, drift) is
sigma^2 S^-1, S the reduced normal matrix (each camera's observations weighed by its blob noise)
and sigma the blob noise before resampling, per degree of freedom: a resampled blob's own noise
is smaller, but consecutive ones share samples and over the slowly turning velocity add up to a
whole blob's (docs/decisions/0022-sync-cost-and-standard-error.md).
SE(phase) ~ sigma_px / (|v|_rms sqrt(n (1 - 1/m))) for m cameras a wand end, before the
reference's own share is added (docs/sync.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.solve.sync.tracks import SMALL, Tracks, interpolable
from wandcal.calib.triangulate import refine_points, triangulate_points

MAX_ITERATIONS = 8  # Gauss-Newton steps; from within a frame it settles in 3-4
STEP_TOLERANCE = 1e-4  # frames: a twentieth of the smallest standard error at 0.3 px and 1-4 m/s
# or when every offset's step is this share of its own standard error: with the outliers settled
# (SETTLED_STEP) each step was a tenth of the last or less on simulated rigs, so what is left after
# a step this small is a few hundredths of a standard error, nothing the data can tell
STEP_SHARE_OF_SE = 0.5
MAX_STEP = 1.0  # frames a step may move an offset: the interpolant's slope is trusted that far
OUTLIER_LIMIT = 4.0  # robust sigmas: an observation beyond is left out of a step (chi2 with 2 dof: 3e-4 of clean ones)
MIN_OUTLIER_PX = 1.0  # never cut closer than this, so a clean rig keeps all its observations
# wand frames a fit uses, spread over the recording: 800 fix an offset to ~0.0015 frame at 0.3 px
# and 1-4 m/s. Fewer cost less but bias it: at 400 of 1500 frames every offset came out 0.005 frame
# (2-3 SE) low and the rig 1.4x the synchronised one's error, at 800 within 0.0023 and 1.1x
# (docs/decisions/0018-sync-from-the-wand.md)
MAX_FIT_FRAMES = 800
# with ``ba``, whose final stage refines the offsets again over every frame (sync/joint.py), the
# fit only starts them: at 16 x 2500 (seeds 1-6) 400 frames left the rig 1.15x the synchronised
# one's error as 800 did, at 8 x 1500 1.09x against 1.10x, and the command's CPU time 1.17x that
# of --sync none against 1.22-1.28x (docs/decisions/0022-sync-cost-and-standard-error.md)
BA_FIT_FRAMES = 400
# once no offset moves by more than this (frames), the observations left out as outliers are kept
# out for the rest of the fit: judged again at each step, a few flip in and out, and the fast
# wand's, whose interpolation is the roughest and whose weight in an offset the largest, moved
# the offsets by half a standard error a step, back and forth, for as many steps as were allowed
SETTLED_STEP = 0.02
POSE = 6  # a pose's columns: rotation increment (radians), translation (metres)
GAUGE_DAMPING = 1e-9  # relative to S's largest diagonal entry: pins the gauge, moves the offsets by ~1e-9 of theirs


def spread_frames(n_frames: int, most: int) -> np.ndarray:
    """At most ``most`` of the frame indices 0 .. n_frames - 1, evenly spaced."""
    if n_frames <= most:
        return np.arange(n_frames)
    return np.unique(np.linspace(0, n_frames - 1, most).round().astype(np.int64))


@dataclass(frozen=True, eq=False)
class Timing:
    """Each camera's offset model, phi_c(f) = phase[c] + drift[c] (f - centre[c]) frames.

    phase: (N,) frames; drift: (N,) frames a frame (ppm x 1e-6); centre: (N,) frame numbers;
    cov: (N, 2, 2) covariance of (phase, drift); sigma_px: the blob noise the fit saw (its
    residuals' RMS per degree of freedom, less the resampling's smoothing); used: (N,)
    observations each camera gave to the fit.
    """

    phase: np.ndarray
    drift: np.ndarray
    centre: np.ndarray
    cov: np.ndarray
    sigma_px: float
    used: np.ndarray
    iterations: int = 0
    R: np.ndarray | None = None  # (N, 3, 3) the poses refined with the offsets (fit_timing(poses=True)), else None
    t: np.ndarray | None = None  # (N, 3)
    held: np.ndarray | None = None  # (N,) bool: held at phi = 0 (the reference; cameras whose frames are too sparse)

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
    poses: bool = False, tracks: Tracks | None = None, markers: tuple[np.ndarray, np.ndarray] | None = None,
) -> Timing:
    """Estimate each camera's sub-frame offset (and drift), with the poses held or refined too.

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
        poses: refine the poses with the offsets (the wand ends free, no wand length): poses
            found from frames still out of time by a fraction are biased, and so would be offsets
            fitted with them held; the result's ``R``, ``t`` are the refined poses. The offsets'
            covariance then allows for the poses' uncertainty.
        tracks: ``Tracks(pairs, N)`` when the caller has it already.
        markers: a multi-marker wand's every marker (xy, uv), each (P, K, 2), the pairs' rows
            with end 0 first and end 1 last: each marker a free point of the fit (the ends'
            tracks still order the frames), so the interior markers' motion tells the offsets too.
    """
    n = len(R)
    model = start or zero_timing(n, pairs)
    R, t = np.array(R, dtype=float), np.array(t, dtype=float)
    k = 2 if drift else 1
    width = POSE + k if poses else k  # each camera's columns: [rotation, translation,] phase[, drift]
    tracks = tracks or Tracks(pairs, n)
    rows = np.flatnonzero(np.isin(pairs.frame, spread_frames(len(pairs.frames), max_frames)))
    held = ~interpolable(pairs, focal, tracks, rows)
    held[reference] = True
    if held.all():  # no camera's timing can be fitted (a digitised session): nothing to refine
        return replace(model, R=R if poses else None, t=t if poses else None, held=held)
    free = np.ones((n, width), bool)
    free[held, width - k :] = False
    cols = np.flatnonzero(free.ravel())
    sub = pairs.subset(rows)
    X = cut = frozen = None
    for iteration in range(1, max_iterations + 1):
        xy, vel, keep, _, spread = tracks.resample(model.phase, model.drift, model.centre, rows, pixels=False,
                                                   markers=markers)
        S, rhs, sigma, used, X, cut = _normal_equations(R, t, sub, xy, vel, keep, focal, model.centre, k, poses, X,
                                                        frozen, spread)
        Sf = S[np.ix_(cols, cols)]
        # the poses' similarity gauge (points free, no wand length) is S's null space, orthogonal
        # to every offset: a faint damping of the pose columns pins it, and leaves the offsets alone
        damp = np.where(np.tile(np.arange(width) < width - k, n)[cols], GAUGE_DAMPING * np.diag(Sf).max(), 0.0)
        inv = np.linalg.inv(Sf + np.diag(damp + SMALL))
        full = np.zeros(n * width)
        full[cols] = inv @ rhs[cols]
        step = full.reshape(n, width)
        time_step = np.clip(step[:, width - k :], -MAX_STEP, MAX_STEP)
        if poses:
            R, t = _moved(R, t, _without_gauge(R, t, step[:, :POSE]))
        cov_full = np.zeros((n * width, n * width))
        cov_full[np.ix_(cols, cols)] = inv * sigma**2
        cov = np.zeros((n, 2, 2))
        for c in range(n):
            at = c * width + width - k
            cov[c, :k, :k] = cov_full[at : at + k, at : at + k]
        model = Timing(model.phase + time_step[:, 0], model.drift + (time_step[:, 1] if drift else 0.0), model.centre,
                       cov, sigma, used, iteration, R if poses else None, t if poses else None, held)
        # the offsets settle with the poses (their steps are solved together)
        se = np.sqrt(np.maximum(cov[:, np.arange(k), np.arange(k)], 0.0))
        if np.all(np.abs(time_step) <= np.maximum(STEP_TOLERANCE, STEP_SHARE_OF_SE * se)):
            break
        if frozen is None and np.abs(time_step).max() < SETTLED_STEP:
            frozen = cut
    return model


def _without_gauge(R: np.ndarray, t: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The pose step (N, 6) less its part along the similarity gauge (a rotation, translation or
    scaling of the world moves every pose and leaves the residuals as they are). The damping
    leaves that part to rounding: on a real session it moved the cameras by millimetres at random.

    In R <- exp([w]x) R, t <- t + dt, a world rotation by omega is w = -R omega, a world shift by
    tau is dt = -R tau, and a scaling by (1 + s) is dt = s t.
    """
    n = len(R)
    N = np.zeros((n, POSE, 7))
    N[:, :3, :3] = -R
    N[:, 3:, 3:6] = -R
    N[:, 3:, 6] = t
    basis = N.reshape(n * POSE, 7)
    flat = step.reshape(-1)
    return (flat - basis @ np.linalg.lstsq(basis, flat, rcond=None)[0]).reshape(n, POSE)


def _moved(R: np.ndarray, t: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses after a step (N, 6): R <- exp([w]x) R, t <- t + dt (w radians, dt metres)."""
    w = step[:, :3]
    angle = np.linalg.norm(w, axis=1)
    axis = w / np.maximum(angle, 1e-300)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K = K - K.transpose(0, 2, 1)
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    dR = np.eye(3) + s * K + (1 - c) * K @ K
    return dR @ R, t + step[:, 3:]


def resample(pairs: WandPairs, timing: Timing, tracks: Tracks | None = None) -> tuple[WandPairs, np.ndarray]:
    """The pairs brought to the reference instants (module docstring), and keep (P,) bool: the
    rows whose neighbouring frames let them be resampled (the others are left out). ``tracks``:
    ``Tracks(pairs, N)`` when the caller has it already."""
    n = int(pairs.camera.max()) + 1 if len(pairs) else 0
    tracks = tracks or Tracks(pairs, max(n, len(timing.phase)))
    xy, _, keep, uv, _ = tracks.resample(timing.phase, timing.drift, timing.centre)
    out = WandPairs(pairs.frame, pairs.camera, xy, uv, pairs.frames, pairs.dropped).subset(keep)
    return out, keep


def _centres(pairs: WandPairs, n: int) -> np.ndarray:
    f = pairs.frames[pairs.frame].astype(float)
    count = np.bincount(pairs.camera, minlength=n)
    return np.bincount(pairs.camera, f, minlength=n) / np.maximum(count, 1)


def _normal_equations(R, t, pairs: WandPairs, xy, vel, keep, focal, centre, k, poses, X_last=None, cut=None,
                      spread=None):
    """The reduced normal equations of each camera's [pose,] phase[, drift] columns, the wand ends
    eliminated point by point: S (N w, N w), rhs (N w,), the residuals' sigma (pixels), the
    observations each camera gave, the wand ends (2F, 3) triangulated (from ``X_last`` when given)
    and the outliers (P, K) bool, each pair row's markers left out (``cut``, when given, instead of
    judging them again). A residual r (observed - projected, pixels) changes by
    G d(theta) - A dX: G = -v f [1, f - centre] for the offsets (v the track's velocity), and for
    a pose (R <- exp([w]x) R, t <- t + dt) -f P [-[R X]x, I], P the projection's derivative."""
    n, K = len(R), xy.shape[1]  # K: the wand's markers (its two ends, or every marker of a longer wand)
    F = len(pairs.frames)
    rows = np.flatnonzero(keep)
    point = np.concatenate([pairs.frame[rows] * K + k for k in range(K)])
    cam = np.concatenate([pairs.camera[rows]] * K)
    obs = np.concatenate([xy[rows, k] for k in range(K)])
    v = np.concatenate([vel[rows, k] for k in range(K)])
    fr = np.concatenate([pairs.frames[pairs.frame[rows]]] * K).astype(float)
    # from the last step's wand ends a few Gauss-Newton steps suffice; the linear start only once
    needed = np.bincount(point, minlength=K * F) >= 2
    if X_last is not None and np.all(np.isfinite(X_last[needed])):
        X = refine_points(R, t, point, cam, obs, np.where(needed[:, None], X_last, np.nan))
    else:
        X = triangulate_points(R, t, point, cam, obs, K * F)
    ok = np.isfinite(X[point]).all(1)
    RX = np.einsum("mij,mj->mi", R[cam], np.where(ok[:, None], X[point], 0.0))
    Xc = RX + t[cam]
    z = Xc[:, 2]
    z = np.where(np.abs(z) > SMALL, z, SMALL)
    proj = Xc[:, :2] / z[:, None]
    fc = focal[cam]
    r = (obs - proj) * fc
    e = np.linalg.norm(r, axis=1)
    # each camera's own robust sigma: a camera still out of time has larger residuals, and they
    # are the signal, not outliers
    if cut is None:
        cut = _outliers(e, ok, cam, rows, n, (len(pairs), K))
    ok &= ~cut[np.concatenate([rows] * K), np.repeat(np.arange(K), len(rows))]
    views = np.bincount(point[ok], minlength=K * F)
    ok &= views[point] >= 2
    Pj = np.zeros((len(z), 2, 3))  # d proj / d x_cam, pixels, times z
    Pj[:, 0, 0], Pj[:, 1, 1] = fc[:, 0], fc[:, 1]
    Pj[:, :, 2] = -proj * fc
    Pj /= z[:, None, None]
    A = Pj @ R[cam]  # (M, 2, 3) d proj / dX, pixels a metre
    g = -v * fc  # (M, 2) d r / d phase, pixels a frame
    G = g[:, :, None] * (np.stack([np.ones(len(fr)), fr - centre[cam]], 1)[:, None, :k])  # (M, 2, k)
    if poses:  # d r / d(w, dt) = -P [-[RX]x, I]; a row p of P [RX]x is p x RX
        G = np.concatenate([_cross_rows(Pj, RX), -Pj, G], axis=2)
    width = G.shape[2]
    A, G, r, point, cam = A[ok], G[ok], r[ok], point[ok], cam[ok]
    used = np.bincount(cam, minlength=n)
    share = np.concatenate([spread[rows]] * K)[ok] if spread is not None else None
    pooled, weight = _camera_weights(r, point, cam, used, width, share)
    A, G, r = A * weight[:, :, None], G * weight[:, :, None], r * weight
    S, rhs = _eliminated(A, G, r, point, cam, n, K * F)
    return S, rhs, float(np.sqrt(pooled)), used, X, cut


def _outliers(e: np.ndarray, ok: np.ndarray, cam: np.ndarray, rows: np.ndarray, n: int,
              shape: tuple[int, int]) -> np.ndarray:
    """(P, K) bool, ``shape``: each pair row's markers (its ends, K = 2) whose residual length
    ``e`` (K R,) pixels passes ``OUTLIER_LIMIT`` of its camera's own robust sigma (at least
    ``MIN_OUTLIER_PX``)."""
    limit = np.full(n, MIN_OUTLIER_PX)
    for c in range(n):
        mine = ok & (cam == c)
        if mine.any():
            limit[c] = max(OUTLIER_LIMIT * np.sqrt(np.median(e[mine] ** 2) / (2 * np.log(2))), MIN_OUTLIER_PX)
    cut = np.zeros(shape, bool)
    cut[np.concatenate([rows] * shape[1]), np.repeat(np.arange(shape[1]), len(rows))] = e > limit[cam]
    return cut


def _camera_weights(r: np.ndarray, point: np.ndarray, cam: np.ndarray, used: np.ndarray, width: int,
                    share: np.ndarray | None) -> tuple[float, np.ndarray]:
    """(the pooled blob variance, pixels^2; (M, 1) each observation's weight, its camera's noise
    against the pooled) from the residuals ``r`` (M, 2) pixels, the share of each residual's
    variance the resampling kept (M,), or None for all of it.

    Each camera's blob noise, from its residuals less the share the resampling smoothed away:
    the values' noise is correlated from frame to frame, and over the slowly turning image
    velocity that an offset is seen through it adds up to a whole blob's; the residuals' own
    variance, 0.64 of it half-way between frames, made the standard errors 1.2-1.3x optimistic."""
    n = len(used)
    M = len(r)
    dof_share = max(2 * M - 3 * len(np.unique(point)) - n * width, 1) / (2 * M)
    share = share if share is not None else np.ones(M)
    noise = np.bincount(cam, (r**2).sum(1), minlength=n) / np.maximum(2 * np.bincount(cam, share, minlength=n), 1e-300)
    noise = noise / dof_share
    noise = np.where(used > 0, noise, 1.0)
    pooled = float(np.sum(noise * used) / max(used.sum(), 1))
    weight = np.sqrt(pooled / np.maximum(noise, 1e-300))[cam][:, None]  # each camera by its noise, in pixels
    return pooled, weight


def _eliminated(A: np.ndarray, G: np.ndarray, r: np.ndarray, point: np.ndarray, cam: np.ndarray, n: int,
                n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera columns' normal equations with the points eliminated point by point: S (n w,
    n w), rhs (n w,), from each observation's point Jacobian ``A`` (M, 2, 3), camera Jacobian
    ``G`` (M, 2, w) and residual ``r`` (M, 2), all weighted."""
    width = G.shape[2]
    H = _sums(point, _outer_sum(A, A), n_points)
    ar = _sums(point, np.einsum("mai,ma->mi", A, r), n_points)
    D = np.zeros((n, width, width))
    gr = np.zeros((n, width))
    for c in range(n):  # a camera's block is one product over its observations
        mine = cam == c
        Gc = G[mine].reshape(-1, width)
        D[c], gr[c] = Gc.T @ Gc, Gc.T @ r[mine].ravel()
    seen = np.flatnonzero(np.bincount(point, minlength=n_points) >= 2)
    slot = np.full(n_points, -1)
    slot[seen] = np.arange(len(seen))
    # a camera sees a wand end once, so each (end, camera) block of B is one observation's A^T G
    B = np.zeros((len(seen) * n, 3, width))
    at = slot[point] >= 0
    B[slot[point[at]] * n + cam[at]] = np.matmul(A[at].transpose(0, 2, 1), G[at])
    B = B.reshape(len(seen), n, 3, width).transpose(0, 2, 1, 3).reshape(len(seen), 3, n * width)
    Hinv = np.linalg.inv(H[seen] + np.eye(3) * SMALL)
    W = np.einsum("pij,pjq->piq", Hinv, B)
    S = -(B.reshape(-1, n * width).T @ W.reshape(-1, n * width))  # one matrix product over all points
    for c in range(n):
        S[c * width : (c + 1) * width, c * width : (c + 1) * width] += D[c]
    rhs = -gr.ravel() + np.einsum("piq,pi->q", W, ar[seen])
    return S, rhs


def _cross_rows(P: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, 2, 3) each row of P (M, 2, 3) crossed with v (M, 3): P @ [v]x."""
    v0, v1, v2 = v[:, None, 0], v[:, None, 1], v[:, None, 2]
    p0, p1, p2 = P[:, :, 0], P[:, :, 1], P[:, :, 2]
    return np.stack([p1 * v2 - p2 * v1, p2 * v0 - p0 * v2, p0 * v1 - p1 * v0], axis=2)


def _outer_sum(A: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(M, i, k) A[m]^T G[m] of A (M, 2, i) and G (M, 2, k): the two rows' outer products
    (for 3 x 3, faster than an einsum or a batched matmul)."""
    return A[:, 0, :, None] * G[:, 0, None, :] + A[:, 1, :, None] * G[:, 1, None, :]


def _sums(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, ...) the sums of ``values`` (M, ...) by ``index`` (M,): one bincount a component."""
    flat = values.reshape(len(values), -1)
    out = np.stack([np.bincount(index, flat[:, j], minlength=size) for j in range(flat.shape[1])], axis=1)
    return out.reshape(size, *values.shape[1:])


SYNC_MODES = ("none", "auto")
DEFAULT_SYNC = "none"  # docs/decisions/0018-sync-from-the-wand.md: a trigger's frames need no search
# an offset this many standard errors (and OUT_OF_TIME_FRAMES) from its start is worth a warning
OUT_OF_TIME_SIGMAS = 4.0
OUT_OF_TIME_FRAMES = 0.05  # frames: below the accuracy the issue asks of the estimate


def sync_report(
    ids: list[str], whole: np.ndarray, reference: int, timing: Timing, start: np.ndarray | None, rate_hz: float | None,
    drift: bool,
) -> tuple[dict, list[str]]:
    """The result's ``sync`` section (docs/result-format.md) and the warnings of cameras found out
    of time.

    Args:
        ids: camera ids (N,).
        whole: (N,) int whole-frame offsets the frames were renumbered by.
        reference: the camera held at offset 0.
        timing: the sub-frame model fitted on the renumbered frames.
        start: (N,) the offsets the capture's timestamps gave (frames), or None (zeros).
        rate_hz: the reference camera's frame rate, for seconds; None when unknown.
        drift: whether drift was estimated.
    """
    n = len(ids)
    start = np.zeros(n) if start is None else np.asarray(start, dtype=float)
    at_zero, std = timing.offset_at(whole.astype(float))  # phi at each camera's own frame 0 (renumbered to whole)
    offset = whole + at_zero
    cameras, warnings = [], []
    for c in range(n):
        whole_only = timing.held is not None and timing.held[c] and c != reference
        entry = {
            "id": ids[c],
            "offset_frames": float(offset[c]),
            "offset_std_frames": None if whole_only else float(std[c]),
            "offset_s": float(offset[c] / rate_hz) if rate_hz else None,
            "drift_ppm": float(1e6 * timing.drift[c]) if drift else None,
            "drift_std_ppm": float(1e6 * np.sqrt(max(timing.cov[c, 1, 1], 0.0))) if drift else None,
        }
        cameras.append(entry)
        gap = offset[c] - start[c]
        if whole_only:
            warnings.append(f"{ids[c]}: its wand frames are too sparse or too far apart in time to interpolate, so its "
                            "time offset is found in whole frames only")
        entry["out_of_time"] = bool(c != reference and abs(gap) > max(OUT_OF_TIME_SIGMAS * std[c], OUT_OF_TIME_FRAMES))
        if entry["out_of_time"]:
            said = "its timestamps" if np.any(start) else "its frame numbers"
            warnings.append(
                f"{ids[c]} is out of time: its frame k was exposed at {ids[reference]}'s frame k {offset[c]:+.3f} "
                f"(+-{std[c]:.3f}) frames, {gap:+.3f} from what {said} said; its frames were realigned by the wand"
            )
    doc = {"mode": "auto", "reference": ids[reference], "rate_hz": rate_hz, "residual_sigma_px": timing.sigma_px,
           "cameras": cameras}
    return doc, warnings
