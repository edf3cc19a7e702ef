"""A camera knocked so far that the outlier pass rejected its views after the knock: its rejected
camera-frames bunched at one end of its time (issue 31, decision 0077i).

A knock of a degree or more on a sparse camera puts its later wand views beyond the rig's outlier
limit: the outlier pass drops them, and the step test (:mod:`wandcal.calib.judge.faults.pose_steps`),
which trims what lies beyond that limit, never sees the step. What was rejected says it instead.
The judgement's residuals mark the same camera-frames (``Residuals.outlier``: beyond the rig's
limit at the solved points, the outlier pass's rule).

The test, per camera, on its wand camera-frames another camera shares, in capture order: under the
null (no knock) which of them are gross outliers does not depend on when they were seen (the rig's
reflections and mis-detections come and go with the wand), so given the camera's ``m`` rejected of
its ``n`` frames every set of ``m`` frames is equally likely, and the number of rejected among the
last (or first) ``L`` frames is hypergeometric. A knock makes them a contiguous tail (or head,
where the solve kept the pose after it). The smallest hypergeometric tail probability over the
``2 (n - 1)`` blocks, times their number (Bonferroni: exact under the null whatever the outlier
rate, which the conditioning removes), is the p-value; a camera is named ``moved`` at
:data:`~wandcal.calib.judge.faults.pose_steps.STEP_ALPHA`, the step test's own rate. Only a
camera's own rejected views count: another camera's knock rejects that camera's views, not its
neighbours' (the solved points came from the kept views).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA
from wandcal.calib.judge.residuals import Residuals


@dataclass(frozen=True)
class RejectedRun:
    """A camera's rejected camera-frames bunched at one end of its time: after capture frame
    ``frame`` (``tail``; else before it and up to it) ``rejected`` of the ``block`` camera-frames
    were rejected, against ``total_rejected`` of its ``frames`` in all; p_value: the hypergeometric
    tail probability times the blocks tried."""

    frame: int
    tail: bool
    block: int
    rejected: int
    frames: int
    total_rejected: int
    p_value: float


def _log_comb(log_fact: np.ndarray, n: np.ndarray | int, k: np.ndarray) -> np.ndarray:
    """log C(n, k) from the table ``log_fact`` (log k! for k = 0 .. its length - 1)."""
    return log_fact[n] - log_fact[k] - log_fact[n - k]


def block_p_values(rejected: np.ndarray) -> np.ndarray:
    """(n - 1,) for each tail length L = 1 .. n - 1 of the (n,) bool sequence ``rejected``, the
    probability under exchangeability (m of n rejected, every placement alike) that the last L hold
    at least as many rejected as they do: the hypergeometric upper tail, summed in log space."""
    n, m = len(rejected), int(rejected.sum())
    if n < 2 or m == 0:
        return np.ones(max(n - 1, 0))
    L = np.arange(1, n)
    x = np.cumsum(rejected[::-1])[:-1]  # rejected among the last L
    j = np.arange(m + 1)
    # log pmf (L, j): C(m, j) C(n - m, L - j) / C(n, L), zero where L - j is outside 0 .. n - m
    Lj = L[:, None] - j[None, :]
    ok = (Lj >= 0) & (Lj <= n - m)
    lf = np.concatenate([[0.0], np.cumsum(np.log(np.arange(1, n + 1)))])
    logp = _log_comb(lf, m, j)[None, :] + _log_comb(lf, n - m, np.clip(Lj, 0, n - m)) - _log_comb(lf, n, L)[:, None]
    pmf = np.where(ok & (j[None, :] >= x[:, None]), np.exp(logp), 0.0)
    return np.minimum(pmf.sum(axis=1), 1.0)


def rejected_run(rejected: np.ndarray, frames: np.ndarray) -> RejectedRun | None:
    """The most bunched block of rejected camera-frames at either end of one camera's time:
    ``rejected`` (n,) bool and ``frames`` (n,) capture frame numbers, in capture order. None
    with fewer than two frames or none rejected."""
    n, m = len(rejected), int(rejected.sum())
    if n < 2 or m == 0:
        return None
    tails, heads = block_p_values(rejected), block_p_values(rejected[::-1])
    tail = bool(tails.min() <= heads.min())
    k = int(np.argmin(tails if tail else heads))
    L = k + 1
    block = rejected[n - L:] if tail else rejected[:L]
    frame = int(frames[n - L - 1] if tail else frames[L - 1])
    p = float(min((tails if tail else heads)[k] * 2 * (n - 1), 1.0))
    return RejectedRun(frame, tail, L, int(block.sum()), n, m, p)


def camera_runs(res: Residuals, n_cameras: int) -> list[RejectedRun | None]:
    """Each camera's :func:`rejected_run` on its wand camera-frames (a point track's observations
    have no time the wand's shares) that another camera sees too, with a finite residual."""
    wand = (res.point >= 0) & (res.point % 2 == 0) & np.all(np.isfinite(res.residual), axis=1)
    row = res.point[wand] // 2
    cam, out = res.camera[wand], res.outlier[wand]
    views = np.bincount(row, minlength=len(res.frames))
    runs: list[RejectedRun | None] = []
    for c in range(n_cameras):
        mine = (cam == c) & (views[row] >= 2)
        order = np.argsort(res.frames[row[mine]], kind="stable")
        runs.append(rejected_run(out[mine][order], res.frames[row[mine]][order]))
    return runs


def rejected_moved(ids: list[str], res: Residuals) -> list[dict]:
    """A ``moved`` fault on the camera whose rejected camera-frames bunch at one end of its time
    at p under :data:`STEP_ALPHA` (the smallest p where several do); [] where none does."""
    found = sorted((r.p_value, c, r) for c, r in enumerate(camera_runs(res, len(ids)))
                   if r is not None and r.p_value < STEP_ALPHA)
    if not found:
        return []
    _, c, r = found[0]
    return [rejected_fault(ids[c], r)]


def rejected_fault(cam: str, r: RejectedRun) -> dict:
    """The ``moved`` fault of a camera whose rejected views bunch (:class:`RejectedRun`)."""
    when = f"after frame {r.frame}" if r.tail else f"up to frame {r.frame}"
    other = "before" if r.tail else "after"
    return {"kind": "moved", "camera": cam, "evidence": {
        "frame": r.frame, "rejected_block": r.rejected, "block_frames": r.block, "rejected": r.total_rejected,
        "frames": r.frames, "p_value": float(f"{r.p_value:.3g}"), "rejected_views": True},
        "message": f"{cam} moved during the capture: {r.rejected} of its {r.block} camera-frames {when} are gross "
                   f"outliers against {r.total_rejected - r.rejected} of its {r.frames - r.block} {other} (p "
                   f"{r.p_value:.2g}), too far off for the outlier pass to keep, where the other cameras agree; "
                   f"fix its mount and calibrate again, or re-solve it from the frames on one side of {r.frame} alone "
                   f"(calibrate --from RESULT --solve-only {cam})"}
