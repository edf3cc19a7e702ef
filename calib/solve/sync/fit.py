"""Sub-frame time offsets and rate differences (drift) of cameras without a trigger.

After the whole-frame search (:mod:`wandcal.calib.start.offsets.whole_frames`) each camera's frames are on the
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
reference's own share is added (docs/sync.md). The step's normal equations are built in
:mod:`wandcal.calib.solve.sync.normal`; the result's ``sync`` section in :mod:`wandcal.calib.solve.sync.report`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.solve.sync.normal import normal_equations
from wandcal.calib.solve.sync.tracks import SMALL, Tracks, TrackSmoothness, track_smoothness

MAX_ITERATIONS = 8  # Gauss-Newton steps; from within a frame it settles in 3-4
STEP_TOLERANCE = 1e-4  # frames: a twentieth of the smallest standard error at 0.3 px and 1-4 m/s
# or when every offset's step is this share of its own standard error: with the outliers settled
# (SETTLED_STEP) each step was a tenth of the last or less on simulated rigs, so what is left after
# a step this small is a few hundredths of a standard error, nothing the data can tell
STEP_SHARE_OF_SE = 0.5
MAX_STEP = 1.0  # frames a step may move an offset: the interpolant's slope is trusted that far
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
    smoothness: TrackSmoothness | None = None  # why the cameras held for their tracks were (fit_timing's judgement)

    def offset_at(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) phi_c(f[c]) and its standard error, frames, at frame numbers f (N,)."""
        d = np.asarray(f, dtype=float) - self.centre
        value = self.phase + self.drift * d
        var = self.cov[:, 0, 0] + 2 * d * self.cov[:, 0, 1] + d**2 * self.cov[:, 1, 1]
        return value, np.sqrt(np.maximum(var, 0.0))


def zero_timing(n: int, pairs: WandPairs) -> Timing:
    """No sub-frame offset or drift; centres at each camera's mean frame."""
    return Timing(np.zeros(n), np.zeros(n), _centres(pairs, n), np.zeros((n, 2, 2)), 0.0, np.zeros(n, np.int64))


def fit_rows(pairs: WandPairs, max_frames: int = MAX_FIT_FRAMES) -> np.ndarray:
    """The pair rows :func:`fit_timing` fits: those of ``max_frames`` wand frames spread over the
    recording (indices into ``pairs``)."""
    return np.flatnonzero(np.isin(pairs.frame, spread_frames(len(pairs.frames), max_frames)))


def smoothness(pairs: WandPairs, focal: np.ndarray, tracks: Tracks | None = None,
               max_frames: int = MAX_FIT_FRAMES) -> TrackSmoothness:
    """Each camera's wand track judged on the rows :func:`fit_timing` uses, as it judges them: a
    camera whose track is not interpolable is held at its whole-frame offset (focal (N, 2) or
    (N, 1) pixels). What a message advising ``--sync auto`` checks first."""
    n = len(focal)
    return track_smoothness(pairs, focal, tracks or Tracks(pairs, n), fit_rows(pairs, max_frames))


def why_untimeable(pairs: WandPairs, rig: Rig, c: int) -> str:
    """Why ``--sync auto`` would hold camera c at its whole-frame offset, its figure beside the limit
    ("" where it can fit a fraction): :func:`smoothness` with the rig's focal lengths (fx, fy)."""
    return smoothness(pairs, np.array([cam.focal for cam in rig.cameras], float).reshape(len(rig.cameras), -1)).why_not(c)


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
    rows = fit_rows(pairs, max_frames)
    smooth = track_smoothness(pairs, focal, tracks, rows)
    held = ~smooth.interpolable
    held[reference] = True
    if held.all():  # no camera's timing can be fitted (a digitised session): nothing to refine
        return replace(model, R=R if poses else None, t=t if poses else None, held=held, smoothness=smooth)
    free = np.ones((n, width), bool)
    free[held, width - k :] = False
    cols = np.flatnonzero(free.ravel())
    sub = pairs.subset(rows)
    X = cut = frozen = None
    for iteration in range(1, max_iterations + 1):
        xy, vel, keep, _, spread = tracks.resample(model.phase, model.drift, model.centre, rows, pixels=False,
                                                   markers=markers)
        S, rhs, sigma, used, X, cut = normal_equations(R, t, sub, xy, vel, keep, focal, model.centre, k, poses, X,
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
                       cov, sigma, used, iteration, R if poses else None, t if poses else None, held, smooth)
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
