"""A moved camera's blobs found again: the correspondence of its blobs with the markers the cameras
that did not move triangulate, by a wide search, for a camera turned too far for the 12 px the
health test looks in (:data:`wandcal.calib.watch.health.HEALTH_PX`; 1 deg at f = 1700 px is 30 px).

A knock turns a camera about its centre far more than it moves it (a turn of 1 deg moves the images
of markers 2 m away as far as a move of 35 mm). Every blob of the camera within :data:`SEARCH_DEG` of
a marker's projection at the standing pose, in the same frame, is a candidate view of it. A turn
Q (world -> camera rays ``b ~ Q a``, a the marker's ray at the standing pose) is fitted to two
candidates at a time (Kabsch) and scored by the candidates it brings within :data:`GATE_PX`
(RANSAC, :data:`TRIES` draws from a fixed seed: the same take gives the same turn). The best turn's
views, each marker's nearest blob within the gate and clearly the nearest, are the re-solve's data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.watch.match import CLEAR_RATIO

SEARCH_DEG = 3.0  # candidates this far from the standing projection: three times the knocks of issue 31
GATE_PX = 4.0  # a view within this of the turned projection: the real sessions' model error (~1 px) and 2 mm of move
TRIES = 300  # RANSAC draws of two candidates; a fifth of candidates right finds the turn with p > 1 - 1e-5
SEED = 36  # the draws' seed (issue 36): the search is deterministic


@dataclass(frozen=True, eq=False)
class Views:
    """The camera's blobs found for markers. point: (k,) index of the marker (into the X given);
    xy: (k, 2) its blob, normalised; turn: (3, 3) the fitted turn (camera frame) from the standing pose;
    candidates: how many (marker, blob) pairs the search weighed."""

    point: np.ndarray
    xy: np.ndarray
    turn: np.ndarray
    candidates: int

    def __len__(self) -> int:
        return len(self.point)


def rays(xy: np.ndarray) -> np.ndarray:
    """(k, 3) unit rays of normalised image points xy (k, 2)."""
    v = np.column_stack([xy, np.ones(len(xy))])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def candidate_pairs(proj: np.ndarray, blob_xy: np.ndarray, point_frame: np.ndarray, blob_frame: np.ndarray,
                    radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(point index (n,), blob index (n,)) of every blob within ``radius`` (normalised units) of a
    marker's projection ``proj`` (P, 2) in the same frame (``point_frame`` (P,), ``blob_frame`` (B,))."""
    from scipy.spatial import cKDTree

    if not len(proj) or not len(blob_xy):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # frames side by side in one tree, far apart: a pair is of one frame
    gap = 1e3 * (radius + float(np.abs(blob_xy).max()) + float(np.abs(proj).max()))
    tree = cKDTree(np.column_stack([blob_xy, blob_frame * gap]))
    found = tree.query_ball_point(np.column_stack([proj, point_frame * gap]), radius)
    counts = np.array([len(f) for f in found])
    return np.repeat(np.arange(len(proj)), counts), np.concatenate([np.asarray(f, np.int64) for f in found] + [
        np.zeros(0, np.int64)])


def kabsch_turns(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3, 3) the rotations Q that best take rays a (n, m, 3) onto b (n, m, 3), ``b ~ Q a``."""
    M = np.einsum("nki,nkj->nij", b, a)
    U, _, Vt = np.linalg.svd(M)
    D = np.ones((len(M), 3))
    D[:, 2] = np.sign(np.linalg.det(U @ Vt))
    return (U * D[:, None, :]) @ Vt


def _projected(Q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(..., k, 2) normalised projections of rays a (k, 3) turned by Q (..., 3, 3)."""
    v = (Q.reshape(-1, 3) @ a.T).reshape(*Q.shape[:-2], 3, len(a))  # one matrix product for every turn
    z = np.where(v[..., 2, :] > 1e-9, v[..., 2, :], np.nan)
    return np.stack([v[..., 0, :] / z, v[..., 1, :] / z], axis=-1)


def best_turn(a: np.ndarray, b: np.ndarray, point: np.ndarray, gate: float) -> tuple[np.ndarray, int]:
    """(Q (3, 3), candidates it explains) of candidate rays a (n, 3) at the standing pose and b (n, 3)
    of the blobs, ``point`` (n,) their markers; ``gate`` normalised units. The identity competes."""
    rng = np.random.default_rng(SEED)
    i = rng.integers(0, len(a), TRIES)
    j = rng.integers(0, len(a), TRIES)
    ok = point[i] != point[j]
    turns = np.concatenate([np.eye(3)[None], kabsch_turns(np.stack([a[i[ok]], a[j[ok]]], 1),
                                                          np.stack([b[i[ok]], b[j[ok]]], 1))])
    bxy = b[:, :2] / b[:, 2:]
    best, score = np.eye(3), -1
    for chunk in np.array_split(np.arange(len(turns)), max(1, len(turns) * len(a) // 2_000_000)):
        e = _projected(turns[chunk], a) - bxy
        counts = (np.einsum("tkc,tkc->tk", e, e) < gate**2).sum(1)  # within the gate, no square root
        k = int(np.argmax(counts))
        if counts[k] > score:
            best, score = turns[chunk][k], int(counts[k])
    return best, score


def nearest_views(proj: np.ndarray, blob_xy: np.ndarray, point: np.ndarray, blob: np.ndarray,
                  gate: float) -> tuple[np.ndarray, np.ndarray]:
    """(markers (k,), their blobs (k,)): of the candidate pairs (``point``, ``blob``), each marker's
    nearest blob to its projection ``proj`` (P, 2) within ``gate``, when clearly the nearest
    (:data:`wandcal.calib.watch.match.CLEAR_RATIO`), and each blob taken by one marker only."""
    d = np.linalg.norm(blob_xy[blob] - proj[point], axis=1)
    order = np.lexsort((d, point))
    p, bl, d = point[order], blob[order], d[order]
    first = np.r_[True, p[1:] != p[:-1]]
    second = np.r_[first[1:], True]  # the next row is another marker's: no second candidate
    d2 = np.where(second, np.inf, np.r_[d[1:], np.inf])
    keep = first & (d < gate) & (d2 >= CLEAR_RATIO * d)
    p, bl = p[keep], bl[keep]
    taken = np.bincount(bl, minlength=len(blob_xy))
    once = taken[bl] == 1
    return p[once], bl[once]


def search_views(a_all: np.ndarray, frame: np.ndarray, blob_xy: np.ndarray, blob_frame: np.ndarray,
                 focal: float) -> Views:
    """The camera's views of markers whose rays at the standing pose are ``a_all`` (P, 3) (camera
    frame, unit), in frames ``frame`` (P,), among its blobs ``blob_xy`` (B, 2) normalised, in
    ``blob_frame`` (B,); ``focal`` pixels. Empty when no candidate is within :data:`SEARCH_DEG`."""
    proj = a_all[:, :2] / a_all[:, 2:]
    point, blob = candidate_pairs(proj, blob_xy, frame, blob_frame, np.tan(np.radians(SEARCH_DEG)))
    gate = GATE_PX / focal
    if not len(point):
        return Views(point, np.zeros((0, 2)), np.eye(3), 0)
    Q, _ = best_turn(a_all[point], rays(blob_xy[blob]), point, gate)
    p, bl = nearest_views(_projected(Q, a_all), blob_xy, point, blob, gate)
    return Views(p, blob_xy[bl], Q, len(point))
