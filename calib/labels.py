"""Tell the wand's two ends apart across cameras.

Blobs carry no labels, so each camera-frame's pair is in arbitrary order. With approximate
poses, one camera per frame is the reference; every other camera's order is chosen by epipolar
consistency with it, then re-checked against the triangulated ends (reprojection), which also
settles the cases where both ends lie near one epipolar line.
"""

from __future__ import annotations

import numpy as np

from calib.observations import WandPairs
from calib.triangulate import triangulate_points

RELABEL_ROUNDS = 2  # a second reprojection pass changes nothing on simulated rigs


def flatten(pairs: WandPairs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observation arrays of labelled pairs: point (2P,) = 2*frame + end, camera (2P,), xy (2P, 2)."""
    point = np.concatenate([2 * pairs.frame, 2 * pairs.frame + 1])
    camera = np.concatenate([pairs.camera, pairs.camera])
    xy = np.concatenate([pairs.xy[:, 0], pairs.xy[:, 1]])
    return point, camera, xy


def wand_lengths(R: np.ndarray, t: np.ndarray, pairs: WandPairs) -> np.ndarray:
    """(F,) length of each frame's wand, each end triangulated on its own from labelled pairs
    (metres; NaN where fewer than two cameras see the frame)."""
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    return np.linalg.norm(X[:, 1] - X[:, 0], axis=1)


def label_ends(
    R: np.ndarray, t: np.ndarray, pairs: WandPairs, known: np.ndarray, length: float | None = None
) -> tuple[WandPairs, np.ndarray]:
    """Order each pair's ends consistently across the cameras whose pose is known.

    Args:
        R: (N, 3, 3), t: (N, 3) approximate poses.
        pairs: camera-frame pairs, any order.
        known: (N,) bool, cameras whose pose may be used; pairs of other cameras are left as they are.
        length: the wand length, metres. In a frame seen by only two cameras both matchings can
            fit the epipolar geometry (a wand near an epipolar plane); the one whose triangulated
            wand is nearer this length is kept.

    Returns:
        (labelled pairs of known cameras, (P_known,) margin in normalised units: how much worse
        the other order fits; small margins are doubtful).
    """
    sub = pairs.subset(known[pairs.camera])
    if len(sub) == 0:
        return sub, np.zeros(0)
    sub = sub.swapped(_epipolar_order(R, t, sub))
    sub = sub.swapped(_pairwise_consensus(R, t, sub))
    margin = np.zeros(len(sub))
    for _ in range(RELABEL_ROUNDS):
        point, camera, xy = flatten(sub)
        X = triangulate_points(R, t, point, camera, xy, 2 * len(sub.frames)).reshape(-1, 2, 3)
        ends = X[sub.frame]  # (P, 2, 3)
        Rc, tc = R[sub.camera], t[sub.camera]
        proj = np.stack([_project(Rc, tc, ends[:, e]) for e in range(2)], axis=1)
        same = np.linalg.norm(proj - sub.xy, axis=2).sum(1)
        other = np.linalg.norm(proj[:, ::-1] - sub.xy, axis=2).sum(1)
        flip = np.isfinite(other) & (other < same)
        margin = np.where(np.isfinite(same), np.abs(other - same), 0.0)
        if not flip.any():
            break
        sub = sub.swapped(flip)
    if length is not None:
        sub = _two_view_by_length(R, t, sub, length)
    return sub, margin


def _two_view_by_length(R: np.ndarray, t: np.ndarray, pairs: WandPairs, length: float) -> WandPairs:
    """In frames seen by exactly two cameras, swap the second camera's ends when that brings the
    triangulated wand nearer ``length``."""
    views = np.bincount(pairs.frame, minlength=len(pairs.frames))
    two = views[pairs.frame] == 2
    if not two.any():
        return pairs
    # the second pair of each two-view frame (pairs are grouped by frame in camera order)
    order = np.lexsort((pairs.camera, pairs.frame))
    second = np.zeros(len(pairs), bool)
    sorted_frames = pairs.frame[order]
    second[order[1:]] = sorted_frames[1:] == sorted_frames[:-1]
    candidate = second & two
    now = wand_lengths(R, t, pairs)
    alt = wand_lengths(R, t, pairs.swapped(candidate))
    better = np.abs(alt - length) < np.abs(now - length)
    return pairs.swapped(candidate & better[pairs.frame])


def _project(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    xc = np.einsum("mij,mj->mi", R, X) + t
    return xc[:, :2] / xc[:, 2:3]


def _epipolar_order(R: np.ndarray, t: np.ndarray, pairs: WandPairs) -> np.ndarray:
    """(P,) bool: swap each pair so it agrees with its frame's reference pair (the one whose
    blobs are furthest apart, which is the least ambiguous)."""
    order = np.lexsort((-np.linalg.norm(pairs.xy[:, 0] - pairs.xy[:, 1], axis=1), pairs.frame))
    frame_sorted = pairs.frame[order]
    first = np.r_[True, frame_sorted[1:] != frame_sorted[:-1]]
    ref_of_sorted = order[np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))]
    ref = np.empty(len(pairs), dtype=np.int64)
    ref[order] = ref_of_sorted
    a, b = ref, np.arange(len(pairs))
    ca, cb = pairs.camera[a], pairs.camera[b]
    R_ab = R[cb] @ np.swapaxes(R[ca], 1, 2)
    t_ab = t[cb] - np.einsum("mij,mj->mi", R_ab, t[ca])
    E = _skew(t_ab) @ R_ab
    xa, xb = pairs.xy[a], pairs.xy[b]
    same = _sampson(E, xa[:, 0], xb[:, 0]) + _sampson(E, xa[:, 1], xb[:, 1])
    swap = _sampson(E, xa[:, 0], xb[:, 1]) + _sampson(E, xa[:, 1], xb[:, 0])
    return (swap < same) & (a != b)


def _pairwise_consensus(R: np.ndarray, t: np.ndarray, pairs: WandPairs, max_passes: int = 8) -> np.ndarray:
    """(P,) bool flips that lower each frame's epipolar cost summed over all its camera pairs.

    The reference-based order trusts one camera per frame; when the wand lies near an epipolar
    plane of that camera, other cameras can split into two camps. Here every pair of cameras in
    a frame votes, and single-camera flips are taken greedily (the best one per frame and pass)
    while they lower the frame's total.
    """
    P = len(pairs)
    order = np.argsort(pairs.frame, kind="stable")
    fr = pairs.frame[order]
    start = np.searchsorted(fr, fr, side="left")
    count = np.bincount(fr, minlength=len(pairs.frames))[fr]
    # all ordered pairs (i, j), i != j, within a frame
    reps = count
    i_idx = np.repeat(order, reps)
    offs = np.arange(len(i_idx)) - np.repeat(np.cumsum(reps) - reps, reps)
    j_idx = order[np.repeat(start, reps) + offs]
    keep = i_idx < j_idx  # each unordered pair once: the Sampson distance is symmetric
    a_idx, b_idx = i_idx[keep], j_idx[keep]
    if len(a_idx) == 0:
        return np.zeros(P, bool)
    E = _essential_matrices(R, t)[pairs.camera[a_idx], pairs.camera[b_idx]]
    xa, xb = pairs.xy[a_idx], pairs.xy[b_idx]
    same = _sampson(E, xa[:, 0], xb[:, 0]) + _sampson(E, xa[:, 1], xb[:, 1])
    cross = _sampson(E, xa[:, 0], xb[:, 1]) + _sampson(E, xa[:, 1], xb[:, 0])
    i_idx, j_idx = np.concatenate([a_idx, b_idx]), np.concatenate([b_idx, a_idx])
    same, cross = np.concatenate([same, same]), np.concatenate([cross, cross])
    flip = np.zeros(P, bool)
    for _ in range(max_passes):
        agree = flip[i_idx] == flip[j_idx]
        now = np.where(agree, same, cross)
        after = np.where(agree, cross, same)  # flipping i changes its agreement with every j
        gain = np.bincount(i_idx, now - after, minlength=P)
        best = np.full(len(pairs.frames), 0.0)
        np.maximum.at(best, pairs.frame, gain)
        take = (gain > 0) & (gain >= best[pairs.frame])
        # one flip per frame and pass: the frame's best single flip
        first = np.zeros(P, bool)
        idx = np.flatnonzero(take)
        _, first_of_frame = np.unique(pairs.frame[idx], return_index=True)
        first[idx[first_of_frame]] = True
        if not first.any():
            break
        flip ^= first
    return flip


def _essential_matrices(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, N, 3, 3): E[a, b] with x_b^T E x_a = 0 for cameras a, b (normalised coordinates)."""
    R_ab = R[None, :] @ np.swapaxes(R, 1, 2)[:, None]  # [a, b] = R_b R_a^T
    t_ab = t[None, :] - np.einsum("abij,aj->abi", R_ab, t)
    return _skew(t_ab.reshape(-1, 3)).reshape(R_ab.shape) @ R_ab


def _skew(v: np.ndarray) -> np.ndarray:
    z = np.zeros(len(v))
    return np.stack(
        [np.stack([z, -v[:, 2], v[:, 1]], 1), np.stack([v[:, 2], z, -v[:, 0]], 1), np.stack([-v[:, 1], v[:, 0], z], 1)],
        axis=1,
    )


def _sampson(E: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Sampson epipolar distance, (M,), for x_b^T E x_a = 0 in normalised coordinates."""
    ha = np.concatenate([xa, np.ones((len(xa), 1))], 1)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], 1)
    Ea = np.einsum("mij,mj->mi", E, ha)
    Etb = np.einsum("mji,mj->mi", E, hb)
    num = np.einsum("mi,mi->m", hb, Ea) ** 2
    den = Ea[:, 0] ** 2 + Ea[:, 1] ** 2 + Etb[:, 0] ** 2 + Etb[:, 1] ** 2
    return num / np.maximum(den, 1e-300)
