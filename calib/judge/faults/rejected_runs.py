"""A camera knocked so far that the outlier pass rejected its views after the knock: its rejected
camera-frames bunched at one end of its time (issue 31, decision 0084).

A knock of a degree or more on a sparse camera puts its later wand views beyond the rig's outlier
limit: the outlier pass drops them, and the step test (:mod:`wandcal.calib.judge.faults.pose_steps`),
which trims what lies beyond that limit, never sees the step. What was rejected says it instead.
The judgement's residuals mark the same camera-frames (``Residuals.outlier``: beyond the rig's
limit at the solver's points, which the rejected views did not pull: the outlier pass's rule).

The test, per camera, on its wand camera-frames another camera shares, in capture order. Under the
null (no knock) a camera-frame is rejected at the rig's rate (reflections and mis-detections, spread
in time), bounded above by the other cameras' share (Clopper-Pearson 97.5%, the frames of the
camera's block left out: a knock rejects its partners' views in the frames they share with it).
A knock makes a block at one end of the camera's time (after the knock; or before it, where the
solve kept the later pose) rejected far beyond that rate: the smallest binomial tail P(Bin(L, q) >=
rejected of the last or first L) times the 2 (n - 1) blocks tried (Bonferroni) is the p-value,
named at :data:`~wandcal.calib.judge.faults.pose_steps.STEP_ALPHA`, the step test's own rate. A
camera whose rejects are its own noise or a reflection would pass that too where they crowd one
end, so the block must also be a pose: one turn of the camera about its centre, fitted to the
block's views against the points the other cameras place without it, brings them back within the
limit (no more left beyond it than the rate explains, :func:`turned_back`). Only a camera's own
rejected views count, and the camera of smallest p that turns back is the one named.

Where the count names nothing, a block too short for it (a camera of 8-24 camera-frames, most
with one partner: Brown's) is judged by the size of its errors (:func:`turn_against_partners`,
decision 0101): one turn of the camera fitted to its block's distances from its partners'
epipolar lines, an F test against its own scatter before, at the same rate, with each partner's
distances left out in turn (that partner may be the one that moved).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import projection_derivative, rotvec_to_matrix, turn_response
from wandcal.calib.judge.faults.f_distribution import binomial_tail, binomial_upper, f_survival
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA
from wandcal.calib.judge.residuals import Residuals
from wandcal.calib.triangulate import triangulate_points

TURN_STEPS = 4  # Gauss-Newton steps of the block's turn, before and after leaving out what stays beyond the limit
# a rejected block is the candidate's own only where, any one other camera left out too (the one
# that might have moved instead, its knocked pose followed by the solve), two cameras still place
# its points: N - 2 >= 2. In a rig of three the outlier pass may reject the unmoved camera of a
# pair (the seed-11 grid: easyWand sample cam2 5 deg named on cam1), which the data cannot undo
MIN_CAMERAS = 4
MIN_PLACED = 3  # block frames the others place: a turn (three columns) fitted to fewer is not tested
FITS_LEVEL = 0.01  # the turned block is as the rig when its camera-frames left beyond the limit are this likely at its rate
LENS_COLUMNS = 8  # the held-out lens (lens_predicts_block): the pose's six, a focal scale and k1
# the held-out lens is trusted to predict the block only from this many placed camera-frames outside
# it (four equations each: twelve a column). Brown's cameras share 8-24 wand frames in all, so it is
# never tried there: decision 0100's lens over all the frames absorbed real knocks on those sessions
MIN_LENS_FRAMES = 3 * LENS_COLUMNS


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


def block_against_rate(rejected: np.ndarray, frames: np.ndarray, q: float) -> RejectedRun | None:
    """The block at either end of one camera's time (``rejected`` (n,) bool, ``frames`` (n,), in
    capture order) whose rejected count is least likely were each camera-frame rejected at the
    rig's rate ``q`` alone: P(Bin(L, q) >= its count), times the 2 (n - 1) blocks tried. None
    without a rejected frame. The tail is summed exactly only where its Chernoff bound
    exp(-L KL(x / L, q)) could reach :data:`STEP_ALPHA` after the factor; elsewhere the bound (above
    the exact tail) stands for it."""
    n = len(rejected)
    if n < 2 or not rejected.any():
        return None
    best: tuple[float, bool, int] = (2.0, True, 0)
    factor = 2 * (n - 1)
    for tail, seq in ((True, rejected[::-1]), (False, rejected)):
        x = np.cumsum(seq)[:-1].astype(float)
        L = np.arange(1, n, dtype=float)
        share = x / L
        with np.errstate(divide="ignore", invalid="ignore"):
            kl = (np.where(share > 0, share * np.log(share / q), 0.0)
                  + np.where(share < 1, (1 - share) * np.log((1 - share) / (1 - q)), 0.0))
        bound = np.where((share > q) & (x > 0), np.exp(-L * kl), 1.0)
        for j in np.flatnonzero(bound * factor < STEP_ALPHA).tolist():
            bound[j] = binomial_tail(int(x[j]), j + 1, q)
        k = int(np.argmin(bound))
        if bound[k] < best[0]:
            best = (float(bound[k]), tail, k + 1)
    p, tail, L_best = best
    if L_best == 0:
        return None
    block = rejected[n - L_best:] if tail else rejected[:L_best]
    frame = int(frames[n - L_best - 1] if tail else frames[L_best - 1])
    return RejectedRun(frame, tail, L_best, int(block.sum()), n, int(rejected.sum()), float(min(p * factor, 1.0)))


def _shared_wand_rows(res: Residuals) -> np.ndarray:
    """The rows of wand camera-frames another camera sees too, with a finite residual (first ends)."""
    wand = (res.point >= 0) & (res.point % 2 == 0) & np.all(np.isfinite(res.residual), axis=1)
    views = np.bincount(res.point[wand] // 2, minlength=len(res.frames))
    rows = np.flatnonzero(wand)
    return rows[views[res.point[rows] // 2] >= 2]


def _camera_frames(res: Residuals, c: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera c's wand camera-frames another camera sees too, with a finite residual, in capture
    order: (their residuals' rows of the first end (K,), rejected (K,) bool)."""
    rows = _shared_wand_rows(res)
    rows = rows[res.camera[rows] == c]
    rows = rows[np.argsort(res.frames[res.point[rows] // 2], kind="stable")]
    return rows, res.outlier[rows]


def _every_cameras_frames(res: Residuals, n_cameras: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`_camera_frames` of every camera from one stable sort of the shared rows by (camera,
    capture frame): the rows in the order each camera's own stable sort by frame gives them."""
    rows = _shared_wand_rows(res)
    rows = rows[np.lexsort((res.frames[res.point[rows] // 2], res.camera[rows]))]
    bounds = np.searchsorted(res.camera[rows], np.arange(n_cameras + 1))
    return [(r, res.outlier[r]) for r in (rows[bounds[c]:bounds[c + 1]] for c in range(n_cameras))]


def camera_runs(res: Residuals, n_cameras: int) -> list[tuple[RejectedRun, float] | None]:
    """Each camera's :func:`block_against_rate` on its wand camera-frames (a point track's
    observations have no time the wand's shares) that another camera sees too, and the rate it was
    judged at: the upper 97.5% bound (:func:`binomial_upper`) of the other cameras' rejected share
    in the frames outside the camera's block (a knock rejects its partners' views in the frames they
    share with it too: in a frame of two views the error is split), the block found at the others'
    whole rate first, then again at that rate."""
    per = _every_cameras_frames(res, n_cameras)
    frame_of = [res.point[rows] // 2 for rows, _ in per]
    all_frames = np.concatenate(frame_of) if per else np.zeros(0, np.int64)
    all_out = np.concatenate([o for _, o in per]) if per else np.zeros(0, bool)
    rejected_in = np.bincount(all_frames, all_out, minlength=len(res.frames))  # every camera's, per frame
    seen_in = np.bincount(all_frames, minlength=len(res.frames)).astype(float)
    runs: list[tuple[RejectedRun, float] | None] = []
    for c, (_, out) in enumerate(per):
        frames, inside = res.frames[frame_of[c]], np.zeros(len(out), bool)
        run, q = None, 1.0
        for _ in range(2):
            block = frame_of[c][inside]  # the others' camera-frames outside c's block
            k = rejected_in.sum() - out.sum() - (rejected_in[block].sum() - out[inside].sum())
            n = seen_in.sum() - len(out) - (seen_in[block].sum() - inside.sum())
            q = binomial_upper(int(round(k)), int(round(n)))
            run = block_against_rate(out, frames, q) if q < 1 else None
            if run is None:
                break
            inside = frames > run.frame if run.tail else frames <= run.frame
        runs.append(None if run is None else (run, q))
    return runs


def _placed_by_others(res: Residuals, R: np.ndarray, t: np.ndarray, c: int, pts: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray] | None:
    """Camera c's views of the wand ends of the points ``pts`` (first ends) and those ends as the
    other cameras' kept views place them (two views or more): (its residuals' rows (K,), X (K, 3)
    world, metres); None where the others place none."""
    ends = np.isin(res.point, np.r_[pts, pts + 1]) & (res.point >= 0)
    views = np.flatnonzero(ends & (res.camera == c))
    others = np.flatnonzero(ends & (res.camera != c) & ~res.outlier)
    seen = np.bincount(res.point[others], minlength=2 * len(res.frames))
    others = others[seen[res.point[others]] >= 2]
    if not len(others):
        return None
    X = triangulate_points(R, t, res.point[others], res.camera[others], res.xy[others], 2 * len(res.frames))
    X = X[res.point[views]]
    ok = np.all(np.isfinite(X), axis=1) & (seen[res.point[views]] >= 2)
    return views[ok], X[ok]


def _block_views(res: Residuals, c: int, run: RejectedRun) -> tuple[np.ndarray, np.ndarray]:
    """Camera c's shared first-end rows (:func:`_camera_frames`) inside and outside its block:
    (inside (K,) rows, outside (M,) rows)."""
    rows, _ = _camera_frames(res, c)
    frames = res.frames[res.point[rows] // 2]
    inside = frames > run.frame if run.tail else frames <= run.frame
    return rows[inside], rows[~inside]


def _left_beyond(res: Residuals, views: np.ndarray, err: np.ndarray, q: float) -> bool:
    """Whether the camera-frames of ``views`` (rows (K,)) whose errors ``err`` (K,) px pass the rig's
    limit are as few as its rate ``q`` explains (P(Bin(placed frames, q) >= those) >= :data:`FITS_LEVEL`)."""
    beyond, placed = np.zeros(len(res.frames), bool), np.zeros(len(res.frames), bool)
    np.logical_or.at(beyond, res.point[views] // 2, err > res.limit_px)
    placed[res.point[views] // 2] = True
    return binomial_tail(int(beyond.sum()), int(placed.sum()), q) >= FITS_LEVEL


def turned_back(res: Residuals, R: np.ndarray, t: np.ndarray, c: int, run: RejectedRun, q: float) -> bool:
    """Whether one turn of camera c about its centre brings its block's camera-frames back: after
    the turn (least squares on the block's views, the ones still beyond the limit then left out and
    fitted once more) no more of them stay beyond the rig's limit than its rate ``q`` would put
    there (P(Bin(block, q) >= those left) >= :data:`FITS_LEVEL`). A reflection or a second marker
    is not a pose: one turn does not explain it."""
    block, _ = _block_views(res, c, run)
    found = _placed_by_others(res, R, t, c, res.point[block])
    if found is None:
        return True  # the others do not place the block: the rate's test stands alone
    views, X = found
    if len(np.unique(res.point[views] // 2)) < MIN_PLACED:
        return True  # too few of the block's frames placed without it to tell a turn from a reflection
    Xc0 = X @ R[c].T + t[c]
    w, use = np.zeros(3), np.ones(len(views), bool)
    for k in range(2 * TURN_STEPS):
        Xc = Xc0 @ rotvec_to_matrix(w).T
        err = (Xc[:, :2] / Xc[:, 2:] - res.xy[views]) * res.focal[views, None]
        if k == TURN_STEPS:  # the views the first fit leaves beyond the limit are left out of the second
            use = np.linalg.norm(err, axis=1) <= res.limit_px
            if use.sum() < 3:
                break
        J = np.einsum("kij,kjl->kil", projection_derivative(Xc), turn_response(Xc)) * res.focal[views, None, None]
        A = np.einsum("kmi,kmj->ij", J[use], J[use])
        w = w - np.linalg.lstsq(A, np.einsum("kmi,km->i", J[use], err[use]), rcond=None)[0]
    Xc = Xc0 @ rotvec_to_matrix(w).T
    err = np.linalg.norm((Xc[:, :2] / Xc[:, 2:] - res.xy[views]) * res.focal[views, None], axis=1)
    return _left_beyond(res, views, err, q)


def _lens_errors(p: np.ndarray, Xc0: np.ndarray, xy: np.ndarray, focal: np.ndarray) -> np.ndarray:
    """(K, 2) pixels, the camera's views ``xy`` (K, 2 normalised) against the camera-frame points
    Xc0 (K, 3) turned by p[:3], moved by p[3:6] and seen through a lens scaled by 1 + p[6] with a
    radial term p[7] r^2 (r^2 normalised): its pose, its focal length and its k1 refitted."""
    Xc = Xc0 @ rotvec_to_matrix(p[:3]).T + p[3:6]
    x = Xc[:, :2] / Xc[:, 2:]
    return ((1 + p[6]) * x * (1 + p[7] * (x * x).sum(axis=1, keepdims=True)) - xy) * focal[:, None]


def _fitted_lens(Xc0: np.ndarray, xy: np.ndarray, focal: np.ndarray, limit_px: float) -> np.ndarray | None:
    """(8,) the pose, focal scale and k1 of :func:`_lens_errors` fitted to the views (Gauss-Newton,
    those the first fit leaves beyond ``limit_px`` left out of the second); None with fewer kept
    views than columns."""
    p, use, h = np.zeros(LENS_COLUMNS), np.ones(len(xy), bool), 1e-7
    for k in range(2 * TURN_STEPS):
        err = _lens_errors(p, Xc0, xy, focal)
        if k == TURN_STEPS:
            use = np.linalg.norm(err, axis=1) <= limit_px
            if use.sum() < LENS_COLUMNS:
                return None
        J = np.stack([(_lens_errors(p + h * e, Xc0, xy, focal) - err) / h for e in np.eye(LENS_COLUMNS)], axis=2)
        A = np.einsum("kmi,kmj->ij", J[use], J[use])
        p = p - np.linalg.lstsq(A, np.einsum("kmi,km->i", J[use], err[use]), rcond=None)[0]
    return p


def lens_predicts_block(res: Residuals, R: np.ndarray, t: np.ndarray, c: int, run: RejectedRun, q: float) -> bool:
    """Whether camera c's rejected block is its lens's, not a move's, by a held-out test: its pose,
    focal length and k1 (:data:`LENS_COLUMNS`) fitted to its camera-frames *outside* the block
    against the points the other cameras place without it, and that lens then leaves no more of the
    block's camera-frames beyond the rig's limit than its rate ``q`` explains (:func:`_left_beyond`).
    A focal length a few per cent off is off by the same pattern at every time, growing with where
    in the image the wand is: the frames before predict the block. A knock is a change in time: the
    pose fitted before it leaves the block turned, and the block cannot pull the fit (decision 0100's
    lens for all the frames could, and absorbed real knocks). False (a move stands) where fewer than
    :data:`MIN_LENS_FRAMES` camera-frames outside the block are placed by the others."""
    block, outside = _block_views(res, c, run)
    fit_on = _placed_by_others(res, R, t, c, res.point[outside])
    if fit_on is None or len(np.unique(res.point[fit_on[0]] // 2)) < MIN_LENS_FRAMES:
        return False
    judged = _placed_by_others(res, R, t, c, res.point[block])
    if judged is None or len(np.unique(res.point[judged[0]] // 2)) < MIN_PLACED:
        return False
    p = _fitted_lens(fit_on[1] @ R[c].T + t[c], res.xy[fit_on[0]], res.focal[fit_on[0]], res.limit_px)
    if p is None:
        return False
    views, X = judged
    err = np.linalg.norm(_lens_errors(p, X @ R[c].T + t[c], res.xy[views], res.focal[views]), axis=1)
    return _left_beyond(res, views, err, q)


def _epipolar_pairs(res: Residuals, R: np.ndarray, t: np.ndarray, c: int, first: np.ndarray) -> tuple[np.ndarray, ...]:
    """Camera c's wand views (both ends of its frames another camera shares: ``first``, their first
    ends' rows, :func:`_camera_frames`) against every other
    camera's view of the same end: (rows (K,) c's residual rows, one a pair, normals (K, 3) of the
    plane through c's centre and the other camera's ray, in c's frame, frames (K,) capture frames,
    partners (K,) the other camera).
    c's view lies on that plane, up to noise, wherever c has not moved (the epipolar line)."""
    mine = np.flatnonzero(np.isin(res.point, np.r_[res.point[first], res.point[first] + 1]) & (res.camera == c))
    at = np.full(2 * len(res.frames), -1)
    at[res.point[mine]] = mine
    other = np.flatnonzero((res.point >= 0) & (res.camera != c) & np.all(np.isfinite(res.residual), axis=1))
    other = other[at[res.point[other]] >= 0]
    d = res.camera[other]
    centre = -np.einsum("nji,nj->ni", R, t)  # (N, 3) camera centres, world
    ray = np.einsum("kji,kj->ki", R[d], np.c_[res.xy[other], np.ones(len(other))])  # the other camera's rays, world
    normals = np.cross(centre[d] - centre[c], ray) @ R[c].T
    return at[res.point[other]], normals, res.frames[res.point[other] // 2], d


def _epipolar_px(res: Residuals, rows: np.ndarray, normals: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(K,) c's views' distances from their epipolar lines, pixels, after c turns by w (3,)."""
    n = normals @ rotvec_to_matrix(w).T
    return np.einsum("ki,ki->k", n, np.c_[res.xy[rows], np.ones(len(rows))]) / np.hypot(n[:, 0], n[:, 1]) * res.focal[rows]


def turn_against_partners(res: Residuals, R: np.ndarray, t: np.ndarray, c: int, run: RejectedRun, q: float,
                          first: np.ndarray) -> tuple[bool, float]:
    """Camera c's block (``run``) against the rays of every camera that shares its frames, where the
    others place too few of them for :func:`turned_back` (Brown's cameras share most wand frames
    with one other): (back, p_value). One turn of c about its centre is fitted to its block's
    distances from their epipolar lines (least squares; those still beyond the rig's limit then left
    out and fitted again); back: no more of the block's frames left beyond the limit than the rig's
    rate ``q`` explains (P(Bin(frames, q) >= left) >= :data:`FITS_LEVEL`); p_value: the turn's F
    test, what it takes off the kept distances' squares over its three columns against the mean
    square of c's distances outside the block within the limit, P(F(3, dof) > F) with dof the
    camera-frames those come from (a frame's distances share its views' errors),
    times the 2 (n - 1) blocks of :func:`block_against_rate` (Bonferroni: the block was chosen from
    the same views). A knock's later views are all off by one turn however few they are, which
    the count of rejects cannot show under a few camera-frames. (False, 1) with fewer than
    :data:`MIN_PLACED` block frames or three reference frames. Were a partner the one that moved,
    the distances against it would carry the turn: p_value is the largest of the test's with each
    partner's distances left out in turn (1 with one partner alone: the pair cannot say which of
    the two moved)."""
    rows, normals, frames, partner = _epipolar_pairs(res, R, t, c, first)
    inside = frames > run.frame if run.tail else frames <= run.frame
    ref = np.abs(_epipolar_px(res, rows[~inside], normals[~inside], np.zeros(3)))
    # the dof: the camera-frames (the count's unit), not the distances: a frame's distances share its
    # views' errors (both ends detected in one image at one instant, each against every partner)
    ref_views = len(np.unique(frames[~inside][ref <= res.limit_px]))
    ref = ref[ref <= res.limit_px]
    rows, normals, frames, partner = rows[inside], normals[inside], frames[inside], partner[inside]
    if len(np.unique(frames)) < MIN_PLACED or ref_views < 3:
        return False, 1.0
    e0, e, use = _turned(res, rows, normals)
    beyond = np.unique(frames[np.abs(e) > res.limit_px])
    back = binomial_tail(len(beyond), len(np.unique(frames)), q) >= FITS_LEVEL
    s2 = max(float(np.mean(ref**2)), 1e-300)
    left = float(np.sum(e[use] ** 2)) / max(int(use.sum()) - 3, 1) / s2  # what the turn leaves, against the same scatter
    fits = int(use.sum()) <= 3 or f_survival(int(use.sum()) - 3, ref_views, left) >= FITS_LEVEL
    # were a partner d the camera that moved, the distances against d would carry the whole turn: the
    # turn must stand out with each partner's distances left out as well (the largest p; with one
    # partner alone nothing is left: the pair cannot say which of them moved)
    p = 0.0
    for d in (None, *np.unique(partner).tolist()):
        keep = partner != d
        e0_d, e_d, use_d = _turned(res, rows[keep], normals[keep]) if d is not None else (e0, e, use)
        f = float(np.sum(e0_d[use_d] ** 2) - np.sum(e_d[use_d] ** 2)) / 3 / s2 if use_d.sum() > 3 else 0.0
        p = max(p, min(1.0, 2 * (run.frames - 1) * f_survival(3, ref_views, f)))
        if p >= STEP_ALPHA or not (back and fits):
            break  # named by none of them: the rest cannot lower the largest
    return back and fits, p


def _turned(res: Residuals, rows: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One turn of the camera fitted to its views' distances from their epipolar lines (``rows``,
    ``normals``: :func:`_epipolar_pairs`), Gauss-Newton, what is beyond the rig's limit at both
    poses (the first fit's and the solve's) left out of the second fit: (distances before (K,),
    after (K,), pixels, kept (K,) bool)."""
    e0 = _epipolar_px(res, rows, normals, np.zeros(3))
    w, use, h = np.zeros(3), np.ones(len(rows), bool), 1e-6
    for k in range(2 * TURN_STEPS):
        e = _epipolar_px(res, rows, normals, w)
        if k == TURN_STEPS:
            use = (np.abs(e) <= res.limit_px) | (np.abs(e0) <= res.limit_px)
        if use.sum() <= 3:
            return e0, e, use
        J = np.stack([(_epipolar_px(res, rows[use], normals[use], w + h * np.eye(3)[i]) - e[use]) / h for i in range(3)], 1)
        w = w - np.linalg.lstsq(J, e[use], rcond=None)[0]
    return e0, _epipolar_px(res, rows, normals, w), use


def rejected_moved(ids: list[str], res: Residuals, R: np.ndarray, t: np.ndarray) -> list[dict]:
    """A ``moved`` fault on the camera whose rejected camera-frames bunch at one end of its time
    beyond the rig's rate at p under :data:`STEP_ALPHA` and which one turn of the camera brings
    back (:func:`turned_back`); the smallest p where several do. Else, on the camera whose block
    one turn brings back to its partners' rays and whose turn stands out of its own scatter at p
    under :data:`STEP_ALPHA` (:func:`turn_against_partners`: a block too short for the count), the
    smallest such p; [] where none does, and in a rig of fewer than :data:`MIN_CAMERAS`."""
    if len(ids) < MIN_CAMERAS:
        return []
    runs = [(c, rq) for c, rq in enumerate(camera_runs(res, len(ids))) if rq is not None]
    for _, c, (r, q) in sorted((rq[0].p_value, c, rq) for c, rq in runs if rq[0].p_value < STEP_ALPHA):
        if turned_back(res, R, t, c, r, q) and not lens_predicts_block(res, R, t, c, r, q):
            return [rejected_fault(ids[c], r)]
    per = _every_cameras_frames(res, len(ids)) if runs else []
    turns = [(p, c, r) for c, (r, q) in runs for back, p in [turn_against_partners(res, R, t, c, r, q, per[c][0])]
             if back and p < STEP_ALPHA]
    if not turns:
        return []
    p, c, r = min(turns, key=lambda x: (x[0], x[1]))
    return [rejected_fault(ids[c], r, turn_p=p)]


def rejected_fault(cam: str, r: RejectedRun, turn_p: float | None = None) -> dict:
    """The ``moved`` fault of a camera whose rejected views bunch (:class:`RejectedRun`); turn_p:
    the p-value of :func:`turn_against_partners` where that named it (given in place of the count's)."""
    when = f"after frame {r.frame}" if r.tail else f"up to frame {r.frame}"
    other = "before" if r.tail else "after"
    if turn_p is not None:
        return {"kind": "moved", "camera": cam, "evidence": {
            "frame": r.frame, "rejected_block": r.rejected, "block_frames": r.block, "rejected": r.total_rejected,
            "frames": r.frames, "p_value": float(f"{turn_p:.3g}"), "rejected_views": True, "turn_against_partners": True},
            "message": f"{cam} moved during the capture: its {r.block} camera-frames {when} are off the other cameras' "
                       f"rays by one turn of it about its centre ({r.rejected} of them gross outliers; p {turn_p:.2g}), "
                       f"where its camera-frames {other} agree with them; fix its mount and calibrate again, or re-solve "
                       f"it from the frames on one side of {r.frame} alone (calibrate --from RESULT --solve-only {cam})"}
    return {"kind": "moved", "camera": cam, "evidence": {
        "frame": r.frame, "rejected_block": r.rejected, "block_frames": r.block, "rejected": r.total_rejected,
        "frames": r.frames, "p_value": float(f"{r.p_value:.3g}"), "rejected_views": True},
        "message": f"{cam} moved during the capture: {r.rejected} of its {r.block} camera-frames {when} are gross "
                   f"outliers against {r.total_rejected - r.rejected} of its {r.frames - r.block} {other} (p "
                   f"{r.p_value:.2g}), too far off for the outlier pass to keep, where the other cameras agree; "
                   f"fix its mount and calibrate again, or re-solve it from the frames on one side of {r.frame} alone "
                   f"(calibrate --from RESULT --solve-only {cam})"}
