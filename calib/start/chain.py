"""The camera graph of a capture: which cameras share wand frames and single-point tracks, and
each linked pair's relative pose from its essential matrix, scaled by the wand length or by
points that cameras already placed have triangulated.

A pair's correspondences are its shared wand ends (each frame offers both matchings of its two
ends, and RANSAC keeps the right one, as in easyWand and Argus) and its shared point tracks. A
wand frame counts as two correspondences, a track as one.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from wandcal.calib.errors import Failure
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.triangulate import triangulate_points

ESSENTIAL_THRESHOLD_PX = 2.0  # RANSAC inlier threshold; blob noise is well under a pixel, digitised points ~1.5 px
ESSENTIAL_CONFIDENCE = 0.9999
MAX_PAIR_FRAMES = 150  # wand frames per pair given to RANSAC (600 candidate matches): a start needs no more
MAX_PAIR_TRACKS = 300  # point tracks per pair given to RANSAC
MIN_PAIR_MATCHES = 10  # correspondences a pair needs: five fix the essential matrix, the rest must confirm it
MIN_SCALE_FRAMES = 3  # shared wand frames that fix a pair's scale (median of their lengths)
MIN_SCALE_POINTS = 3  # already-triangulated points that fix a pair's scale (median of their ratios)
# NumPy steps per counted pair of co_seen's sparse count against one multiply-add of the dense
# product: above it the product is cheaper (an 8-camera rig whose every frame is in all 8)
SPARSE_COST = 16
MAX_SPARSE_PAIRS = 2_000_000  # the sparse count's index arrays stay near 100 MB; past it the product (its F x N floats)
REFINE_STEPS = 5  # Gauss-Newton steps on the Sampson error; the RANSAC pose is within a degree


@dataclass(frozen=True, eq=False)
class Views:
    """Who saw what.

    wand: (F, N) row of :class:`WandPairs` holding camera n's two blobs in frame f, -1 where it
    did not see both ends; track: (T, N) row of :class:`PointTracks` holding camera n's
    observation of track k, -1 where it did not see it.
    """

    wand: np.ndarray
    track: np.ndarray

    @property
    def n_cams(self) -> int:
        return self.wand.shape[1]

    def links(self, capped: bool = False) -> np.ndarray:
        """(N, N) correspondences each camera pair shares: 2 per wand frame plus 1 per track
        (the diagonal holds each camera's own count); ``capped``: only as many as
        :func:`pair_pose` uses."""
        frames, tracks = self._shared
        if capped:
            frames, tracks = np.minimum(frames, MAX_PAIR_FRAMES), np.minimum(tracks, MAX_PAIR_TRACKS)
        return 2 * frames + tracks

    @cached_property
    def _shared(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, N) wand frames and tracks each camera pair shares, once per Views (:func:`co_seen`)."""
        return co_seen(self.wand >= 0), co_seen(self.track >= 0)

    def shared(self, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
        """(wand frames (S,), tracks (K,)) both cameras see."""
        return (
            np.flatnonzero((self.wand[:, a] >= 0) & (self.wand[:, b] >= 0)),
            np.flatnonzero((self.track[:, a] >= 0) & (self.track[:, b] >= 0)),
        )


def co_seen(seen: np.ndarray) -> np.ndarray:
    """(N, N) int64: for each pair of columns of ``seen`` (F, N) bool, the rows where both are
    True (the diagonal: each column's own count).

    Where each row holds few of the N columns (a sparse rig's frame is in 2-4 of 128 cameras), the
    pairs of each row's columns are counted, sum(k^2) of them for rows of k: at 128 x 3000 about
    30,000, against the product's F N^2 = 49M multiply-adds (35-60 CPU ms with BLAS's threads, and
    the start made three: 0.17-0.22 CPU s). Dense tables, and tables whose pairs would not fit in
    :data:`MAX_SPARSE_PAIRS`, take the product, in floating point, exact to 2^53 (NumPy's integer
    product is a plain loop). Both count the same integers.
    """
    F, N = seen.shape
    rows, cols = np.nonzero(seen)  # row-major: each row's columns together
    per = np.bincount(rows, minlength=F)
    pairs = int(per @ per)
    if pairs * SPARSE_COST > F * N * N or pairs > MAX_SPARSE_PAIRS:
        w = seen.astype(float)
        return (w.T @ w).astype(np.int64)
    return row_pairs(rows, cols, N)


def row_pairs(rows: np.ndarray, cols: np.ndarray, n: int) -> np.ndarray:
    """(n, n) int64: for each pair of columns, the rows holding both (the diagonal: each column's
    rows), from the table's True entries (rows, cols) (E,), sorted by row, each (row, col) once:
    the pairs of each row's columns counted, sum(k^2) of them for rows of k (:func:`co_seen`'s
    sparse count; guidance counts its camera pairs with it from the wand's camera-frames)."""
    per = np.bincount(rows)
    first = np.cumsum(per) - per  # each row's first entry in (rows, cols)
    k = per[rows]
    a = np.repeat(np.arange(len(rows)), k)  # each entry against every entry of its row
    b = np.repeat(first[rows] - np.cumsum(k) + k, k) + np.arange(int(k.sum()))
    return np.bincount(cols[a] * n + cols[b], minlength=n * n).reshape(n, n).astype(np.int64)


def camera_groups(linked: np.ndarray, keep: np.ndarray | None = None) -> list[list[int]]:
    """The connected groups of cameras of the graph ``linked`` (N, N) bool, restricted to ``keep``
    (N,) bool (all when None): sorted camera indices each, the groups largest first (ties: by
    their lowest camera)."""
    keep = np.ones(len(linked), bool) if keep is None else keep
    graph = linked & keep[:, None] & keep[None, :]
    left = keep.copy()
    groups = []
    while left.any():
        # a group grows by all its cameras' links at once: one pass per step of its diameter
        # (scipy's connected components would cost its 0.7 s import to every calibration)
        group = np.zeros(len(left), bool)
        group[np.argmax(left)] = True
        while True:
            grown = group | graph[group].any(axis=0)
            if np.array_equal(grown, group):
                break
            group = grown
        groups.append(np.flatnonzero(group).tolist())
        left &= ~group
    return sorted(groups, key=lambda g: (-len(g), g[0]))


def camera_views(pairs: WandPairs, points: PointTracks | None, n_cams: int) -> Views:
    """The :class:`Views` tables of a capture's wand pairs and (optional) point tracks."""
    wand = np.full((len(pairs.frames), n_cams), -1, dtype=np.int64)
    wand[pairs.frame, pairs.camera] = np.arange(len(pairs))
    if points is None:
        return Views(wand, np.full((0, n_cams), -1, dtype=np.int64))
    track = np.full((points.n_tracks, n_cams), -1, dtype=np.int64)
    track[points.track, points.camera] = np.arange(len(points))
    return Views(wand, track)


def spread(index: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` entries of ``index`` (M,), evenly spaced so a subsample covers the whole
    wand path rather than its start."""
    if len(index) <= most:
        return index
    return index[np.linspace(0, len(index) - 1, most).round().astype(np.int64)]


@dataclass(frozen=True, eq=False)
class PairPose:
    """Camera b relative to camera a, up to scale: ``x_b = R @ x_a + s * u`` for a point's
    coordinates x_a, x_b in the two camera frames and the pair's baseline s (metres).

    R: (3, 3); u: (3,) unit vector; inliers: correspondences that fit; frames: (S,) the shared
    wand frames used; swap: (S,) bool, b's ends in those frames are in the opposite order to a's;
    fits: (S,) bool, both ends of the frame fit the epipolar geometry.
    """

    a: int
    b: int
    R: np.ndarray
    u: np.ndarray
    inliers: int
    frames: np.ndarray
    swap: np.ndarray
    fits: np.ndarray

    def __bool__(self) -> bool:
        return True


def pair_pose(
    pairs: WandPairs, points: PointTracks | None, views: Views, a: int, b: int, focal_px: float
) -> PairPose | Failure:
    """Relative pose of cameras a and b from the essential matrix of their shared wand ends and
    point tracks (five-point RANSAC on a subsample, then Gauss-Newton on the Sampson error of
    its inliers). OpenCV's USAC RANSAC is used: with its local optimisation, on a simulated pair
    with 0.3 px noise and 100-150 frames, it took 4 ms instead of 35-45 ms and its rotation was
    within 0.05-0.3 degree instead of 0.3-0.9.

    Args:
        pairs, points: the observations (normalised coordinates); points may be None.
        views: their :class:`Views`.
        a, b: camera indices.
        focal_px: a focal length of the two cameras in pixels, to set the inlier threshold.

    Returns:
        :class:`PairPose`, or a Failure saying why.
    """
    frames, tracks = views.shared(a, b)
    have = 2 * len(frames) + len(tracks)
    if have < MIN_PAIR_MATCHES:
        return Failure(f"{have} shared correspondences, {MIN_PAIR_MATCHES} needed")
    frames, tracks = spread(frames, MAX_PAIR_FRAMES), spread(tracks, MAX_PAIR_TRACKS)
    xa, xb = pairs.xy[views.wand[frames, a]], pairs.xy[views.wand[frames, b]]
    ya = points.xy[views.track[tracks, a]] if points is not None and len(tracks) else np.zeros((0, 2))
    yb = points.xy[views.track[tracks, b]] if points is not None and len(tracks) else np.zeros((0, 2))
    p1 = np.concatenate([xa[:, 0], xa[:, 1], xa[:, 0], xa[:, 1], ya])
    p2 = np.concatenate([xb[:, 0], xb[:, 1], xb[:, 1], xb[:, 0], yb])
    threshold = ESSENTIAL_THRESHOLD_PX / focal_px
    E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.USAC_DEFAULT, ESSENTIAL_CONFIDENCE, threshold)
    if E is None or E.shape[1:] != (3,) or len(E) < 3:
        return Failure("no essential matrix fits their shared observations")
    # the five-point solver may return several essential matrices: the first with most points in front
    poses = [
        cv2.recoverPose(E[3 * k : 3 * k + 3], p1, p2, np.eye(3), mask=mask.copy()) for k in range(len(E) // 3)
    ]
    _, R, u, _ = max(poses, key=lambda pose: pose[0])
    u = u.ravel()
    S = len(frames)
    same = _sampson(R, u, xa[:, 0], xb[:, 0]) + _sampson(R, u, xa[:, 1], xb[:, 1])
    cross = _sampson(R, u, xa[:, 0], xb[:, 1]) + _sampson(R, u, xa[:, 1], xb[:, 0])
    swap = cross < same
    q1 = np.concatenate([xa[:, 0], xa[:, 1], ya])
    q2 = np.concatenate([np.where(swap[:, None], xb[:, 1], xb[:, 0]), np.where(swap[:, None], xb[:, 0], xb[:, 1]), yb])
    keep = _sampson(R, u, q1, q2) < threshold**2
    if keep.sum() >= MIN_PAIR_MATCHES:
        R, u = _refine_relative(R, u, q1[keep], q2[keep])
        keep = _sampson(R, u, q1, q2) < threshold**2
    if keep.sum() < MIN_PAIR_MATCHES:
        return Failure(f"only {int(keep.sum())} of {len(q1)} correspondences fit one relative pose")
    fits = keep[:S] & keep[S : 2 * S]
    return PairPose(a=a, b=b, R=R, u=u, inliers=int(keep.sum()), frames=frames, swap=swap, fits=fits)


def wand_scale(pairs: WandPairs, views: Views, pose: PairPose, length: float) -> float | Failure:
    """The pair's baseline s (metres) from the wand: its shared frames triangulated with a unit
    baseline, s = length / median of their wand lengths."""
    frames = pose.frames[pose.fits]
    if len(frames) < MIN_SCALE_FRAMES:
        return Failure(f"{len(frames)} shared wand frames fit, {MIN_SCALE_FRAMES} needed for the scale")
    xa = pairs.xy[views.wand[frames, pose.a]]
    xb = pairs.xy[views.wand[frames, pose.b]]
    xb = np.where(pose.swap[pose.fits][:, None, None], xb[:, ::-1], xb)
    S = len(frames)
    R = np.stack([np.eye(3), pose.R])
    t = np.stack([np.zeros(3), pose.u])
    point = np.concatenate([np.arange(2 * S), np.arange(2 * S)])
    camera = np.repeat([0, 1], 2 * S)
    xy = np.concatenate([xa.reshape(-1, 2), xb.reshape(-1, 2)])
    X = triangulate_points(R, t, point, camera, xy, 2 * S).reshape(S, 2, 3)
    in_front = (X[..., 2] > 0).all(1) & ((X @ pose.R[2] + pose.u[2]) > 0).all(1)
    lengths = np.linalg.norm(X[:, 0] - X[:, 1], axis=1)[in_front]
    lengths = lengths[np.isfinite(lengths) & (lengths > 0)]
    if len(lengths) < MIN_SCALE_FRAMES:
        return Failure(f"{len(lengths)} shared wand frames triangulate in front of both cameras, {MIN_SCALE_FRAMES} needed")
    return float(length / np.median(lengths))


def points_scale(
    R_a: np.ndarray, t_a: np.ndarray, pose: PairPose, ends: np.ndarray, ends_xy: np.ndarray, X: np.ndarray, xy: np.ndarray,
    focal_px: float,
) -> float | Failure:
    """The pair's baseline s (metres) from points already triangulated by placed cameras.

    Camera b's centre lies on the line ``C_a + s d`` (d the baseline direction in the world); each
    point seen by b along the ray r gives s from ``point - C_a = s d + lambda r`` in least
    squares, and s is their median.

    Args:
        R_a: (3, 3), t_a: (3,) camera a's pose.
        pose: the pair's relative pose.
        ends: (S, 2, 3) triangulated wand ends, metres; ends_xy: (S, 2, 2) camera b's normalised
            blobs of those frames, in either order (the order that fits better is used).
        X: (K, 3) triangulated track points, metres; xy: (K, 2) camera b's observations of them.
        focal_px: camera b's focal length, for the inlier threshold.
    """
    R_b = pose.R @ R_a
    C_a = -R_a.T @ t_a
    d = -R_b.T @ pose.u
    s_same, r_same = _line_scale(C_a, d, R_b, ends.reshape(-1, 3), ends_xy.reshape(-1, 2))
    s_swap, r_swap = _line_scale(C_a, d, R_b, ends.reshape(-1, 3), ends_xy[:, ::-1].reshape(-1, 2))
    swap = r_swap.reshape(-1, 2).sum(1) < r_same.reshape(-1, 2).sum(1)
    s_ends = np.where(swap[:, None], s_swap.reshape(-1, 2), s_same.reshape(-1, 2)).ravel()
    s = np.concatenate([s_ends, _line_scale(C_a, d, R_b, X, xy)[0]])
    s = s[np.isfinite(s) & (s > 0)]
    if len(s) < MIN_SCALE_POINTS:
        return Failure(f"{len(s)} already-triangulated points fix the scale, {MIN_SCALE_POINTS} needed")
    scale = float(np.median(s))
    # that scale must make b reproject the points: count the ones that it does
    t_b = pose.R @ t_a + scale * pose.u
    ends_xy = np.where(swap[:, None, None], ends_xy[:, ::-1], ends_xy)
    pts = np.concatenate([ends.reshape(-1, 3), X])
    obs = np.concatenate([ends_xy.reshape(-1, 2), xy])
    xc = pts @ R_b.T + t_b
    err = np.linalg.norm(xc[:, :2] / xc[:, 2:3] - obs, axis=1)
    good = int((err < 2 * ESSENTIAL_THRESHOLD_PX / focal_px).sum())
    if good < MIN_SCALE_POINTS:
        return Failure(f"only {good} already-triangulated points agree with one scale, {MIN_SCALE_POINTS} needed")
    return scale


def _line_scale(C: np.ndarray, d: np.ndarray, R_b: np.ndarray, X: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M,) s and residual distance (metres) of ``X - C = s d + lambda r`` for rays r of xy in b."""
    r = np.concatenate([xy, np.ones((len(xy), 1))], 1) @ R_b  # R_b.T @ ray, row-wise
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    v = X - C
    dd, dr, rr = d @ d, r @ d, np.ones(len(r))
    vd, vr = v @ d, np.einsum("mi,mi->m", v, r)
    det = dd * rr - dr**2
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (rr * vd - dr * vr) / det
        lam = (dd * vr - dr * vd) / det
    res = np.linalg.norm(v - s[:, None] * d - lam[:, None] * r, axis=1)
    s = np.where(lam > 0, s, np.nan)  # the point must be in front of b
    return s, np.where(np.isfinite(res), res, np.inf)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _sampson(R: np.ndarray, u: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """(M,) squared Sampson distance of x2^T E x1 = 0, E = [u]x R, normalised coordinates (M, 2)."""
    E = _skew(u) @ R
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], 1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], 1)
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    num = np.einsum("mi,mi->m", h2, Ex1) ** 2
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return num / np.maximum(den, 1e-300)


def _refine_relative(R: np.ndarray, u: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the Sampson distances of inlying matches x1, x2 (M, 2) over the five
    degrees of freedom of (R, u): a rotation increment and u moved in its tangent plane. The
    Jacobian is by central differences: five evaluations of a vectorised residual."""
    def residual(p: np.ndarray) -> np.ndarray:
        Rp, up = _perturbed(R, u, p, basis)
        return np.sqrt(_sampson(Rp, up, x1, x2))

    for _ in range(REFINE_STEPS):
        basis = _tangent_basis(u)
        r0 = residual(np.zeros(5))
        h = 1e-7
        J = np.stack([(residual(h * e) - residual(-h * e)) / (2 * h) for e in np.eye(5)], axis=1)
        step, *_ = np.linalg.lstsq(J, -r0, rcond=None)
        R_new, u_new = _perturbed(R, u, step, basis)
        if np.sum(_sampson(R_new, u_new, x1, x2)) >= np.sum(r0**2):
            break
        R, u = R_new, u_new
    return R, u


def _tangent_basis(u: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane perpendicular to u."""
    _, _, vt = np.linalg.svd(u[None, :])
    return vt[1:].T


def _perturbed(R: np.ndarray, u: np.ndarray, p: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dR = cv2.Rodrigues(np.asarray(p[:3], dtype=float).reshape(3, 1))[0]
    v = u + basis @ p[3:]
    return dR @ R, v / np.linalg.norm(v)
