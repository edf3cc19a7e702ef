"""The LP method's entry points (:func:`refine_lp`, :func:`refine_lp_covariance`) and its first
phase, least absolute error on a subset of frames spread over the capture, before the phase on all
frames (:func:`wandcal.calib.solve.lp.phase.run_phase`)."""

from __future__ import annotations

import time

import numpy as np
from threadpoolctl import threadpool_limits

from wandcal.calib.solve.lp.phase import run_phase
from wandcal.calib.solve.lp.settings import (
    CERTIFY_FIRST_PHASE,
    MAX_ITER,
    POINT_PARAMS,
    SCHEMES,
    SUBSET_FRAMES,
    SUBSET_ONLY_ABOVE,
)
from wandcal.calib.solve.reduced import ReducedSystem
from wandcal.calib.solve.robustloss import EFFICIENT, L1
from wandcal.calib.solve.uncertainty import PoseCovariance, fitted_sigma
from wandcal.calib.solve.wandmodel import WandModel, WandProblem


def refine_lp(
    model: WandModel,
    x0: np.ndarray | None = None,
    progress=None,
    max_iter: int = MAX_ITER,
    time_limit: float | None = None,
    subset_frames: int = SUBSET_FRAMES,
    scheme: str = "irls",
    certify: bool = True,
    warm: bool = False,
):
    """Refine all free cameras and wand frames by sequential LP.

    The first steps, far from the optimum, move many residuals across many breakpoints; they
    run on ``subset_frames`` frames spread evenly over the capture (the wand path sweeps the
    volume, so an even spread covers it). The cameras found there start the steps on all frames.

    Args:
        model: the wand problem about its start state.
        x0: (n_params,) start, ``model.x0()`` when None.
        progress: optional callable(dict).
        time_limit: seconds for each LP solve.
        subset_frames: frames of the first phase (0: none).
        scheme: "irls" (IRLS steps, then LP steps that certify the optimum) or "lp" (LP steps
            only, the scheme before; the same estimator, kept to check the other against).
        certify: with ``scheme="irls"``, False stops at the last phase's IRLS point, near the
            optimum but not on it, without the LP that certifies it (the first phase's, and a
            solve that only tells outliers; calib/run/refine/ now uses a robust ba for that,
            decision 0024).
        warm: x0 is the solution of nearly the same problem (an outlier pass, calib/run/refine/): no
            first phase on a subset, and the phase linearises once at its start (no Gauss-Newton
            step to refit frames fitted to other cameras).

    Returns:
        (x, info) with info: iterations, seconds, lp_seconds, lp_rows_mean, scale, and status:
        "converged", "iteration_limit", "time_limit" (an LP hit ``time_limit``: x is the best
        state reached before it) or "lp_<status>" (HiGHS failed; x likewise); irls_steps.
    """
    # the dense products are small (a 186 x 186 Cholesky at 32 cameras): a second BLAS thread costs
    # more in hand-offs than it gains, as in calib/solve/ba/adjust.py (32 x 2000, bench_peers's scene: the LP solves
    # took 1.6-2.0 s with two BLAS threads, 0.5 s with one)
    with threadpool_limits(limits=1, user_api="blas"):
        x, info, _ = _refine_lp(model, x0, progress, max_iter, time_limit, subset_frames, scheme, certify, warm)
    return x, info


def refine_lp_covariance(model: WandModel, n_wand_frames: int, progress=None, time_limit: float | None = None,
                         warm: bool = False) -> tuple[np.ndarray, dict, PoseCovariance]:
    """:func:`refine_lp` to its certified optimum, and the pose covariance there (what
    calib/run/refine/ reports for ``lp``): from the reduced system the last step was taken on, whose
    Schur complement the phase has already formed for its standard errors, so it costs no other
    linearisation (at 128 x 3000 a separate one, ``ba``'s information matrix, took 1.3-1.6 s CPU;
    decision 0027). The first ``n_wand_frames`` frames are the wand's (the rest point tracks).

    Returns:
        (x, info, covariance).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        x, info, state = _refine_lp(model, None, progress, MAX_ITER, time_limit, SUBSET_FRAMES, "irls", True, warm)
        if state is None or state.model is not model:  # the first phase's state stood: linearise here
            state = ReducedSystem(model, x)
        # sigma as ba's: the median 2D residual at the solution, over n - p degrees of freedom
        n_par = model.frame_col0 + model.frame_params * n_wand_frames + POINT_PARAMS * (model.p.n_frames - n_wand_frames)
        sigma = fitted_sigma(np.linalg.norm(model.residuals(x).reshape(-1, 2), axis=1), n_par)
        return x, info, state.pose_covariance(sigma, n_wand_frames)


def _refine_lp(model, x0, progress, max_iter, time_limit, subset_frames, scheme, certify=True, warm=False):
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, not {scheme!r}")
    start = time.perf_counter()
    x = model.x0() if x0 is None else x0.copy()
    info_sub, state = None, None
    F = model.p.n_frames
    if subset_frames and not warm and SUBSET_ONLY_ABOVE * subset_frames < F:  # a warm start needs no first phase
        keep = np.unique(np.linspace(0, F - 1, subset_frames).round().astype(int))
        sub, sub_x = _frame_subset(model, x, keep)
        sub_x, info_sub, _ = run_phase(sub, sub_x, progress, max_iter, time_limit, "first phase, frame subset", L1,
                                       scheme, certify=CERTIFY_FIRST_PHASE)
        x[: model.frame_col0] = sub_x[: model.frame_col0]  # the frames follow in the phase's first step
    if info_sub is not None and info_sub["status"] != "converged":
        info = dict(info_sub, iterations=0, lp_seconds=0.0)  # the first phase's best state stands
    else:
        x, info, state = run_phase(model, x, progress, max_iter, time_limit, "all frames", EFFICIENT, scheme,
                                   certify=certify, warm=warm)
    if info_sub is not None:
        info["iterations"] += info_sub["iterations"]
        info["lp_seconds"] += info_sub["lp_seconds"]
        info["uncertified_steps"] += info_sub["uncertified_steps"]
        info["irls_steps"] += info_sub["irls_steps"]
        info["lp_steps"] = info_sub["lp_steps"] + info["lp_steps"]
        info["subset"] = {"frames": int(len(keep)), "iterations": info_sub["iterations"]}
    info["seconds"] = time.perf_counter() - start
    return x, info, state


def _frame_subset(model: WandModel, x: np.ndarray, keep: np.ndarray):
    """A WandModel on frames ``keep`` (sorted) with the same cameras, and its state from x."""
    p = model.p
    new_index = np.full(p.n_frames, -1)
    new_index[keep] = np.arange(len(keep))
    sel = new_index[p.frame] >= 0
    sub_p = WandProblem(p.camera[sel], new_index[p.frame[sel]], p.end[sel], p.xy[sel], p.focal, p.length, len(keep),
                        None if p.along is None else p.along[sel])
    sub = WandModel(sub_p, model.R0, model.t0, model.unit_frames(x)[keep], model.fixed)
    sub_x = sub.x0()
    sub_x[: sub.frame_col0] = x[: model.frame_col0]
    return sub, sub_x
