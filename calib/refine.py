"""From labelled wand pairs and start poses to a refinement problem, and back."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.labels import flatten
from calib.observations import WandPairs
from calib.rig import Rig
from calib.triangulate import triangulate_points
from calib.wandmodel import WandModel, WandProblem


@dataclass(frozen=True, eq=False)
class Setup:
    """A refinement problem and the bookkeeping to map its frames back to the capture.

    frames: (F,) capture frame numbers of the problem's wand frames; pair_index: (M,) the row
    of the labelled pairs each observation came from.
    """

    problem: WandProblem
    model: WandModel
    frames: np.ndarray
    pair_index: np.ndarray


def build_problem(rig: Rig, pairs: WandPairs, R: np.ndarray, t: np.ndarray, gauge: int = 0) -> Setup:
    """Triangulate the labelled pairs at the given poses and set up the wand model.

    Frames seen by fewer than two cameras are left out. The camera ``gauge`` is held fixed.
    """
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    ok = np.all(np.isfinite(X), axis=(1, 2))
    new_index = np.cumsum(ok) - 1
    P = len(pairs)
    obs_pair = np.concatenate([np.arange(P), np.arange(P)])
    end = np.repeat([0, 1], P)
    sel = ok[pairs.frame][obs_pair]
    order = np.argsort(obs_pair[sel] * 2 + end[sel], kind="stable")
    pair_index = obs_pair[sel][order]
    problem = WandProblem(
        camera=camera[sel][order],
        frame=new_index[pairs.frame[pair_index]],
        end=end[sel][order],
        xy=xy[sel][order],
        focal=np.array([c.focal for c in rig.cameras]),
        length=rig.wand_length,
        n_frames=int(ok.sum()),
    )
    fixed = np.zeros(len(rig.cameras), bool)
    fixed[gauge] = True
    model = WandModel(problem, R, t, X[ok], fixed)
    return Setup(problem=problem, model=model, frames=pairs.frames[ok], pair_index=pair_index)
