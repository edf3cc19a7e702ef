"""One pair of cameras' wand frames at one lag, for the whole-frame search
(:mod:`wandcal.calib.start.offsets.whole_frames`): the frames they share, the essential matrix
RANSAC fits to both matchings of their unlabelled ends and the share of frames it fits, and the
midpoint scores of every lag at once. Lags: camera a's frame k against camera b's k + lag."""

from __future__ import annotations

import cv2
import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.start.chain import ESSENTIAL_CONFIDENCE, ESSENTIAL_THRESHOLD_PX, _sampson, spread

TIMING_FRAMES = 60  # shared frames per shift given to RANSAC (240 candidate matches): enough to tell, 2 ms a shift
MIN_TIMING_FRAMES = 8  # shared frames a shift needs to be judged: five fix the essential matrix, three confirm
# a frame fits when both its ends lie this close to their epipolar lines: looser than RANSAC's 2 px,
# since a camera still off by half a frame moves a 3 m/s wand ~5 px from them
SHARE_THRESHOLD_PX = 6.0
MIDPOINT_FRAMES = 100  # a partner's frames per shift for the midpoint score: a 9x9 eigenproblem each
TRIM_PASSES = 3  # linear fits of the midpoint score, each on the best TRIM_KEEP of the last one's frames
TRIM_KEEP = 0.8  # drops digitising slips and reflections (a few %) with room to spare


def frame_table(pairs: WandPairs, n: int) -> np.ndarray:
    """(span, N) each frame's pair row for each camera, -1 where it saw no wand; frames from the first."""
    first = int(pairs.frames.min()) if len(pairs.frames) else 0
    span = int(pairs.frames.max()) - first + 1 if len(pairs.frames) else 0
    table = np.full((span, n), -1, np.int64)
    table[pairs.frames[pairs.frame] - first, pairs.camera] = np.arange(len(pairs))
    return table


def shared_counts(table: np.ndarray, a: int, b: int, lags: np.ndarray) -> np.ndarray:
    """(S,) how many frames k a saw the wand in with b at k + lag, for each lag (S,): every lag at
    once, a's frames looked up in b's column."""
    span = len(table)
    k = np.flatnonzero(table[:, a] >= 0)
    kb = k[None, :] + np.asarray(lags, np.int64).reshape(-1, 1)  # (S, K)
    hit = (kb >= 0) & (kb < span) & (table[np.clip(kb, 0, max(span - 1, 0)), b] >= 0)
    return np.count_nonzero(hit, axis=1).astype(np.int64)


def shared_rows(table: np.ndarray, a: int, b: int, lag: int, most: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the pairs of a's frame k and b's frame k + lag where both saw both ends, at most
    ``most`` of them spread over the recording."""
    span = len(table)
    k = np.flatnonzero(table[:, a] >= 0)
    kb = k + lag
    ok = (kb >= 0) & (kb < span)
    k, kb = k[ok], kb[ok]
    k, kb = k[table[kb, b] >= 0], kb[table[kb, b] >= 0]
    pick = spread(np.arange(len(k)), most)
    return table[k[pick], a], table[kb[pick], b]


def midpoint_scores(pairs: WandPairs, table: np.ndarray, a: int, b: int, lags: np.ndarray) -> np.ndarray:
    """(S,) for each lag, the median Sampson distance (normalised units) of the wand midpoints of
    a's frame k and b's frame k + lag to a linear fundamental matrix fitted through them (refitted
    twice on the best 80%); NaN where fewer than ``MIN_TIMING_FRAMES`` frames are shared. All lags
    at once: a's frames (at most ``MIDPOINT_FRAMES``, spread) against b's at every lag."""
    span = len(table)
    k = spread(np.flatnonzero(table[:, a] >= 0), MIDPOINT_FRAMES)
    kb = k[None, :] + lags[:, None]  # (S, K)
    rows_b = np.where((kb >= 0) & (kb < span), table[np.clip(kb, 0, span - 1), b], -1)
    valid = rows_b >= 0
    h1 = np.concatenate([pairs.xy[table[k, a]].mean(1), np.ones((len(k), 1))], 1)  # (K, 3)
    h2 = np.concatenate([pairs.xy[np.maximum(rows_b, 0)].mean(2), np.ones((*rows_b.shape, 1))], 2)  # (S, K, 3)
    rows = (h2[:, :, :, None] * h1[None, :, None, :]).reshape(*rows_b.shape, 9)
    keep = valid.copy()
    dist = np.zeros(rows_b.shape)
    for _ in range(TRIM_PASSES):
        w = rows * keep[..., None]
        _, vecs = np.linalg.eigh(np.matmul(w.transpose(0, 2, 1), rows))
        F = vecs[:, :, 0].reshape(-1, 3, 3)
        Fx = np.matmul(h1, F.transpose(0, 2, 1))  # (S, K, 3): F x1 for each frame
        Fty = np.matmul(h2, F)
        num = np.einsum("ski,ski->sk", h2, Fx) ** 2
        den = np.maximum(Fx[..., 0] ** 2 + Fx[..., 1] ** 2 + Fty[..., 0] ** 2 + Fty[..., 1] ** 2, 1e-300)
        dist = np.where(valid, np.sqrt(num / den), np.inf)
        keep = valid & (dist <= _row_quantile(dist, valid, TRIM_KEEP)[:, None])
    score = _row_quantile(dist, valid, 0.5)
    return np.where(valid.sum(1) >= MIN_TIMING_FRAMES, score, np.nan)


def _row_quantile(values: np.ndarray, valid: np.ndarray, q: float) -> np.ndarray:
    """(S,) each row's q-quantile (nearest rank) of ``values`` (S, K) where ``valid``; inf for an empty row."""
    ordered = np.sort(np.where(valid, values, np.inf), axis=1)
    count = valid.sum(1)
    return ordered[np.arange(len(values)), np.clip(np.floor(q * (count - 1)).astype(np.int64), 0, values.shape[1] - 1)]


def pose_share(pairs: WandPairs, table: np.ndarray, a: int, b: int, lag: int, rig: Rig):
    """(R, u) of the essential matrix that RANSAC fits to both matchings of the shared frames'
    ends at this lag, or None."""
    ra, rb = shared_rows(table, a, b, lag, TIMING_FRAMES)
    if len(ra) < MIN_TIMING_FRAMES:
        return None
    xa, xb = pairs.xy[ra], pairs.xy[rb]
    p1 = np.concatenate([xa[:, 0], xa[:, 1], xa[:, 0], xa[:, 1]])
    p2 = np.concatenate([xb[:, 0], xb[:, 1], xb[:, 1], xb[:, 0]])
    threshold = ESSENTIAL_THRESHOLD_PX / _focal(rig, a, b)
    E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), cv2.USAC_DEFAULT, ESSENTIAL_CONFIDENCE, threshold)
    if E is None or E.shape[1:] != (3,) or len(E) < 3:
        return None
    best: tuple | None = None
    for j in range(len(E) // 3):
        n_front, R, u, _ = cv2.recoverPose(E[3 * j : 3 * j + 3], p1, p2, np.eye(3), mask=mask.copy())
        if best is None or n_front > best[0]:
            best = (n_front, R, u.ravel())
    return (best[1], best[2]) if best is not None else None


def fit_share(
    pairs: WandPairs, table: np.ndarray, a: int, b: int, lag: int, rig: Rig, R: np.ndarray, u: np.ndarray
) -> tuple[float, float]:
    """Share of the shared frames at this lag whose both ends fit the relative pose (R, u), and
    the median of their worse end's squared Sampson distance (normalised units)."""
    ra, rb = shared_rows(table, a, b, lag, TIMING_FRAMES)
    if len(ra) < MIN_TIMING_FRAMES:
        return 0.0, float("inf")
    xa, xb = pairs.xy[ra], pairs.xy[rb]
    threshold = SHARE_THRESHOLD_PX / _focal(rig, a, b)
    same = np.maximum(_sampson(R, u, xa[:, 0], xb[:, 0]), _sampson(R, u, xa[:, 1], xb[:, 1]))
    cross = np.maximum(_sampson(R, u, xa[:, 0], xb[:, 1]), _sampson(R, u, xa[:, 1], xb[:, 0]))
    worse = np.minimum(same, cross)
    return float(np.mean(worse < threshold**2)), float(np.median(worse))


def _focal(rig: Rig, a: int, b: int) -> float:
    return float(0.5 * (rig.cameras[a].focal.mean() + rig.cameras[b].focal.mean()))


def lag_share(pairs: WandPairs, table: np.ndarray, a: int, b: int, lag: int, rig: Rig) -> float:
    """The share of a's frames k and b's k + lag whose ends fit the pose RANSAC fits to them (0 with
    too few frames or no pose)."""
    found = pose_share(pairs, table, a, b, lag, rig)
    return fit_share(pairs, table, a, b, lag, rig, *found)[0] if found else 0.0
