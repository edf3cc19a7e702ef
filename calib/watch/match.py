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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.calib.triangulate import refine_points, reprojection_errors
from wandcal.calib.watch.take import PaddedFrames

EPIPOLAR_PX = 2.0  # a blob's distance from the epipolar line: 0.3 px noise in two images and a standing
#                    calibration's ~0.1 px, with room for a camera moved a little (a knock is found by health)
ASSOCIATE_PX = 6.0  # a third camera's blob this near the pair's projected point confirms it (the two-ray
#                     point's own error projects to ~1 px; blobs of a 40-marker take lie ~150 px apart)
GATE_PX = 3.0  # after the full triangulation a view this far from its point is dropped (10 sigma at 0.3 px)
FRAME_GAP_PX = 1e7  # frames side by side in one k-d tree, this far apart: past any image's size
MIN_VIEWS = 3  # a pair and one camera that confirms it
CLEAR_RATIO = 2.0  # a camera's nearest blob must be this much nearer than its second to be the marker's view
SEED_ANGLE_DEG = 60.0  # a seed pair's optical axes this far apart: wide enough to triangulate, close enough to share markers


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


def seed_pairs(R: np.ndarray, t: np.ndarray) -> list[tuple[int, int]]:
    """(a, b) pairs, one for each camera a: the camera b whose optical axis is nearest
    :data:`SEED_ANGLE_DEG` from a's, so every camera seeds once."""
    axes = R[:, 2, :]
    angle = np.degrees(np.arccos(np.clip(axes @ axes.T, -1, 1)))
    np.fill_diagonal(angle, np.inf)
    return [(a, int(np.argmin(np.abs(angle[a] - SEED_ANGLE_DEG)))) for a in range(len(R))]


def match_frames(rig: Rig, R: np.ndarray, t: np.ndarray, padded: PaddedFrames) -> Tracks:
    """Match and triangulate a batch of frames' blobs (R (C, 3, 3), t (C, 3) the standing poses)."""
    focal = np.array([c.focal.mean() for c in rig.cameras])
    free = np.isfinite(padded.xy[..., 0])  # (F, C, K) blobs not yet in a track
    found: list[Tracks] = []
    for a, b in seed_pairs(R, t):
        cand = _candidates(R, t, focal, padded, free, a, b)
        if cand is None:
            continue
        taken = _resolve(R, t, focal, padded, *cand)
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


def _candidates(R, t, focal, padded: PaddedFrames, free, a: int, b: int):
    """Pairs of free blobs of cameras a and b near each other's epipolar line, confirmed by a third
    camera: (frame index (P,), each camera's slot (P, C) or -1, points (P, 3), residual rms px (P,))."""
    # the points start at the two-ray midpoint and are refined by Gauss-Newton (no DLT: its 4x4
    # eigen-decompositions were half the matcher's time)
    xa = np.where(free[:, a, :, None], padded.xy[:, a], np.nan)  # (F, K, 2)
    xb = np.where(free[:, b, :, None], padded.xy[:, b], np.nan)
    R_ab = R[b] @ R[a].T
    t_ab = t[b] - R_ab @ t[a]
    E = _skew(t_ab) @ R_ab
    ha = np.concatenate([xa, np.ones(xa.shape[:2] + (1,))], axis=-1)
    hb = np.concatenate([xb, np.ones(xb.shape[:2] + (1,))], axis=-1)
    lines = ha @ E.T  # (F, K, 3) each a-blob's epipolar line in b
    with np.errstate(invalid="ignore"):
        dist = np.abs(np.einsum("fkd,fjd->fkj", lines, hb)) / np.linalg.norm(lines[..., :2], axis=-1)[..., None]
    f_idx, i, j = np.nonzero(dist * focal[b] < EPIPOLAR_PX)
    if not len(f_idx):
        return None
    X = _two_ray_points(R[a], t[a], R[b], t[b], xa[f_idx, i], xb[f_idx, j])
    slots = _associate(R, t, focal, padded, free, f_idx, X, ASSOCIATE_PX)
    slots[:, a], slots[:, b] = i, j
    keep = (slots >= 0).sum(1) >= MIN_VIEWS
    if not keep.any():
        return None
    f_idx, slots = f_idx[keep], slots[keep]
    X, _ = _triangulate(R, t, focal, padded, f_idx, slots, X[keep])
    # again from the point of every view: each camera's nearest free blob within the gate, unless
    # a second blob is nearly as near (that view is ambiguous and left out, not the marker)
    slots = _associate(R, t, focal, padded, free, f_idx, X, GATE_PX)
    keep = (slots >= 0).sum(1) >= MIN_VIEWS
    f_idx, slots = f_idx[keep], slots[keep]
    if not len(f_idx):
        return None
    key = np.concatenate([f_idx[:, None], slots], axis=1)
    _, first = np.unique(key, axis=0, return_index=True)  # candidates that found the same views are one
    f_idx, slots, X = f_idx[first], slots[first], X[keep][first]
    X, rms = _triangulate(R, t, focal, padded, f_idx, slots, X)
    return f_idx, slots, X, rms


def _associate(R, t, focal, padded: PaddedFrames, free, f_idx, X, radius: float) -> np.ndarray:
    """(P, C) each camera's free blob nearest the point's projection within ``radius`` px and
    :data:`CLEAR_RATIO` times nearer than any other, -1 if none (a k-d tree a camera, frames kept
    apart by :data:`FRAME_GAP_PX`)."""
    from scipy.spatial import cKDTree

    Xc = np.einsum("cij,pj->pci", R, X) + t[None]  # (P, C, 3)
    out = np.full((len(X), len(R)), -1)
    for c in range(len(R)):
        fi, k = np.nonzero(free[:, c])
        ahead = Xc[:, c, 2] > 0
        if not len(fi) or not ahead.any():
            continue
        tree = cKDTree(np.column_stack([padded.xy[fi, c, k] * focal[c], fi * FRAME_GAP_PX]))
        q = np.flatnonzero(ahead)
        proj = Xc[q, c, :2] / Xc[q, c, 2:3] * focal[c]
        d, j = tree.query(np.column_stack([proj, f_idx[q] * FRAME_GAP_PX]), k=2,
                          distance_upper_bound=CLEAR_RATIO * radius)
        near = (d[:, 0] < radius) & (d[:, 1] >= CLEAR_RATIO * d[:, 0])
        out[q[near], c] = k[j[near, 0]]
    return out


def _triangulate(R, t, focal, padded: PaddedFrames, f_idx, slots, X0) -> tuple[np.ndarray, np.ndarray]:
    """Each candidate triangulated from all its views by Gauss-Newton from X0 (P, 3), a close start:
    points (P, 3), rms residual px (P,)."""
    p, c = np.nonzero(slots >= 0)
    xy = padded.xy[f_idx[p], c, slots[p, c]]
    X = refine_points(R, t, p, c, xy, X0)
    res = reprojection_errors(R, t, p, c, xy, X) * focal[c][:, None]
    sq = np.bincount(p, (res ** 2).sum(1), minlength=len(slots))
    n = np.bincount(p, minlength=len(slots))
    return X, np.sqrt(sq / np.maximum(n, 1))


def _resolve(R, t, focal, padded: PaddedFrames, f_idx, slots, X, rms):
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
    if not taken:
        return None
    f_idx, slots = f_idx[taken], kept[taken]
    X, _ = _triangulate(R, t, focal, padded, f_idx, slots, X[taken])
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
