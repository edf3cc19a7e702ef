"""A multi-marker wand's interior markers in the wand model: the known geometry inside ``ba``.

The two-marker problem (wandcal.calib.refine.build_problem on the end markers) is extended with
one observation per interior blob, placed on the frame's wand at its marker's position along the
axis (``WandProblem.along``), so every marker's known position constrains the frame's midpoint
and direction, and through them the cameras, as the wand length does for the ends.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.solve.wandmodel import WandProblem


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
