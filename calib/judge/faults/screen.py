"""Why one camera disagrees with the others: its timing, its intrinsics, or something else.

A camera is judged against wand ends the *other* cameras triangulate
(:func:`wandcal.calib.judge.residuals.held_out`), so a camera at fault cannot hide by pulling the
points towards itself. Two patterns of its residuals ``r = projected - observed`` (normalised
image coordinates) name a cause:

- **timing**: a camera ``d`` frames late (docs/result-format.md's sign, as ``--sync auto``
  reports it) exposes its frame k at the others' time k + d and shows the wand of then, so
  ``r ~ -d v`` with ``v`` the wand's image velocity per frame. A whole-frame search finds the best
  shift, and least squares on ``v`` the fraction: ``d = -sum(r . v) / sum(v . v)`` with standard
  error ``sigma / sqrt(sum |v|^2)``. It is named by its effect in pixels, not by a fraction of a
  frame: at 10 Hz a twelfth of a frame moves the blobs 3 px, at 200 Hz a third of one may not;
- **intrinsics**: with its focal length off by a factor ``1 + a`` the observations are scaled
  about the principal point, ``r ~ a x``; a radial-distortion error gives ``r ~ dk1 |x|^2 x``; a
  principal point error a constant. Least squares of ``r`` on these columns beside the camera's
  own six pose columns (a pose error is not a lens error) says how much of the residual the lens
  explains.

The share of the camera's residual each pattern explains decides; docs/verdict.md derives the
limits.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from wandcal.calib.geometry import finite_rows, rotvec_to_matrix, row_norms
from wandcal.calib.observations import robust_sigma

MAX_SHIFT_FRAMES = 10  # the whole-frame search; a larger offset is a recording of another take
TRIM_SIGMAS = 5.0  # residuals beyond this after a fit are outliers, left out of the next fit
# A pattern names the cause when it explains at least this share of the camera's residual
# variance: pure noise leaves ~ (columns / observations), ~0.1%; a cause that only matches the
# noise (share ~0.5) doubles the camera's residual, the level at which it stands out of the rig.
EXPLAINED_SHARE = 0.3
MIN_T_STAT = 5.0  # and its coefficient is this many standard errors from zero
ASPECT_F = MIN_T_STAT**2  # an aspect error (fy alone) joins the lens pattern at this F: 5 standard errors
# A lens error can hide in a camera's pose: a k1 off by 0.17 on a camera whose samples covered a
# fifth of its image moved it 5.8 mm while its residual's lens pattern held only 10% of the
# variance (at F = 105, against F < 10 on every clean camera and F < 5 on easyWand's real
# sessions). Beyond this F a smaller share names the lens too.
LENS_STRONG_F = 100.0
LENS_HIDDEN_SHARE = 0.05
# an offset is named when, at the wand's median image speed, it moves the camera's blobs by at
# least this many of its residual's sigmas (left after the fit): whatever the frame rate, an
# offset that moves the blobs less than the noise cannot be told from it (as timing_pairs.MIN_EFFECT)
MIN_EFFECT_SIGMAS = 0.5
POSE_STEP = 1e-6  # finite-difference step of the pose columns, radians and metres
# observations a camera's lens screen looks at (evenly spaced in the capture): a pattern that
# holds 20% of the variance has an F statistic in the hundreds at 1,500 already
SCREEN_ROWS = 1500


@dataclass(frozen=True)
class TimingFault:
    """offset_frames: the camera's frame k was exposed at the others' frame k + offset (positive:
    late, docs/result-format.md); offset_std_frames its standard error; explained: the share of
    the residual variance it explains; effect_sigmas: how far the offset moves the camera's blobs
    at the wand's median image speed, in sigmas of the residual left after the fit."""

    offset_frames: float
    offset_std_frames: float
    explained: float
    observations: int
    effect_sigmas: float = 0.0


@dataclass(frozen=True)
class Lens:
    """focal_error: rig.json's focal length over the one the data suggest, minus one; k1_error,
    principal_error (2,) (normalised units) likewise; explained: the share of the residual
    variance (beyond the camera's pose) they explain; f_stat: the F statistic of that;
    aspect_error: rig.json's fy over the data's beyond the common focal error (0 where not fitted)."""

    focal_error: float
    k1_error: float
    principal_error: tuple[float, float]
    explained: float
    f_stat: float
    aspect_error: float = 0.0


def offset_text(offset: float, std: float) -> str:
    """"0.0185 +- 0.0018 frames early": an offset (frames, positive: late) and its standard error,
    to the decimals that show the error's first two digits (two at least)."""
    decimals = 2 if not np.isfinite(std) or std <= 0 else int(np.clip(1 - np.floor(np.log10(std)), 2, 6))
    return f"{abs(offset):.{decimals}f} +- {std:.{decimals}f} frames {'late' if offset > 0 else 'early'}"


def _project(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    Xc = X @ R.T + t
    return Xc[:, :2] / Xc[:, 2:]


def _frame_table(frames: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, int]:
    """(T, 2, 3) the ends by capture frame number (NaN where not triangulated), and the first number."""
    first = int(frames.min()) if len(frames) else 0
    table = np.full((int(frames.max()) - first + 1 if len(frames) else 0, 2, 3), np.nan)
    table[frames - first] = X.reshape(-1, 2, 3)
    return table, first


def _shifted(table: np.ndarray, at: np.ndarray, near: np.ndarray) -> np.ndarray:
    """(K, 3) the wand end at table rows ``at`` nearer to ``near`` (K, 3) (NaN outside the
    recording). Labelling orders a frame's two ends alike in every camera, not alike from one
    frame to the next, so the same marker in another frame is the nearer end."""
    ok = (at >= 0) & (at < len(table))
    out = np.full((len(at), 3), np.nan)
    both = table[at[ok]]  # (k, 2, 3)
    d = np.linalg.norm(both - near[ok][:, None, :], axis=2)
    pick = np.where(np.isnan(d[:, 1]) | (d[:, 0] <= d[:, 1]), 0, 1)
    out[ok] = both[np.arange(len(pick)), pick]
    return out


def _trimmed(r: np.ndarray) -> np.ndarray:
    """(K,) bool: residual rows (K, 2) within :data:`TRIM_SIGMAS` robust sigmas."""
    e = row_norms(r)
    return np.isfinite(e) & (e <= TRIM_SIGMAS * max(robust_sigma(e[np.isfinite(e)]), 1e-12))


@cache
def _step_turn(j: int) -> np.ndarray:
    """(3, 3) the turn of pose parameter j's finite-difference step (the identity for a translation's)."""
    step = np.zeros(3)
    if j < 3:
        step[j] = POSE_STEP
    return rotvec_to_matrix(step)


def _pose_differences(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """:func:`_pose_columns` by forward differences of :data:`POSE_STEP`: each step's projection
    ``X (exp(w) R)^T + t + dt`` over the base's. A translation's step leaves the turned rotation
    R itself (bit for bit): its points' rotation is the base's, not multiplied again."""
    RX = X @ R.T
    base = _divided(RX + t)
    cols = np.empty((2 * len(X), 6))
    for j in range(6):
        step = np.zeros(6)
        step[j] = POSE_STEP
        turned = _step_turn(j) @ R
        same = R.flags.c_contiguous and turned.tobytes() == R.tobytes()
        cols[:, j] = ((_divided((RX if same else X @ turned.T) + (t + step[3:])) - base) / POSE_STEP).ravel()
    return cols


def _divided(Xc: np.ndarray) -> np.ndarray:
    return Xc[:, :2] / Xc[:, 2:]


def _pose_columns(R: np.ndarray, t: np.ndarray, X: np.ndarray, differences: bool = False) -> np.ndarray:
    """(2K, 6) the projection's derivative with respect to the camera's rotation increment
    (``R -> exp(w) R``) and translation, at points X (K, 3); rows x0, y0, x1, y1, ...
    tA (issue 31): analytic, ``dXc/dw_j = e_j x (R X)``, ``dXc/dt_j = e_j``, through ``d(x/z, y/z)/dXc``
    (one pass where the finite differences took seven projections). ``differences``: by forward
    differences of :data:`POSE_STEP` as before, for figures a result writes (the focal limit's, to
    its last digit; the two differ by ~1e-6 of a column)."""
    if differences:
        return _pose_differences(R, t, X)
    RX = X @ R.T
    Xc = RX + t
    z = Xc[:, 2]
    x, y = Xc[:, 0] / z, Xc[:, 1] / z
    # e_j x RX for j = 0, 1, 2, then the translations' e_j: (6, K, 3) the camera-frame motions,
    # each column (v_x - x v_z) / z, (v_y - y v_z) / z, all six in one pass
    moves = np.zeros((6, len(X), 3))
    moves[0, :, 1], moves[0, :, 2] = -RX[:, 2], RX[:, 1]
    moves[1, :, 0], moves[1, :, 2] = RX[:, 2], -RX[:, 0]
    moves[2, :, 0], moves[2, :, 1] = -RX[:, 1], RX[:, 0]
    moves[3:, :, :] = np.eye(3)[:, None, :]
    cols = np.empty((len(X), 2, 6))
    cols[:, 0, :] = ((moves[:, :, 0] - x * moves[:, :, 2]) / z).T
    cols[:, 1, :] = ((moves[:, :, 1] - y * moves[:, :, 2]) / z).T
    return cols.reshape(2 * len(X), 6)


def resect(R: np.ndarray, t: np.ndarray, X: np.ndarray, xy: np.ndarray, iterations: int = 6):
    """The camera's pose refitted to points X (K, 3) seen at xy (K, 2) by Gauss-Newton from (R, t),
    leaving out residuals beyond :data:`TRIM_SIGMAS`. Returns (R, t, residual (K, 2), kept (K,))."""
    ok = finite_rows(X)
    for _ in range(iterations):
        r = _project(R, t, X) - xy
        keep = ok & _trimmed(np.where(ok[:, None], r, np.nan))
        if keep.sum() < 10:
            break
        J = _pose_columns(R, t, X[keep])
        step = np.linalg.lstsq(J, -r[keep].ravel(), rcond=None)[0]
        R, t = rotvec_to_matrix(step[:3]) @ R, t + step[3:]
        if np.abs(step).max() < 1e-10:
            break
    r = _project(R, t, X) - xy
    return R, t, r, ok & _trimmed(np.where(ok[:, None], r, np.nan))


def _share(y: np.ndarray, base: np.ndarray, extra: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Least squares of y on [base | extra]: (the share of y's variance beyond ``base`` that
    ``extra`` explains, extra's coefficients, its F statistic). By the normal equations of the
    scaled columns (a 10 x 10 system at most): a camera's thousands of rows cost one pass."""
    both = np.concatenate([base, extra], axis=1)
    scale = np.sqrt(np.add.reduce(both * both, axis=0))  # np.linalg.norm(both, axis=0) without its copy
    scale[scale == 0] = 1.0
    A = both / scale
    return _normal_share(A.T @ A, A.T @ y, float(y @ y), scale, base.shape[1], len(y))


def _normal_share(G: np.ndarray, b: np.ndarray, yy: float, scale: np.ndarray, k: int, rows: int
                  ) -> tuple[float, np.ndarray, float]:
    """:func:`_share` from the scaled columns' normal equations: G (n, n) = A^T A, b (n,) = A^T y,
    yy = y^T y, scale (n,) the columns' norms, the first ``k`` columns the base, ``rows`` y's length."""

    def fit(n: int) -> tuple[np.ndarray, float]:
        x = np.linalg.lstsq(G[:n, :n], b[:n], rcond=None)[0]  # a tiny system: lstsq for a rank-poor one
        return x, max(yy - float(b[:n] @ x), 0.0)

    _, rss0 = fit(k)
    coef, rss1 = fit(len(G))
    dof = max(rows - len(G), 1)
    f_stat = ((rss0 - rss1) / (len(G) - k)) / max(rss1 / dof, 1e-300)
    return (1 - rss1 / rss0 if rss0 > 0 else 0.0), (coef / scale)[k:], float(f_stat)


def analyse_camera(R: np.ndarray, t: np.ndarray, frames: np.ndarray, X: np.ndarray, point: np.ndarray,
                   xy: np.ndarray) -> tuple[TimingFault | None, Lens | None]:
    """Camera c's timing and lens patterns against wand ends the others triangulated.

    Args:
        R, t: (3, 3), (3,) camera c's pose (a start: it is refitted at every shift tried).
        frames: (F,) capture frame numbers of the wand rows; X: (2F, 3) the others' ends (NaN
            where they did not see one); point: (K,) 2 * frame + end of c's observations;
            xy: (K, 2) those observations, normalised.
    """
    if len(point) < 20:
        return None, None
    table, first = _frame_table(frames, X)
    row = frames[point // 2] - first
    own = X[point]
    fits = {}
    for d in range(-MAX_SHIFT_FRAMES, MAX_SHIFT_FRAMES + 1):
        ends = _shifted(table, row - d, own)
        if np.isfinite(ends).all(axis=1).sum() < len(point) // 2:
            continue
        Rd, td, r, keep = resect(R, t, ends, xy)
        fits[d] = (np.median(row_norms(r[keep])) if keep.any() else np.inf, Rd, td, ends)
    if not fits:
        return None, None
    best = min(fits, key=lambda d: fits[d][0])
    _, Rb, tb, here = fits[best]
    v = (_project(Rb, tb, _shifted(table, row - best + 1, here))
         - _project(Rb, tb, _shifted(table, row - best - 1, here))) / 2  # image velocity per frame
    r = _project(Rb, tb, here) - xy
    keep = _trimmed(r) & finite_rows(v) & finite_rows(here)
    if keep.sum() < 20:
        return None, None
    pose = _pose_columns(Rb, tb, here[keep])
    y = r[keep].ravel()
    share, coef, _ = _share(y, pose, v[keep].reshape(-1, 1))
    frac = float(coef[0])
    # the shift's own share: the residual with the pose refitted at no shift, against at the best
    rss_best = float(np.sum(r[keep] ** 2))
    r0 = fits[0][0] if 0 in fits else np.inf
    whole = 1 - (fits[best][0] / r0) ** 2 if best != 0 and np.isfinite(r0) and r0 > 0 else 0.0
    left = y - np.concatenate([pose, v[keep].reshape(-1, 1)], axis=1) @ np.linalg.lstsq(
        np.concatenate([pose, v[keep].reshape(-1, 1)], axis=1), y, rcond=None)[0]
    sigma = np.sqrt(np.sum(left**2) / max(len(y) - 7, 1))
    vv = np.einsum("ki,ki->", v[keep], v[keep])
    speed = float(np.median(row_norms(v[keep])))
    # c's frame k matched the others' k - best - frac: exposed then (docs/result-format.md's sign)
    offset = -(best + frac)
    timing = TimingFault(offset_frames=offset, offset_std_frames=float(sigma / np.sqrt(vv)) if vv > 0 else np.inf,
                         explained=float(max(share, whole)) if rss_best > 0 else 0.0, observations=int(keep.sum()),
                         effect_sigmas=abs(offset) * speed / sigma if sigma > 0 else np.inf)
    return timing, _lens_fit(y, pose, xy[keep])


def lens_columns(xy: np.ndarray, aspect: bool = False) -> np.ndarray:
    """(2K, 4) the lens pattern's columns at observations xy (K, 2), normalised: a focal-length
    error (r ~ a x), a k1 error (r ~ dk1 |x|^2 x), the principal point's two; with ``aspect`` a
    fifth, fy alone (r_y ~ b y): (2K, 5). Rows x0, y0, x1, y1, ... as :func:`_pose_columns`."""
    K = len(xy)
    radius2 = np.sum(xy**2, axis=1, keepdims=True)
    columns = np.stack([xy.ravel(), (xy * radius2).ravel(), np.tile([1.0, 0.0], K), np.tile([0.0, 1.0], K)], axis=1)
    if aspect:
        return np.concatenate([columns, (xy * [0.0, 1.0]).ravel()[:, None]], axis=1)
    return columns


def _lens_fit(y: np.ndarray, pose: np.ndarray, xy: np.ndarray, aspect: bool = False) -> Lens:
    """The lens pattern of residuals y (2K,) beside the pose columns (2K, 6): a focal-length error
    (r ~ a x), a k1 error (r ~ dk1 |x|^2 x) and a principal-point shift, at observations xy (K, 2).
    With ``aspect``, an error of fy alone too (r_y ~ b y: the aspect ratio, which neither the pose
    nor a focal length common to both axes takes up), where it is significant beyond the other
    four (its own F at least :data:`ASPECT_F`): a column that explains nothing would only dilute
    the pattern's F, and a k1 left out would go unnamed."""
    columns = lens_columns(xy)
    share, coef, f_stat = _share(y, pose, columns)
    aspect_error = 0.0
    if aspect:
        stretch = (xy * [0.0, 1.0]).ravel()[:, None]
        if _share(y, np.concatenate([pose, columns], axis=1), stretch)[2] >= ASPECT_F:
            share, coef, f_stat = _share(y, pose, lens_columns(xy, aspect=True))
            aspect_error = float(coef[4])
    return Lens(focal_error=float(coef[0]), k1_error=float(coef[1]), principal_error=(float(coef[2]), float(coef[3])),
                explained=float(share), f_stat=f_stat, aspect_error=aspect_error)


def classify(timing: TimingFault | None, lens: Lens | None) -> tuple[str, dict]:
    """("timing" | "intrinsics" | "unexplained", evidence) from a camera's two patterns."""
    evidence: dict = {}
    timing_share = lens_share = 0.0
    if timing is not None:
        evidence["timing"] = {"offset_frames": round(timing.offset_frames, 3),
                              "offset_std_frames": round(timing.offset_std_frames, 4),
                              "explained_share": round(timing.explained, 3),
                              "effect_sigmas": round(timing.effect_sigmas, 2)}
        if (timing.effect_sigmas >= MIN_EFFECT_SIGMAS
                and abs(timing.offset_frames) >= MIN_T_STAT * timing.offset_std_frames):
            timing_share = timing.explained
    if lens is not None:
        evidence["intrinsics"] = {"focal_error": round(lens.focal_error, 5), "k1_error": round(lens.k1_error, 5),
                                  "explained_share": round(lens.explained, 3)}
        if lens.f_stat >= MIN_T_STAT**2:
            lens_share = lens.explained
    hidden_lens = lens is not None and lens.f_stat >= LENS_STRONG_F and lens.explained >= LENS_HIDDEN_SHARE
    if max(timing_share, lens_share) < EXPLAINED_SHARE:
        return ("intrinsics" if hidden_lens and timing_share < EXPLAINED_SHARE else "unexplained"), evidence
    return ("timing" if timing_share >= lens_share else "intrinsics"), evidence


def lens_screen(R: np.ndarray, t: np.ndarray, res, c: int) -> Lens | None:
    """A quick look for camera c's lens pattern in the residuals every camera triangulated
    (:class:`wandcal.calib.judge.residuals.Residuals`), without solving anything again: a lens
    error can hide in a camera's pose, its residuals hardly above the others', while the pose is
    millimetres off. A pattern found here sends the camera to :func:`analyse_camera`."""
    sel = res.rows_of(c)
    sel = sel[(res.point[sel] >= 0) & ~res.outlier[sel]]
    if len(sel) < 20:
        return None
    sel = sel[:: max(1, len(sel) // SCREEN_ROWS)]
    X = np.take(res.X, res.point[sel], axis=0)  # take: a 2-D gather at a tenth of indexing's cost
    xy, r = np.take(res.xy, sel, axis=0), np.take(res.residual, sel, axis=0)
    ok = finite_rows(X)
    if not ok.all():
        X, xy, r = X[ok], xy[ok], r[ok]
    return _screen_fit(r.ravel(), R[c], t[c], X, xy)


def _screen_fit(y: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, xy: np.ndarray) -> Lens:
    """:func:`_lens_fit` of y (2K,) on :func:`_pose_columns` at X (K, 3) and :func:`lens_columns` at
    xy (K, 2), its ten columns written into one (2K, 10) array and its normal matrix scaled after
    the product (the columns' norms from its diagonal), not before: no copies of the rows (half
    the screen's time). The same columns bit for bit and the same least squares; only the normal
    matrix's rounding differs from :func:`_share`'s, by which the share and F moved by at most
    2.1e-11 relative (every camera of simulated 16 x 2500, 8 x 1500, 6 x 800 and 4 x 300 rigs):
    the screen's suspects change only for a statistic that close to its limit. Nothing of it is
    written."""
    RX = X @ R.T
    Xc = RX + t
    z = Xc[:, 2]
    x, yn = Xc[:, 0] / z, Xc[:, 1] / z
    M = np.zeros((len(X), 2, 10))  # rows x0, y0, x1, y1, ...: the pose's six, then the lens's four
    M[:, 0, 0], M[:, 0, 1], M[:, 0, 2], M[:, 0, 3], M[:, 0, 5] = (
        -(x * RX[:, 1]) / z, (RX[:, 2] + x * RX[:, 0]) / z, -RX[:, 1] / z, 1.0 / z, -x / z)
    M[:, 1, 0], M[:, 1, 1], M[:, 1, 2], M[:, 1, 4], M[:, 1, 5] = (
        (-RX[:, 2] - yn * RX[:, 1]) / z, (yn * RX[:, 0]) / z, RX[:, 0] / z, 1.0 / z, -yn / z)
    radius2 = np.einsum("ki,ki->k", xy, xy)
    M[:, :, 6] = xy
    M[:, :, 7] = xy * radius2[:, None]
    M[:, 0, 8] = M[:, 1, 9] = 1.0
    A = M.reshape(-1, 10)
    G, b = A.T @ A, A.T @ y
    scale = np.sqrt(np.diag(G).copy())
    scale[scale == 0] = 1.0
    share, coef, f_stat = _normal_share(G / np.outer(scale, scale), b / scale, float(y @ y), scale, 6, len(y))
    return Lens(focal_error=float(coef[0]), k1_error=float(coef[1]), principal_error=(float(coef[2]), float(coef[3])),
                explained=float(share), f_stat=f_stat)
