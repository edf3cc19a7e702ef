"""A cheap screen for a step in each camera's pose in a large rig, so that only its few suspects get
the full test (:func:`wandcal.calib.judge.faults.moved.moved_camera`).
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge.faults.f_distribution import f_survival
from wandcal.calib.judge.faults.own_errors import TRIM_SIGMAS, in_wand_time
from wandcal.calib.judge.faults.pose_steps import MIN_SIDE
from wandcal.calib.judge.residuals import Residuals

# a large rig (over leave_one_out.MAX_CAMERAS) screens every camera cheaply first (step_screen):
# its own views' turn in SCREEN_BLOCKS blocks of time, a Hotelling test of one level against two;
# the MAX_STEP_SUSPECTS cameras below SCREEN_ALPHA (a pre-filter: the full test decides) are tested
# in full. Simulated 16-camera rigs: clean cameras down to p = 7e-4 (one in 16 under 0.01), a
# camera knocked by 0.1 degree 3e-7, by 0.3 degree 4e-11
SCREEN_BLOCKS = 16
SCREEN_VIEWS = 2000  # of a camera, evenly spaced in time: 125 a block
SCREEN_ALPHA = 1e-3
MAX_STEP_SUSPECTS = 3


def screen_views(time: np.ndarray) -> np.ndarray:
    """(min(K, :data:`SCREEN_VIEWS`),) the views :func:`step_screen` looks at, of K timed ones
    (time (K,) their capture frames): evenly spaced in time order. Views already so chosen (in
    time order, at most that many) are all chosen again, in their order."""
    order = np.argsort(time, kind="stable")
    if len(order) <= SCREEN_VIEWS:  # np.linspace(0, K - 1, K) is 0 .. K - 1 exactly: every view
        return order
    return order[np.linspace(0, len(order) - 1, SCREEN_VIEWS).astype(np.int64)]


def step_screen(xy: np.ndarray, r: np.ndarray, time: np.ndarray) -> float:
    """A cheap look for a step in one camera's pose: p-value (Bonferroni over the block
    boundaries; 1 with too few views). Its timed views xy (K, 2) (normalised), their residuals
    r (K, 2) against points every camera triangulated (in a large rig a point hangs little on any
    one view) and their capture frames time (K,): in :data:`SCREEN_BLOCKS` blocks of time, a turn
    about the camera's centre (three columns; a turn moves an image point by what its direction
    alone decides) fitted in each after dropping the block's views beyond :data:`TRIM_SIGMAS` of
    its median; Hotelling's T^2 of the blocks' mean turn before a boundary against after, the
    blocks' own scatter about their two levels as the covariance (so a misfit that runs on in time
    counts, and the residuals' scale does not matter)."""
    n_blocks = SCREEN_BLOCKS
    if len(xy) < n_blocks * MIN_SIDE:
        return 1.0
    order = screen_views(time)
    size = len(order) // n_blocks
    at = order[: n_blocks * size].reshape(n_blocks, size)  # the last views of the remainder left out
    x, y = xy[at, 0], xy[at, 1]
    # the image motion of a turn about the centre, d(projection of exp(w) (x, y, 1))/dw: (B, S, 2, 3)
    G = np.empty(x.shape + (2, 3))
    G[..., 0, 0], G[..., 0, 1], G[..., 0, 2] = -x * y, 1 + x**2, -y
    G[..., 1, 0], G[..., 1, 1], G[..., 1, 2] = -1 - y**2, x * y, x
    rb = r[at]
    e2 = rb[..., 0] ** 2 + rb[..., 1] ** 2  # np.sum(rb**2, axis=2) bit for bit, without its per-row reduction
    ok = e2 <= TRIM_SIGMAS**2 * np.maximum(np.median(e2, axis=1, keepdims=True), 1e-30)
    Gt = (G * ok[..., None, None]).reshape(n_blocks, -1, 3).transpose(0, 2, 1)
    N = Gt @ G.reshape(n_blocks, -1, 3)
    N += 1e-12 * np.trace(N, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    w = np.linalg.solve(N, Gt @ rb.reshape(n_blocks, -1, 1))[..., 0]
    nu = n_blocks - 2
    j = np.arange(2, n_blocks - 1)  # boundaries: at least two blocks either side
    total, outer = np.cumsum(w, axis=0), np.cumsum(np.einsum("bi,bj->bij", w, w), axis=0)
    before, after = total[j - 1] / j[:, None], (total[-1] - total[j - 1]) / (n_blocks - j)[:, None]
    # the blocks' scatter about their two levels: sum w w^T less each side's n m m^T
    S = (outer[-1] - j[:, None, None] * np.einsum("ji,jk->jik", before, before)
         - (n_blocks - j)[:, None, None] * np.einsum("ji,jk->jik", after, after)) / nu
    S += 1e-12 * np.trace(S, axis1=1, axis2=2)[:, None, None] * np.eye(3)
    d = after - before
    t2 = np.einsum("ji,ji->j", d, np.linalg.solve(S, d[..., None])[..., 0]) / (1 / j + 1 / (n_blocks - j))
    # the p-value falls as T^2 grows: the largest T^2 gives the smallest
    return min(1.0, f_survival(3, nu - 2, float(t2.max()) * (nu - 2) / (3 * nu)) * len(j))


def step_suspects(res: Residuals, track_frames: np.ndarray | None) -> list[int]:
    """The cameras of a large rig whose :func:`step_screen` on the judgement's residuals
    (:class:`wandcal.calib.judge.residuals.Residuals`: every camera's views against points all
    cameras triangulated, a knocked camera's later views left out of them as outliers) is below
    :data:`SCREEN_ALPHA`, at most :data:`MAX_STEP_SUSPECTS`, the smallest p first. Timed views:
    the wand's and the point tracks' (track_frames (T,): each track's capture frame) in the wand's
    time (:func:`wandcal.calib.judge.faults.own_errors.in_wand_time`; all of them without a wand)."""
    wand = res.point >= 0
    time = res.frames[np.maximum(res.point, 0) // 2] if len(res.frames) else np.zeros(len(res.point), np.int64)
    timed = wand.copy()
    if track_frames is not None and len(track_frames):
        track = np.maximum(-1 - res.point, 0)
        time = np.where(wand, time, track_frames[track])
        wand_frames = res.frames[np.unique(res.point[wand] // 2)]
        timed |= ~wand & in_wand_time(track_frames, wand_frames)[track]
    if not timed.any():
        return []
    p = []
    for c in range(int(res.camera.max()) + 1 if len(res.camera) else 0):
        rows = res.rows_of(c)
        rows = rows[timed[rows]]
        mine = time[rows]
        # the screen's views chosen first, then only theirs gathered (step_screen chooses the same again)
        pick = screen_views(mine) if len(rows) >= SCREEN_BLOCKS * MIN_SIDE else slice(None)
        rows, mine = rows[pick], mine[pick]
        p.append((step_screen(np.take(res.xy, rows, axis=0), np.take(res.residual, rows, axis=0), mine), c))
    return [c for pc, c in sorted(p) if pc < SCREEN_ALPHA][:MAX_STEP_SUSPECTS]
