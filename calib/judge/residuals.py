"""Every camera's residuals on the same observations, whichever method solved the rig.

The verdict judges the labelled wand pairs the pipeline started from (the same for ``ba``, ``lp``
and ``paper``: labelling comes before the method) and the point tracks, triangulated with the final
poses, outliers included: a camera's outliers count against that camera. Figures are given in the
units a user can check: pixels, the angle of the ray (pixels over focal length, which does not
depend on the resolution), and millimetres in the volume (the ray's distance from the point,
Qualisys's "camera residual").
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from wandcal.calib.geometry import finite_rows, projection_derivative, row_norms
from wandcal.calib.judge.quality import OUTLIER_SIGMAS, reject_worst_per_frame
from wandcal.calib.observations import PointTracks, WandPairs, camera_rows, robust_sigma
from wandcal.calib.start.labels import flatten
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

MIN_OUTLIER_PX = 1.0  # never call a residual under a pixel an outlier, however clean the rest
# the volume's extent: the box of the central 80% of the points, over 0.8 (its share of a
# uniformly filled box): far-off points (nearly parallel rays) leave it alone
EXTENT_QUANTILES = (10.0, 90.0)
EXTENT_SHARE = 0.8
RAY_ANGLE_POINTS = 4000  # points the median ray angle is taken over
# points (wand frames, tracks) of the rig a camera's sigma's standard error is taken over, on a
# stride: Brown's and Ushichka's sessions have 100-400 and are taken whole; a simulated 16 x 2500
# rig's standard error, 1-2%, is far under the measured 11% that holds as the least, so a sample
# of its frames tells it as well
PLACE_SE_POINTS = 400


@dataclass(frozen=True, eq=False)
class Residuals:
    """All observations' residuals with the final poses.

    camera: (M,) index; point: (M,) wand end 2 * frame + end, or -1 - track for a point track;
    xy: (M, 2) observed, normalised; residual: (M, 2) projected minus observed, normalised;
    focal: (M,) the camera's focal length, pixels; depth: (M,) the point's depth in the camera,
    metres (or the rig's units without a wand); outlier: (M,) bool, a gross outlier (beyond
    ``limit_px``, the rig's limit); X: (2F, 3) triangulated wand ends, outliers left out (NaN
    unseen); frames: (F,) capture frame numbers of the wand rows; extent: the volume's size.
    """

    camera: np.ndarray
    point: np.ndarray
    xy: np.ndarray
    residual: np.ndarray
    focal: np.ndarray
    depth: np.ndarray
    outlier: np.ndarray
    X: np.ndarray
    frames: np.ndarray
    extent: float
    limit_px: float

    @property
    def error_px(self) -> np.ndarray:
        """(M,) residual magnitudes, pixels (normalised residuals times the mean focal length)."""
        return row_norms(self.residual) * self.focal

    @cached_property
    def _rows(self) -> list[np.ndarray]:
        return camera_rows(self.camera, int(self.camera.max()) + 1 if len(self.camera) else 0)

    def rows_of(self, c: int) -> np.ndarray:
        """(M_c,) camera c's rows, ascending (``np.flatnonzero(self.camera == c)``, sorted once for all cameras)."""
        return self._rows[c] if c < len(self._rows) else np.zeros(0, dtype=np.int64)


def _depths(R: np.ndarray, t: np.ndarray, camera: np.ndarray, X: np.ndarray) -> np.ndarray:
    # np.take: a gather of rows at a fraction of fancy indexing's cost (numpy 2)
    return np.einsum("mj,mj->m", np.take(R[:, 2, :], camera, axis=0), X) + t[camera, 2]


def _wand_points(R: np.ndarray, t: np.ndarray, pairs: WandPairs, known, flat) -> np.ndarray:
    """(2F, 3) every labelled frame's ends: the solver's where it holds them (``known``: capture
    frame numbers (F2,) and ends (F2, 2, 3), world frame), triangulated with all cameras elsewhere.
    flat: ``flatten(pairs)``."""
    point, camera, xy = flat
    n = 2 * len(pairs.frames)
    if known is None or not len(known[0]) or np.shape(known[1])[1:] != (2, 3):
        return triangulate_points(R, t, point, camera, xy, n)
    frames, ends = known
    at = np.clip(np.searchsorted(pairs.frames, frames), 0, max(len(pairs.frames) - 1, 0))
    held = pairs.frames[at] == frames
    table = np.full((len(pairs.frames), 2, 3), np.nan)
    table[at[held]] = ends[held]
    X = table.reshape(n, 3)
    missing = ~np.isfinite(X[:, 0])
    rows = missing[point]
    if rows.any():  # the frames the solver dropped or never held: triangulated here
        X[missing] = triangulate_points(R, t, point[rows], camera[rows], xy[rows], n)[missing]
    return X


def _rows_by_camera(pair_camera: np.ndarray, track_camera: np.ndarray | None, n: int) -> list[np.ndarray]:
    """:func:`camera_rows` of the observations :func:`observation_residuals` lays out (every pair's
    first end, every pair's second end, then the point tracks: pair_camera (P,), track_camera (T,)
    or None), each camera's rows ascending, from a sort of the P pairs and the T tracks alone."""
    P = len(pair_camera)
    pieces = [camera_rows(pair_camera, n)]
    tracked = camera_rows(track_camera, n) if track_camera is not None else None
    return [np.concatenate([rows, rows + P] + ([tracked[c] + 2 * P] if tracked is not None else []))
            for c, rows in enumerate(pieces[0])]


def observation_residuals(R: np.ndarray, t: np.ndarray, pairs: WandPairs, tracks: PointTracks | None,
                          focal: np.ndarray, known: tuple[np.ndarray, np.ndarray] | None = None) -> Residuals:
    """Measure every labelled wand observation and point track against its point: the solver's
    wand ends where it holds them (``known``: capture frame numbers (F2,), ends (F2, 2, 3)), each
    other point triangulated with all cameras. A camera-frame that is a gross outlier is left out
    of its frame's triangulation (worst first, as the refinement does), so that its error stays with
    its own camera instead of spreading over the frame's others. R, t: (N, 3, 3), (N, 3) final
    poses; focal: (N, 2) fx, fy."""
    point, camera, xy = flat = flatten(pairs)
    X = _wand_points(R, t, pairs, known, flat)
    residual = reprojection_errors(R, t, point, camera, xy, X)  # kept where the points stay as they are
    first = row_norms(residual * np.take(focal, camera, axis=0))
    first_camera = camera
    if tracks is not None and len(tracks):
        points = triangulate_points(R, t, tracks.track, tracks.camera, tracks.xy, int(tracks.track.max()) + 1)
        track_res = reprojection_errors(R, t, tracks.track, tracks.camera, tracks.xy, points)
        first = np.concatenate([first, row_norms(track_res * focal[tracks.camera])])
        first_camera = np.concatenate([camera, tracks.camera])
    finite = np.isfinite(first)
    by_camera = _rows_by_camera(pairs.camera, tracks.camera if tracks is not None and len(tracks) else None,
                                int(first_camera.max()) + 1 if len(first_camera) else 0)
    every = bool(finite.all())  # a clean rig's: no masking
    sigmas = [robust_sigma(first[rows] if every else first[rows[finite[rows]]]) for rows in by_camera if len(rows)]
    limit = max(OUTLIER_SIGMAS * float(np.median(sigmas)) if sigmas else 0.0, MIN_OUTLIER_PX)
    P = len(pairs)
    worst = np.fmax(first[:P], first[P:len(point)]) if P else np.zeros(0)
    keep = np.ones(P, bool)
    if known is not None:
        # the solver's points were not pulled by the camera-frames it dropped: each is judged as it stands
        keep = ~(worst > limit)
    elif np.any(worst > limit):  # a clean rig has none: its one triangulation stands
        keep = reject_worst_per_frame(R, t, pairs, focal, limit)
        kept_point, kept_camera, kept_xy = flatten(pairs.subset(keep))
        X = triangulate_points(R, t, kept_point, kept_camera, kept_xy, 2 * len(pairs.frames))
        residual = reprojection_errors(R, t, point, camera, xy, X)
    depth = _depths(R, t, camera, np.take(X, point, axis=0))
    outlier = ~np.concatenate([keep, keep])
    cloud = [X[finite_rows(X)]]
    if tracks is not None and len(tracks):
        camera = np.concatenate([camera, tracks.camera])
        point = np.concatenate([point, -1 - tracks.track])
        xy = np.concatenate([xy, tracks.xy])
        residual = np.concatenate([residual, track_res])
        depth = np.concatenate([depth, _depths(R, t, tracks.camera, points[tracks.track])])
        outlier = np.concatenate([outlier, row_norms(track_res * focal[tracks.camera]) > limit])
        cloud.append(points[finite_rows(points)])
    ok = finite_rows(residual)
    pts = np.concatenate(cloud)
    lo, hi = np.percentile(pts, EXTENT_QUANTILES, axis=0) if len(pts) else (np.zeros(3), np.zeros(3))
    if ok.all():  # every row kept (a clean rig): no copies, and the rows by camera as sorted above
        out = Residuals(camera=camera, point=point, xy=xy, residual=residual,
                        focal=np.take(row_norms(focal) / np.sqrt(2), camera), depth=depth,
                        outlier=outlier, X=X, frames=pairs.frames, extent=float(np.linalg.norm(hi - lo)) / EXTENT_SHARE,
                        limit_px=limit)
        out.__dict__["_rows"] = by_camera  # Residuals._rows, the same camera_rows of the same cameras
        return out
    return Residuals(camera=camera[ok], point=point[ok], xy=xy[ok], residual=residual[ok],
                     focal=np.take(row_norms(focal) / np.sqrt(2), camera[ok]), depth=depth[ok], outlier=outlier[ok],
                     X=X, frames=pairs.frames, extent=float(np.linalg.norm(hi - lo)) / EXTENT_SHARE, limit_px=limit)


def camera_figures(res: Residuals, n_cameras: int, scaled: bool) -> list[dict]:
    """Per camera: ``observations`` judged, ``rms_px`` (all of them), ``inlier_rms_px``,
    ``noise_px`` (robust per-axis sigma of all), ``outlier_share`` (camera-frames that are gross
    outliers against the rig's limit), ``ray_mrad`` (the inliers' RMS ray angle) and
    ``ray_distance`` (their RMS ray distance from the points, in the capture's units: metres with a
    wand) and ``residual_mm`` (the same in millimetres; None when ``scaled`` is False)."""
    angles = row_norms(res.residual)  # every row's ray angle once (error_px's norm)
    err = angles * res.focal
    out: list[dict] = []
    for c in range(n_cameras):
        sel = res.rows_of(c)
        e = err[sel]
        if not len(e):
            out.append({"observations": 0, "rms_px": None, "inlier_rms_px": None, "noise_px": None,
                        "outlier_share": None, "ray_mrad": None, "ray_distance": None, "residual_mm": None})
            continue
        inl = ~res.outlier[sel]
        every = bool(inl.all())  # no outlier: the inliers' figures are the camera's, not copied again
        some = every or bool(inl.any())
        angle = angles[sel] if every else angles[sel][inl]
        # the ray's distance at the camera's typical depth: a point triangulated from nearly
        # parallel rays lies far off, and its depth would weigh more than all the others
        ray = angle * float(np.median(np.abs(res.depth[sel] if every else res.depth[sel][inl]))) if some else angle
        ms = np.mean(e**2)
        ray_ms = np.mean(ray**2) if some else None
        out.append({
            "observations": int(len(e)),
            "rms_px": float(np.sqrt(ms)),
            "inlier_rms_px": float(np.sqrt(ms if every else np.mean(e[inl] ** 2))) if some else None,
            "noise_px": robust_sigma(e),
            "outlier_share": float(1.0 - inl.mean()),
            "ray_mrad": float(1000 * np.sqrt(np.mean(angle**2))) if some else None,
            "ray_distance": float(np.sqrt(ray_ms)) if ray_ms is not None else None,
            "residual_mm": float(1000 * np.sqrt(ray_ms)) if scaled and ray_ms is not None else None,
        })
    return out


# the unknowns a point takes up from its views' 2 n residuals (decision 0073): a point track's
# three coordinates; a wand end's two and a half (a frame's two ends are six, less the length)
POINT_UNKNOWNS = 3.0
WAND_END_UNKNOWNS = 2.5


def ray_noise_factors(res: Residuals, n_cameras: int) -> list[float | None]:
    """Per camera: its rays' own noise over their fitted miss (``ray_distance``), >= 1.

    The miss is measured at points fitted to the same rays, which take up part of each ray's error:
    an observation of a point of n views keeps ``1 - h`` of its noise's square on average, with
    ``h = p / (2 n)`` its leverage (p the point's unknowns, :data:`POINT_UNKNOWNS`,
    :data:`WAND_END_UNKNOWNS`; the hat matrix's trace p shared by the 2 n residuals), so the ray's
    noise is the miss's mean of ``angle^2 / (1 - h)`` over the mean of ``angle^2``, square-rooted:
    1.41 at three views, 2 at two (the unbiased ``RSS / (m - p)`` of a least-squares fit, by row).
    The camera's inliers, as ``ray_distance``; None without them."""
    inl = ~res.outlier
    point = res.point[inl]
    if not len(point):
        return [None] * n_cameras
    at = point - point.min()  # wand ends >= 0, tracks < 0: one count of both (a bincount, not a sort)
    views = np.bincount(at)[at]
    unknowns = np.where(point >= 0, WAND_END_UNKNOWNS, POINT_UNKNOWNS)
    kept = 1.0 - unknowns / (2.0 * np.maximum(views, 2))
    square = row_norms(res.residual[inl]) ** 2
    # every camera's two sums in one pass each (bincount's running sums, not a sort and np.sum's
    # pairwise sums per camera: the same sums to ~1e-15 relative, rounding's order)
    camera = res.camera[inl]
    total = np.bincount(camera, weights=square, minlength=n_cameras)[:n_cameras]
    noise = np.bincount(camera, weights=square / kept, minlength=n_cameras)[:n_cameras]
    return [float(np.sqrt(s / m)) if m > 0 else None for s, m in zip(noise.tolist(), total.tolist())]


def held_out(R: np.ndarray, t: np.ndarray, pairs: WandPairs, c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera c against wand ends triangulated by the other cameras alone (frames two of them saw),
    so a camera at fault cannot pull the points towards itself.

    Returns (point (K,) 2 * frame + end of c's observations, xy (K, 2) observed, normalised;
    X (2F, 3) the others' triangulated ends)."""
    others = pairs.camera != c
    sub = pairs.subset(others)
    point, camera, xy = flatten(sub)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames))
    p_own, _, xy_own = flatten(pairs.subset(~others))
    seen = finite_rows(X[p_own])
    return p_own[seen], xy_own[seen], X


def median_ray_angle(R: np.ndarray, res: Residuals) -> float | None:
    """The median angle, radians, at which two cameras' rays meet at a point: each observation's
    ray against the first ray to that point. Nearly parallel rays leave the depth undetermined (a
    rig collapsed onto one spot, points at infinity). None when no point has two views."""
    if len(res.point) < 2:
        return None
    # a median over every point's rays is a median over a few thousand as well: keep the points
    # whose index falls on a stride (all their rays, so each point's first ray is among them)
    stride = max(1, -(-(int(res.point.max()) - int(res.point.min()) + 1) // RAY_ANGLE_POINTS))  # at most that many
    sample = np.flatnonzero(res.point % stride == 0)
    ray = np.concatenate([np.take(res.xy, sample, axis=0) - np.take(res.residual, sample, axis=0), np.ones((len(sample), 1))],
                         axis=1)  # the projected point's ray
    ray = np.einsum("mji,mj->mi", np.take(R, res.camera[sample], axis=0), ray)  # camera -> world directions
    ray /= row_norms(ray)[:, None]
    order = np.argsort(res.point[sample], kind="stable")
    k, r = np.take(res.point[sample], order), np.take(ray, order, axis=0)
    first = np.r_[True, k[1:] != k[:-1]]
    lead = np.maximum.accumulate(np.where(first, np.arange(len(k)), 0))
    cos = np.einsum("mi,mi->m", r, np.take(r, lead, axis=0))[~first]
    return float(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))) if len(cos) else None


def _place_rows(R: np.ndarray, res: Residuals, rows: np.ndarray, views: np.ndarray) -> np.ndarray:
    """(K, 2, 6) each of ``rows``' projection derivative in its camera's turn about its own centre
    and its centre, at the point (from its depth along the projected ray), weighed by the square
    root of 1 - 1/n for a point of n views (the point takes up 1/n of the error): per unit noise,
    J^T J is the row's information on the camera's place."""
    c = res.camera[rows]
    projected = np.take(res.xy, rows, axis=0) + np.take(res.residual, rows, axis=0)
    Xc = np.concatenate([projected, np.ones((len(rows), 1))], axis=1) * res.depth[rows][:, None]
    x, y, z = Xc[:, 0], Xc[:, 1], Xc[:, 2]
    # d (x/z, y/z) / d Xc, and d Xc / d turn = -[Xc]x, d Xc / d centre = -R
    D = projection_derivative(Xc)
    J = np.empty((len(rows), 2, 6))  # the turn's three columns, then the centre's, written in place
    for a in (0, 1):
        J[:, a, 0] = D[:, a, 2] * y - D[:, a, 1] * z
        J[:, a, 1] = D[:, a, 0] * z - D[:, a, 2] * x
        J[:, a, 2] = D[:, a, 1] * x - D[:, a, 0] * y
    Rc = np.take(R, c, axis=0)
    for a in (0, 1):  # -(D R) written out: einsum's three-term sums in the same order (the same bits), at a third of its cost
        for j in range(3):
            J[:, a, 3 + j] = -(D[:, a, 0] * Rc[:, 0, j] + D[:, a, 1] * Rc[:, 1, j] + D[:, a, 2] * Rc[:, 2, j])
    J *= np.sqrt(1.0 - 1.0 / np.maximum(views, 2))[:, None, None]
    return J


def place_sigma_errors(R: np.ndarray, res: Residuals, n_cameras: int) -> list[float | None]:
    """Per camera: the relative standard error of its place's sigma from how the information that
    places it is spread over its points (a wand frame, a point track), the bootstrap's over them.

    A sigma from the solver's covariance is sum-of-information driven: ``sigma^2 = tr(P I^-1)``,
    ``I = sum_f I_f`` over the camera's points f. Resampling the points changes it, to first order,
    by ``g_f = tr(P I^-1 I_f I^-1)`` each (their sum is sigma^2), so sigma^2's standard error is
    ``sqrt(n/(n-1) sum (g_f - mean g)^2)`` and sigma's half of it, relative. A camera placed by many
    alike points gets a few per cent; one that hinges on its few best-placed frames (a point far
    off its axis, seen from afar) gets 20% and more: its sigma would change that much with the
    frames a capture happened to catch. Gross outliers (``res.outlier``) are left out. None for a
    camera with fewer than two points or a singular information matrix. R: (N, 3, 3) poses."""
    # the points on a stride (a wand frame's two ends together) stand for all: the standard error of
    # n points is that of the n / stride kept, over sqrt(stride)
    unit = np.where(res.point >= 0, res.point // 2, res.point)
    stride = max(1, (int(unit.max()) - int(unit.min()) + 1) // PLACE_SE_POINTS) if len(unit) else 1
    inl = np.flatnonzero(~res.outlier & np.isfinite(res.depth) & (res.depth > 0) & (unit % stride == 0))
    _, where, counts = np.unique(res.point[inl], return_inverse=True, return_counts=True)
    J = _place_rows(R, res, inl, counts[where])
    _, unit_index = np.unique(unit[inl], return_inverse=True)
    out: list[float | None] = []
    for mine in camera_rows(res.camera[inl], n_cameras):
        _, group = np.unique(unit_index[mine], return_inverse=True)
        n = int(group.max()) + 1 if len(group) else 0
        rows = np.take(J, mine, axis=0).reshape(-1, 6)
        try:
            cov = np.linalg.inv(rows.T @ rows) if n >= 2 else None
        except np.linalg.LinAlgError:
            cov = None
        if cov is None:
            out.append(None)
            continue
        # g_f = tr(P^T I_f P) = |J_f P|^2 with P the covariance's centre columns
        g = np.bincount(group, (((rows @ cov[:, 3:]) ** 2).sum(axis=1)).reshape(-1, 2).sum(axis=1), minlength=n)
        total = float(g.sum())
        se = 0.5 * float(np.sqrt(n / (n - 1) * np.sum((g - g.mean()) ** 2))) / total if total > 0 else None
        out.append(se / np.sqrt(stride) if se is not None else None)
    return out
