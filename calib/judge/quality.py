"""Quality figures of a calibration: residuals per camera, worst frames, wand-length spread."""

from __future__ import annotations

import numpy as np

from wandcal.calib.observations import robust_sigma
from wandcal.calib.solve.wandmodel import WandProblem
from wandcal.calib.start.labels import flatten, wand_lengths
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

WORST_FRAMES = 5  # how many of a camera's worst frames the report lists
FEW_FRAMES = 50  # a camera seeing both ends in fewer frames than this is poorly constrained
HIGH_RMS_PX = 1.0  # well above blob noise: intrinsics or labels may be off
OUTLIER_SIGMAS = 5.0  # a camera-frame this many robust sigmas off is a gross outlier, not noise
MIN_FRAMES_FOR_LENGTH_TEST = 10  # fewer frames give no stable robust spread of wand lengths
MIN_OUTLIER_PX = 1.0  # never call a residual under a pixel an outlier, however clean the rest
# a wand-length spread is past a limit only where its own frames say so at one-sided 2.3%: two
# standard errors, as a camera's noise past its limit (own_errors.NOISE_Z, decision 0064); a spread
# of n frames within that of a limit, either side, is at the limit (decision 0077)
SPREAD_Z = 2.0


def pixel_errors(R: np.ndarray, t: np.ndarray, wand: np.ndarray, problem: WandProblem) -> np.ndarray:
    """(M,) reprojection error magnitude of every observation, pixels."""
    r = reprojection_errors(R, t, problem.point, problem.camera, problem.xy, wand.reshape(-1, 3))
    return np.linalg.norm(r * problem.focal[problem.camera], axis=1)


def reject_worst_per_frame(
    R: np.ndarray, t: np.ndarray, pairs, focal: np.ndarray, limit_px: float, max_rounds: int = 4
) -> np.ndarray:
    """(P,) bool, the labelled pairs to keep: in rounds, triangulate every frame from its kept
    pairs and drop the frame's single worst pair when its error exceeds ``limit_px``.

    A round after the first triangulates only the frames that lost a pair in the round before:
    the others' points, errors and worst pair are as they were, so none of them can drop one
    (each point is triangulated from its own observations alone). At 128 cameras nearly every
    frame holds an outlier in the first round, and the later rounds' frames get fewer.

    Args:
        R, t: (N, 3, 3), (N, 3) poses; pairs: labelled WandPairs; focal: (N, 2) fx, fy.
    """
    keep = np.ones(len(pairs), bool)
    changed = np.ones(len(pairs.frames), bool)  # the frames whose kept pairs changed since judged
    for _ in range(max_rounds):
        judged = keep & changed[pairs.frame]
        sub = pairs.subset(judged)
        point, camera, xy = flatten(sub)
        X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames))
        err = reprojection_errors(R, t, point, camera, xy, X)
        e = np.linalg.norm(err * focal[camera], axis=1)
        e = np.where(np.isfinite(e), e, np.inf)
        P = len(sub)
        pair_err = np.maximum(e[:P], e[P:])
        idx = np.flatnonzero(judged)
        worst = np.full(len(pairs.frames), -1.0)
        np.maximum.at(worst, sub.frame, np.where(np.isfinite(pair_err), pair_err, 0.0))
        drop = (pair_err > limit_px) & np.isfinite(pair_err) & (pair_err >= worst[sub.frame])
        if not drop.any():
            break
        keep[idx[drop]] = False
        changed = np.zeros(len(pairs.frames), bool)
        changed[sub.frame[drop]] = True
    return keep


def length_outlier_frames(R: np.ndarray, t: np.ndarray, pairs, keep: np.ndarray, length: float) -> np.ndarray:
    """(F,) bool over ``pairs.frames``: frames whose wand, each end triangulated on its own from
    the kept pairs, is more than ``OUTLIER_SIGMAS`` robust sigmas off ``length``. A frame seen by
    two cameras has little redundancy, so a bad blob hardly shows in its reprojection error, but
    it bends the wand's length."""
    dev = np.abs(wand_lengths(R, t, pairs.subset(keep)) - length)
    ok = np.isfinite(dev)
    if ok.sum() < MIN_FRAMES_FOR_LENGTH_TEST:
        return np.zeros(len(dev), bool)
    sigma = 1.4826 * np.median(dev[ok])  # the MAD of zero-mean Gaussian deviations
    return ok & (dev > OUTLIER_SIGMAS * max(sigma, 1e-9))


def outlier_mask(errors_px: np.ndarray) -> np.ndarray:
    """(M,) bool: observations that are gross outliers by :data:`OUTLIER_SIGMAS`."""
    limit = max(OUTLIER_SIGMAS * robust_sigma(errors_px), MIN_OUTLIER_PX)
    return errors_px > limit


def free_wand_lengths(R: np.ndarray, t: np.ndarray, problem: WandProblem) -> np.ndarray:
    """(F,) wand lengths with each end triangulated on its own (no length constraint), metres.
    Their spread is the usual independent check of a wand calibration (easyWand's wand score)."""
    X = triangulate_points(R, t, problem.point, problem.camera, problem.xy, 2 * problem.n_frames).reshape(-1, 2, 3)
    lengths = np.linalg.norm(X[:, 1] - X[:, 0], axis=1)
    return lengths[np.isfinite(lengths)]


def spread_z(std: float, limit: float, n: int) -> float:
    """How many standard errors a standard deviation ``std`` of ``n`` Gaussian samples stands above
    ``limit`` (negative: below), were the true spread the limit. ``std`` is the samples' SD about
    their mean divided by n, as the result's ``length_std_m`` is (``lengths.std()``): n s^2 / limit^2
    is then chi-square with k = n - 1 degrees of freedom, and its k-th part's cube root close to
    normal with mean 1 - 2 / (9k) and variance 2 / (9k) (Wilson and Hilferty 1931: at 2 standard
    errors within 0.002 of chi-square's own one-sided 2.3% point from k = 5). Unlike
    ``(s - limit) / (s / sqrt(2k))`` it holds for a few frames, where the SD's distribution is
    skewed. +-inf for fewer than two samples (no sampling error known)."""
    if n < 2 or not limit > 0:
        return np.inf if std > limit else -np.inf  # past it or not, and never at the limit
    k = n - 1
    v = 2.0 / (9.0 * k)
    return float(((n * std**2 / (k * limit**2)) ** (1.0 / 3.0) - (1.0 - v)) / np.sqrt(v))


def camera_report(errors_px: np.ndarray, problem: WandProblem, frames: np.ndarray, camera: int) -> dict:
    """Residual RMS, observation count and worst frames of one camera: each frame once, by the
    larger error of its two wand ends, worst first."""
    sel = problem.camera == camera
    e = errors_px[sel]
    fr = frames[problem.frame[sel]]
    order = np.argsort(-e, kind="stable")
    _, first = np.unique(fr[order], return_index=True)  # each frame's worst end, as a place in ``order``
    worst = order[np.sort(first)][:WORST_FRAMES]
    return {
        "reprojection_rms_px": float(np.sqrt(np.mean(e**2))) if len(e) else None,
        "observations": int(sel.sum()),
        "frames_with_both_ends": int(sel.sum() // 2),
        "worst_frames": [{"frame": int(fr[k]), "error_px": round(float(e[k]), 4)} for k in worst],
    }
