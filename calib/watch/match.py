"""Correspondence with a standing calibration: each camera's unlabelled blobs matched to the other
cameras' along epipolar lines, verified in a third camera, triangulated; ambiguous matches rejected.

For a seed pair of cameras (a, b), every blob of a is paired with the blobs of b near its epipolar
line; each pair's two-ray point is projected into every camera and takes the nearest blob there
within :data:`ASSOCIATE_PX`. A candidate is kept with three cameras or more (the pair and a third
that confirms it) and triangulated from all of them; from that point every camera's view is chosen
again within :data:`GATE_PX`. A view is ambiguous, and left out, when a second blob lies within
:data:`CLEAR_RATIO` times the nearest one's distance (two markers' images side by side): the marker
keeps its other cameras. Candidates that found the same views are one; the rest are taken greedily,
most cameras first, then the smallest residual, each keeping the views no stronger one took (a ghost
of two wrong rays keeps fewer than three and is dropped). Seed pairs run in turn over the blobs still
free, so a marker that camera a or b missed is found from another pair. The geometry is vectorised
over a batch of frames; only the greedy choice loops, over the candidates' blob numbers.

The cameras' geometry is a hook (:class:`Pinhole`, the default; a camera behind a flat window into
water, :class:`wandcal.calib.watch.refracted.Refracted`): pairs near the epipolar line (a curve
through a window), the two-ray point, projection, and triangulation from a candidate's views.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.calib.triangulate import refine_points, reprojection_errors
from wandcal.calib.watch.take import FRAME_GAP_PX, PaddedFrames

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

EPIPOLAR_PX = 2.0  # a blob's distance from the epipolar line: 0.3 px noise in two images and a standing
#                    calibration's ~0.1 px, with room for a camera moved a little (a knock is found by health)
ASSOCIATE_PX = 6.0  # a third camera's blob this near the pair's projected point confirms it (the two-ray
#                     point's own error projects to ~1 px; blobs of a 40-marker take lie ~150 px apart)
GATE_PX = 3.0  # after the full triangulation a view this far from its point is dropped (10 sigma at 0.3 px)
MIN_VIEWS = 3  # a pair and one camera that confirms it
CLEAR_RATIO = 2.0  # a camera's nearest blob must be this much nearer than its second to be the marker's view
SEED_ANGLE_DEG = 60.0  # a seed pair's optical axes this far apart: wide enough to triangulate, close enough to share markers


@dataclass(frozen=True)
class Tolerances:
    """The matcher's pixel gates (the constants above by default; a real rig whose calibration or
    detection is coarser than a simulated take's widens them, in proportion)."""

    epipolar_px: float = EPIPOLAR_PX
    associate_px: float = ASSOCIATE_PX
    gate_px: float = GATE_PX


@dataclass
class MatchCounts:
    """What a :func:`match_frames` call weighed and let go, summed over its seed pairs (for reports):
    pairs: blob pairs near an epipolar line; candidates: those a third camera confirmed, distinct,
    after the gate; ambiguous_views: views left out at the gate because a second blob lay within
    :data:`CLEAR_RATIO` of the nearest; dropped: candidates rejected in the greedy choice (stronger
    ones took their blobs and left them fewer than :data:`MIN_VIEWS`)."""

    pairs: int = 0
    candidates: int = 0
    ambiguous_views: int = 0
    dropped: int = 0


@dataclass(frozen=True, eq=False)
class Tracks:
    """Matched markers of a batch of frames.

    frame: (T,) frame number; views: (T, C) the take's blob row each camera contributed, -1 where
    none; X: (T, 3) world points, metres.
    """

    frame: np.ndarray
    views: np.ndarray
    X: np.ndarray

    def __len__(self) -> int:
        return len(self.frame)


class CameraModel(Protocol):
    """What the matcher asks of the cameras' geometry. xy are normalised image coordinates."""

    def epipolar_pairs(self, a: int, b: int, xa: np.ndarray, xb: np.ndarray,
                       tol_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame index, a's slot, b's slot), each (P,): blob pairs of a frame's xa (F, K, 2) in camera a
        and xb (F, K, 2) in b (NaN where none) within tol_px of each other's epipolar line (or curve)."""
        ...

    def two_ray_points(self, a: int, b: int, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
        """(P, 3) the point nearest both rays of xa (P, 2) in camera a and xb (P, 2) in b, metres."""
        ...

    def project(self, X: np.ndarray) -> np.ndarray:
        """(P, C, 2) points X (P, 3) in every camera, NaN where a camera cannot see the point."""
        ...

    def triangulate(self, p: np.ndarray, c: np.ndarray, xy: np.ndarray, X0: np.ndarray) -> np.ndarray:
        """(P, 3) points from views (point p (M,), camera c (M,), xy (M, 2)), started at X0 (P, 3)."""
        ...

    def residuals(self, p: np.ndarray, c: np.ndarray, xy: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(M, 2) each view's projection of its point minus xy, normalised units."""
        ...


class Pinhole:
    """Pinhole cameras at poses R (C, 3, 3), t (C, 3): epipolar lines, two-ray midpoints,
    Gauss-Newton triangulation (the matcher's default :class:`CameraModel`)."""

    def __init__(self, R: np.ndarray, t: np.ndarray, focal: np.ndarray):
        self.R, self.t, self.focal = R, t, focal

    def epipolar_pairs(self, a, b, xa, xb, tol_px):
        R, t = self.R, self.t
        R_ab = R[b] @ R[a].T
        t_ab = t[b] - R_ab @ t[a]
        E = _skew(t_ab) @ R_ab
        ha = np.concatenate([xa, np.ones(xa.shape[:2] + (1,))], axis=-1)
        hb = np.concatenate([xb, np.ones(xb.shape[:2] + (1,))], axis=-1)
        lines = ha @ E.T  # (F, K, 3) each a-blob's epipolar line in b
        with np.errstate(invalid="ignore"):
            dist = np.abs(np.einsum("fkd,fjd->fkj", lines, hb)) / np.linalg.norm(lines[..., :2], axis=-1)[..., None]
        return np.nonzero(dist * self.focal[b] < tol_px)

    def two_ray_points(self, a, b, xa, xb):
        return _two_ray_points(self.R[a], self.t[a], self.R[b], self.t[b], xa, xb)

    def project(self, X):
        Xc = np.einsum("cij,pj->pci", self.R, X) + self.t[None]  # (P, C, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            xy = Xc[..., :2] / Xc[..., 2:3]
        xy[~(Xc[..., 2] > 0)] = np.nan
        return xy

    def triangulate(self, p, c, xy, X0):
        return refine_points(self.R, self.t, p, c, xy, X0)

    def residuals(self, p, c, xy, X):
        return reprojection_errors(self.R, self.t, p, c, xy, X)


def seed_pairs(R: np.ndarray, t: np.ndarray) -> list[tuple[int, int]]:
    """(a, b) pairs, one for each camera a: the camera b whose optical axis is nearest
    :data:`SEED_ANGLE_DEG` from a's, so every camera seeds once."""
    axes = R[:, 2, :]
    angle = np.degrees(np.arccos(np.clip(axes @ axes.T, -1, 1)))
    np.fill_diagonal(angle, np.inf)
    return [(a, int(np.argmin(np.abs(angle[a] - SEED_ANGLE_DEG)))) for a in range(len(R))]


def match_frames(rig: Rig, R: np.ndarray, t: np.ndarray, padded: PaddedFrames, *,
                 model: CameraModel | None = None, tolerances: Tolerances | None = None,
                 counts: MatchCounts | None = None) -> Tracks:
    """Match and triangulate a batch of frames' blobs (R (C, 3, 3), t (C, 3) the standing poses;
    ``model`` the cameras' geometry, pinhole at R, t by default; ``tolerances`` the matcher's
    pixel gates, :class:`Tolerances` () by default; ``counts``, if given, is added to)."""
    focal = np.array([c.focal.mean() for c in rig.cameras])
    model = Pinhole(R, t, focal) if model is None else model
    tol = Tolerances() if tolerances is None else tolerances
    free = np.isfinite(padded.xy[..., 0])  # (F, C, K) blobs not yet in a track
    found: list[Tracks] = []
    for a, b in seed_pairs(R, t):
        cand = _candidates(model, tol, focal, padded, free, a, b, counts)
        if cand is None:
            continue
        taken = _resolve(model, focal, padded, *cand, counts=counts)
        if taken is None:
            continue
        f_idx, slots, X = taken
        used_c = np.nonzero(slots >= 0)
        free[f_idx[used_c[0]], used_c[1], slots[used_c]] = False
        rows = np.where(slots >= 0, padded.row[f_idx[:, None], np.arange(len(R))[None, :], np.maximum(slots, 0)], -1)
        found.append(Tracks(padded.frames[f_idx], rows, X))
    if not found:
        return Tracks(np.zeros(0, np.int64), np.zeros((0, len(R)), np.int64), np.zeros((0, 3)))
    return Tracks(np.concatenate([f.frame for f in found]), np.concatenate([f.views for f in found]),
                  np.concatenate([f.X for f in found]))


def _candidates(model: CameraModel, tol: Tolerances, focal, padded: PaddedFrames, free, a: int, b: int,
                counts: MatchCounts | None = None):
    """Pairs of free blobs of cameras a and b near each other's epipolar line, confirmed by a third
    camera: (frame index (P,), each camera's slot (P, C) or -1, points (P, 3), residual rms px (P,))."""
    # the points start at the two-ray midpoint and are refined by Gauss-Newton (no DLT: its 4x4
    # eigen-decompositions were half the matcher's time)
    xa = np.where(free[:, a, :, None], padded.xy[:, a], np.nan)  # (F, K, 2)
    xb = np.where(free[:, b, :, None], padded.xy[:, b], np.nan)
    f_idx, i, j = model.epipolar_pairs(a, b, xa, xb, tol.epipolar_px)
    if counts is not None:
        counts.pairs += len(f_idx)
    if not len(f_idx):
        return None
    X = model.two_ray_points(a, b, xa[f_idx, i], xb[f_idx, j])
    trees = _free_trees(focal, padded, free)  # both passes below look among the same free blobs
    slots = _associate(model, focal, trees, f_idx, X, tol.associate_px)
    slots[:, a], slots[:, b] = i, j
    keep = (slots >= 0).sum(1) >= MIN_VIEWS
    if not keep.any():
        return None
    f_idx, slots = f_idx[keep], slots[keep]
    X, _ = _triangulate(model, focal, padded, f_idx, slots, X[keep])
    # again from the point of every view: each camera's nearest free blob within the gate, unless
    # a second blob is nearly as near (that view is ambiguous and left out, not the marker)
    slots = _associate(model, focal, trees, f_idx, X, tol.gate_px, counts)
    keep = (slots >= 0).sum(1) >= MIN_VIEWS
    f_idx, slots = f_idx[keep], slots[keep]
    if not len(f_idx):
        return None
    key = np.concatenate([f_idx[:, None], slots], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)  # candidates that found the same views are one
    f_idx, slots, X = f_idx[first], slots[first], X[keep][first]
    X, rms = _triangulate(model, focal, padded, f_idx, slots, X)
    if counts is not None:
        counts.candidates += len(f_idx)
    return f_idx, slots, X, rms


def _free_trees(focal, padded: PaddedFrames, free) -> list[tuple[np.ndarray, cKDTree] | None]:
    """Per camera, (its free blobs' slots (B,), a k-d tree of them in pixels, frames kept apart by
    :data:`FRAME_GAP_PX`), None where it has none: what :func:`_associate` looks among."""
    from scipy.spatial import cKDTree

    trees: list[tuple[np.ndarray, cKDTree] | None] = []
    for c in range(free.shape[1]):
        fi, k = np.nonzero(free[:, c])
        trees.append((k, cKDTree(np.column_stack([padded.xy[fi, c, k] * focal[c], fi * FRAME_GAP_PX])))
                     if len(fi) else None)
    return trees


def _associate(model: CameraModel, focal, trees: list[tuple[np.ndarray, cKDTree] | None], f_idx, X, radius: float,
               counts: MatchCounts | None = None) -> np.ndarray:
    """(P, C) each camera's free blob nearest the point's projection within ``radius`` px and
    :data:`CLEAR_RATIO` times nearer than any other, -1 if none (``trees``: :func:`_free_trees`)."""
    xy = model.project(X)  # (P, C, 2)
    out = np.full(xy.shape[:2], -1)
    for c in range(xy.shape[1]):
        ahead, free_c = np.isfinite(xy[:, c, 0]), trees[c]
        if free_c is None or not ahead.any():
            continue
        k, tree = free_c
        q = np.flatnonzero(ahead)
        proj = xy[q, c] * focal[c]
        d, j = tree.query(np.column_stack([proj, f_idx[q] * FRAME_GAP_PX]), k=2,
                          distance_upper_bound=CLEAR_RATIO * radius)
        near = (d[:, 0] < radius) & (d[:, 1] >= CLEAR_RATIO * d[:, 0])
        out[q[near], c] = k[j[near, 0]]
        if counts is not None:
            counts.ambiguous_views += int(((d[:, 0] < radius) & ~near).sum())
    return out


def _triangulate(model: CameraModel, focal, padded: PaddedFrames, f_idx, slots, X0) -> tuple[np.ndarray, np.ndarray]:
    """Each candidate triangulated from all its views by Gauss-Newton from X0 (P, 3), a close start:
    points (P, 3), rms residual px (P,)."""
    p, c = np.nonzero(slots >= 0)
    xy = padded.xy[f_idx[p], c, slots[p, c]]
    X = model.triangulate(p, c, xy, X0)
    res = model.residuals(p, c, xy, X) * focal[c][:, None]
    sq = np.bincount(p, (res ** 2).sum(1), minlength=len(slots))
    n = np.bincount(p, minlength=len(slots))
    return X, np.sqrt(sq / np.maximum(n, 1))


def _resolve(model: CameraModel, focal, padded: PaddedFrames, f_idx, slots, X, rms, *,
             counts: MatchCounts | None = None):
    """Candidates taken greedily, most cameras first, then the smaller residual: each keeps the
    views no stronger candidate took, and is taken while it keeps :data:`MIN_VIEWS`; the taken ones
    are triangulated again from the views they kept. Returns (frame index, slots, points) or None."""
    n_cam, width = slots.shape[1], padded.xy.shape[2]
    views = (slots >= 0).sum(1)
    order = np.lexsort((rms, -views))
    blob = np.where(slots >= 0, (f_idx[:, None] * n_cam + np.arange(n_cam)) * width + slots, -1)
    used: set[int] = set()
    taken: list[int] = []
    kept = np.full_like(slots, -1)
    for k, row in zip(order.tolist(), blob[order].tolist()):
        mine = [(c, b) for c, b in enumerate(row) if b >= 0 and b not in used]
        if len(mine) < MIN_VIEWS:
            continue
        taken.append(k)
        for c, b in mine:
            used.add(b)
            kept[k, c] = slots[k, c]
    if counts is not None:
        counts.dropped += len(order) - len(taken)
    if not taken:
        return None
    f_idx, slots = f_idx[taken], kept[taken]
    X, _ = _triangulate(model, focal, padded, f_idx, slots, X[taken])
    return f_idx, slots, X


def _two_ray_points(Ra, ta, Rb, tb, xa, xb) -> np.ndarray:
    """(P, 3) midpoints of the closest approach of the rays through xa (P, 2) in camera a and xb in b."""
    Ca, Cb = -Ra.T @ ta, -Rb.T @ tb
    da = np.concatenate([xa, np.ones((len(xa), 1))], 1) @ Ra  # R^T x, rows
    db = np.concatenate([xb, np.ones((len(xb), 1))], 1) @ Rb
    w = Ca - Cb
    aa, bb, ab = (da * da).sum(1), (db * db).sum(1), (da * db).sum(1)
    wa, wb = da @ w, db @ w
    den = np.where(np.abs(aa * bb - ab * ab) > 1e-12, aa * bb - ab * ab, 1e-12)
    sa = (ab * wb - bb * wa) / den
    sb = (aa * wb - ab * wa) / den
    return (Ca + sa[:, None] * da + Cb + sb[:, None] * db) / 2


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
