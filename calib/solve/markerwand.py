"""A multi-marker wand's interior markers in the wand model: the known geometry inside ``ba``.

The two-marker problem (wandcal.calib.run.refine.build_problem on the end markers) is extended with
one observation per interior blob, placed on the frame's wand at its marker's position along the
axis (``WandProblem.along``) and, for a planar wand, across it in the wand's plane
(``WandProblem.across``), so every marker's known position constrains the frame's pose, and
through it the cameras, as the wand length does for the ends. A planar wand's frames carry their
roll about the axis: ``ba`` refines them with :class:`PlanarWandTerm`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.solve.backend import schur
from wandcal.calib.solve.reprojection import BundleState, Rows, _linearised_projection, _Term, camera_index, exp_so3
from wandcal.calib.solve.wandmodel import PLANAR_FRAME_PARAMS, WandModel, WandProblem


class PlanarWandTerm(_Term):
    """``ba``'s observations of a planar wand's markers: camera (M,), frame (M,), xy (M, 2)
    normalised, focal (M, 2), along and across (M,) metres (each marker's place in the wand's
    plane). Per frame the midpoint moves by ``dm`` and the axes by a left increment,
    ``Q <- exp([w]) Q``, so marker k at ``m + Q (o, q, 0)`` moves by ``dm - [Q (o, q, 0)]x w``."""

    size = PLANAR_FRAME_PARAMS

    def __init__(self, camera, frame, xy, focal, along, across, n_frames, free, n_cams, raw=None):
        self.camera, self.frame, self.xy, self.focal, self.raw = camera, frame, xy, focal, raw
        self.body = np.stack([along, across, np.zeros_like(along)], axis=1)  # (M, 3) in the wand's axes
        self.structure = schur.TermStructure(camera_index(free, camera, n_cams), camera, frame, len(free), n_frames,
                                             PLANAR_FRAME_PARAMS)

    def _offsets(self, s: BundleState, sl: Rows) -> np.ndarray:
        assert s.Q is not None, "a planar wand's state carries its frames' axes"
        return np.einsum("mij,mj->mi", s.Q[self.frame[sl]], self.body[sl])

    def _residuals(self, s: BundleState, sl: Rows) -> np.ndarray:
        return self._project(s, s.m[self.frame[sl]] + self._offsets(s, sl), sl)

    def _linearise(self, s: BundleState, sl: Rows):
        camera = self.camera[sl]
        Rc = s.R[camera]
        v = self._offsets(s, sl)
        Y = np.einsum("mij,mj->mi", Rc, s.m[self.frame[sl]] + v)
        raw = None if self.raw is None else (self.raw[0][sl], self.raw[1])
        r, J = _linearised_projection(Y, s, camera, Rc, self.xy[sl], self.focal[sl], raw, PLANAR_FRAME_PARAMS)
        c = J.shape[2] - PLANAR_FRAME_PARAMS
        # d(pixel)/dw = d(pixel)/dX @ -[v]x, i.e. row k of it is v x (row k of d(pixel)/dX)
        J[:, :, c + 3 : c + 6] = np.cross(v[:, None, :], J[:, :, c : c + 3])
        return r, J

    def moved(self, s: BundleState, dp: np.ndarray) -> BundleState:
        Q = exp_so3(dp[:, 3:]) @ s.Q
        return replace(s, m=s.m + dp[:, :3], Q=Q, d=Q[:, :, 0])


def planar_term(p: WandProblem, free: np.ndarray, raw=None) -> PlanarWandTerm:
    """The :class:`PlanarWandTerm` of a planar wand's problem (every observation, ends included)."""
    assert p.across is not None
    return PlanarWandTerm(p.camera, p.frame, p.xy, p.focal[p.camera], p.offsets, p.across, p.n_frames, free,
                          p.n_cams, raw)


def with_interior(problem: WandProblem, row: np.ndarray, camera: np.ndarray, xy: np.ndarray,
                  along: np.ndarray, rank: np.ndarray, row_frame: np.ndarray, across: np.ndarray | None = None) -> WandProblem:
    """``problem`` (the end markers) plus interior-marker observations.

    Args:
        problem: the ends' problem; its observations keep their order and come first.
        row: (Q,) the labelled pair each interior blob belongs to; camera: (Q,); xy: (Q, 2)
            normalised; along: (Q,) its marker's position on the axis, metres; rank: (Q,) its
            place from end 0 (1..K-2).
        row_frame: (P,) each labelled pair's frame index in ``problem``, -1 where the frame was
            left out (seen by fewer than two cameras).
        across: (Q,) a planar wand's offsets across the axis, metres (the ends' are 0), or None.
    """
    keep = row_frame[row] >= 0
    n = len(problem.camera)
    planar = None if across is None else np.concatenate([np.zeros(n), across[keep]])
    return WandProblem(
        camera=np.concatenate([problem.camera, camera[keep]]),
        frame=np.concatenate([problem.frame, row_frame[row][keep]]),
        end=np.concatenate([problem.end, 1 + rank[keep]]),  # interior ranks after the ends' 0 and 1
        xy=np.concatenate([problem.xy, xy[keep]]),
        focal=problem.focal,
        length=problem.length,
        n_frames=problem.n_frames,
        along=np.concatenate([problem.offsets[:n], along[keep]]),
        across=planar,
    )


def marker_model(problem: WandProblem, pair_index: np.ndarray, labelled_camera: np.ndarray, xy: np.ndarray,
                 along: np.ndarray, R: np.ndarray, t: np.ndarray, wand: np.ndarray,
                 fixed: np.ndarray, across: np.ndarray | None = None) -> tuple[WandModel, np.ndarray]:
    """The wand model of every marker, started at the given poses and wand ends, and (Q,) the
    labelled pair of each interior observation (they follow the ends' observations).

    Args:
        problem: the end markers' problem; pair_index: (M,) the labelled pair of each of its
            observations (wandcal.calib.run.refine.Setup).
        labelled_camera: (P,) each labelled pair's camera; xy: (P, K, 2) its blobs from end 0
            and along: (P, K) their axial positions, metres (wandcal.calib.start.markerlabels).
        R: (N, 3, 3), t: (N, 3), wand: (F, 2, 3) the start; fixed: (N,) the gauge cameras.
        across: (P, K) a planar wand's offsets across the axis, metres, or None. Its rows are
            labelled absolutely (end 0 is the layout's own in every row), so the ends'
            observations take the labels' blobs too.
    """
    P, k = along.shape
    row_frame = np.full(P, -1)
    row_frame[pair_index] = problem.frame
    row = np.repeat(np.arange(P), k - 2)
    rank = np.tile(np.arange(1, k - 1), P)
    if across is not None:
        problem = replace(problem, xy=xy[pair_index, np.where(problem.end == 1, k - 1, 0)])
    full = with_interior(problem, row, labelled_camera[row], xy[:, 1:-1].reshape(-1, 2), along[:, 1:-1].ravel(), rank,
                         row_frame, None if across is None else across[:, 1:-1].ravel())
    plane0 = None
    if across is not None:
        wand = _ends(full, R, t, wand)  # the frames' start from the labels: end 0 is the layout's own in every row
        plane0 = _planes(full, R, t, wand)
    return WandModel(full, R, t, wand, fixed, plane0), row[row_frame[row] >= 0]


def _ends(problem: WandProblem, R: np.ndarray, t: np.ndarray, wand: np.ndarray) -> np.ndarray:
    """(F, 2, 3) each frame's end markers triangulated at R, t from ``problem``'s end observations;
    ``wand`` where they do not triangulate."""
    from wandcal.calib.triangulate import triangulate_points

    ends = problem.end <= 1
    X = triangulate_points(R, t, problem.point[ends], problem.camera[ends], problem.xy[ends],
                           2 * problem.n_frames).reshape(-1, 2, 3)
    return np.where(np.all(np.isfinite(X), axis=(1, 2))[:, None, None], X, wand)


def _planes(problem: WandProblem, R: np.ndarray, t: np.ndarray, wand: np.ndarray) -> np.ndarray:
    """(F, 3) each frame's in-plane direction across the axis, from its markers triangulated at
    R, t: the least-squares ``e`` of ``X_k - m - o_k d = q_k e`` over the off-axis markers; any
    normal to the axis where they do not triangulate."""
    from wandcal.calib.triangulate import triangulate_points

    F = problem.n_frames
    point = problem.frame * (problem.end.max() + 1) + problem.end
    n_points = F * (problem.end.max() + 1)
    X = triangulate_points(R, t, point, problem.camera, problem.xy, n_points).reshape(F, -1, 3)
    m = wand.mean(axis=1)
    d = (wand[:, 1] - wand[:, 0]) / np.linalg.norm(wand[:, 1] - wand[:, 0], axis=1, keepdims=True)
    along = np.zeros(X.shape[:2])
    across = np.zeros(X.shape[:2])
    along[problem.frame, problem.end] = problem.offsets
    across[problem.frame, problem.end] = problem.across
    v = X - m[:, None] - along[..., None] * d[:, None]
    e = np.nansum(across[..., None] * np.where(np.isfinite(v), v, 0.0), axis=1)
    fallback = np.cross(d, np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    e = e - np.einsum("fi,fi->f", e, d)[:, None] * d
    weak = np.linalg.norm(e, axis=1) < 1e-9
    e[weak] = fallback[weak]
    return e


def marker_pair_lengths(R: np.ndarray, t: np.ndarray, frame: np.ndarray, camera: np.ndarray, xy: np.ndarray,
                        marker: np.ndarray, layout: np.ndarray) -> list[dict]:
    """Each marker pair's distance, every marker triangulated on its own (no layout constraint).

    Args:
        frame: (P,) frame index of each labelled camera-frame; camera: (P,); xy: (P, K, 2)
            normalised blobs; marker: (P, K) their layout index. layout: (K, 3) metres.

    Returns:
        one dict per pair (i < j): ``markers`` [i, j], ``length_m`` (the layout's),
        ``mean_error_m`` and ``std_m`` of the measured distances, ``frames``.
    """
    from wandcal.calib.triangulate import triangulate_points

    k = layout.shape[0]
    n_frames = int(frame.max()) + 1 if len(frame) else 0
    point = (frame[:, None] * k + marker).ravel()
    cams = np.repeat(camera, k)
    X = triangulate_points(R, t, point, cams, xy.reshape(-1, 2), n_frames * k).reshape(n_frames, k, 3)
    out = []
    for i in range(k):
        for j in range(i + 1, k):
            d = np.linalg.norm(X[:, i] - X[:, j], axis=1)
            d = d[np.isfinite(d)]
            true = float(np.linalg.norm(layout[i] - layout[j]))
            out.append({"markers": [i, j], "length_m": true, "mean_error_m": float(d.mean() - true) if len(d) else None,
                        "std_m": float(d.std()) if len(d) else None, "frames": int(len(d))})
    return out
