"""A multi-marker wand's interior markers in the wand model: the known geometry inside ``ba``.

The two-marker problem (wandcal.calib.refine.build_problem on the end markers) is extended with
one observation per interior blob, placed on the frame's wand at its marker's position along the
axis (``WandProblem.along``), so every marker's known position constrains the frame's midpoint
and direction, and through them the cameras, as the wand length does for the ends.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.solve.wandmodel import WandModel, WandProblem


def with_interior(problem: WandProblem, row: np.ndarray, camera: np.ndarray, xy: np.ndarray,
                  along: np.ndarray, rank: np.ndarray, row_frame: np.ndarray) -> WandProblem:
    """``problem`` (the end markers) plus interior-marker observations.

    Args:
        problem: the ends' problem; its observations keep their order and come first.
        row: (Q,) the labelled pair each interior blob belongs to; camera: (Q,); xy: (Q, 2)
            normalised; along: (Q,) its marker's position on the axis, metres; rank: (Q,) its
            place from end 0 (1..K-2).
        row_frame: (P,) each labelled pair's frame index in ``problem``, -1 where the frame was
            left out (seen by fewer than two cameras).
    """
    keep = row_frame[row] >= 0
    n = len(problem.camera)
    return WandProblem(
        camera=np.concatenate([problem.camera, camera[keep]]),
        frame=np.concatenate([problem.frame, row_frame[row][keep]]),
        end=np.concatenate([problem.end, 1 + rank[keep]]),  # interior ranks after the ends' 0 and 1
        xy=np.concatenate([problem.xy, xy[keep]]),
        focal=problem.focal,
        length=problem.length,
        n_frames=problem.n_frames,
        along=np.concatenate([problem.offsets[:n], along[keep]]),
    )


def marker_model(problem: WandProblem, pair_index: np.ndarray, labelled_camera: np.ndarray, xy: np.ndarray,
                 along: np.ndarray, R: np.ndarray, t: np.ndarray, wand: np.ndarray,
                 fixed: np.ndarray) -> tuple[WandModel, np.ndarray]:
    """The wand model of every marker, started at the given poses and wand ends, and (Q,) the
    labelled pair of each interior observation (they follow the ends' observations).

    Args:
        problem: the end markers' problem; pair_index: (M,) the labelled pair of each of its
            observations (wandcal.calib.refine.Setup).
        labelled_camera: (P,) each labelled pair's camera; xy: (P, K, 2) its blobs from end 0
            and along: (P, K) their axial positions, metres (wandcal.calib.start.markerlabels).
        R: (N, 3, 3), t: (N, 3), wand: (F, 2, 3) the start; fixed: (N,) the gauge cameras.
    """
    P, k = along.shape
    row_frame = np.full(P, -1)
    row_frame[pair_index] = problem.frame
    row = np.repeat(np.arange(P), k - 2)
    rank = np.tile(np.arange(1, k - 1), P)
    full = with_interior(problem, row, labelled_camera[row], xy[:, 1:-1].reshape(-1, 2), along[:, 1:-1].ravel(), rank,
                         row_frame)
    return WandModel(full, R, t, wand, fixed), row[row_frame[row] >= 0]


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
