"""A refinement problem: the labelled wand pairs triangulated at the start poses into the wand model
(:class:`Setup`), restricted to kept pairs, point tracks added as frames, and the world's up
direction the paper's height rows need."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.solve.wandmodel import WandModel, WandProblem
from wandcal.calib.start.labels import flatten
from wandcal.calib.triangulate import triangulate_points

TRACK_FRAME_HALF = np.array([0.5, 0.0, 0.0])  # a point track's frame in with_tracks: any unit direction

GAUGE_CAMERA = 0


@dataclass(frozen=True, eq=False)
class Setup:
    """A refinement problem and the bookkeeping to map its frames back to the capture.

    frames: (F,) capture frame numbers of the problem's wand frames; pair_index: (M,) the row
    of the labelled pairs each observation came from; uv: (M, 2) its raw pixels.
    """

    problem: WandProblem
    model: WandModel
    frames: np.ndarray
    pair_index: np.ndarray
    uv: np.ndarray


def build_problem(rig: Rig, pairs: WandPairs, R: np.ndarray, t: np.ndarray, gauge: int | np.ndarray = 0) -> Setup:
    """Triangulate the labelled pairs at the given poses and set up the wand model.

    Frames seen by fewer than two cameras are left out. The camera ``gauge`` is held fixed (or,
    given an (N,) bool array, every camera it marks).
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
        length=rig.wand_length if rig.wand_length is not None else 0.0,
        n_frames=int(ok.sum()),
    )
    if isinstance(gauge, np.ndarray):
        fixed = gauge.astype(bool)
    else:
        fixed = np.zeros(len(rig.cameras), bool)
        fixed[gauge] = True
    model = WandModel(problem, R, t, X[ok], fixed)
    uv = np.concatenate([pairs.uv[:, 0], pairs.uv[:, 1]])[sel][order]
    return Setup(problem=problem, model=model, frames=pairs.frames[ok], pair_index=pair_index, uv=uv)


def restarted(setup: Setup, keep: np.ndarray, R: np.ndarray, t: np.ndarray, wand: np.ndarray) -> Setup:
    """The setup restricted to the labelled pairs where ``keep`` (P,) is true and started at the
    given poses and wand (F, 2, 3), with no new triangulation: as :func:`build_problem` on
    ``pairs.subset(keep)``, frames left with fewer than two cameras dropped."""
    p = setup.problem
    obs = keep[setup.pair_index]
    views = np.bincount(p.frame[obs], minlength=p.n_frames) // 2
    frame_ok = views >= 2
    obs &= frame_ok[p.frame]
    new_frame = np.cumsum(frame_ok) - 1
    problem = WandProblem(p.camera[obs], new_frame[p.frame[obs]], p.end[obs], p.xy[obs], p.focal, p.length, int(frame_ok.sum()))
    model = WandModel(problem, R, t, wand[frame_ok], setup.model.fixed)
    pair_index = (np.cumsum(keep) - 1)[setup.pair_index[obs]]
    return Setup(problem=problem, model=model, frames=setup.frames[frame_ok], pair_index=pair_index, uv=setup.uv[obs])


def with_tracks(model: WandModel, tracks: PointTracks | None, X: np.ndarray | None) -> WandModel:
    """The wand model with each point track as one more frame whose observations sit at the
    frame's midpoint (``along`` 0): its 3D point is the midpoint and its direction is left free
    (the frame's normal matrix is then singular in it, which the LP's elimination regularises),
    so ``lp`` refines point tracks beside the wand with no new kind of unknown. ``model`` itself
    without tracks. X: (T, 3) the tracks' start points, metres."""
    if tracks is None or X is None or not len(tracks):
        return model
    p = model.p
    F = p.n_frames
    problem = WandProblem(
        camera=np.concatenate([p.camera, tracks.camera]), frame=np.concatenate([p.frame, F + tracks.track]),
        end=np.concatenate([p.end, np.zeros(len(tracks), dtype=p.end.dtype)]), xy=np.concatenate([p.xy, tracks.xy]),
        focal=p.focal, length=p.length, n_frames=F + tracks.n_tracks,
        along=np.concatenate([p.offsets, np.zeros(len(tracks))]),
    )
    # any direction starts a point's frame: its observations do not depend on it
    ends = np.stack([X - TRACK_FRAME_HALF, X + TRACK_FRAME_HALF], axis=1)
    wand0 = model.wand(model.x0()) if F else np.zeros((0, 2, 3))
    return WandModel(problem, model.R0, model.t0, np.concatenate([wand0, ends]), model.fixed)


def triangulated(R, t, tracks: PointTracks):
    """The tracks that triangulate at the given poses, and their points (T, 3)."""
    X = triangulate_points(R, t, tracks.track, tracks.camera, tracks.xy, tracks.n_tracks)
    ok = np.all(np.isfinite(X), axis=1)
    if ok.all():
        return tracks, X
    return tracks.subset(ok[tracks.track]), X[ok]


def up_direction(rig: Rig, R: np.ndarray, t: np.ndarray, setup: Setup) -> np.ndarray:
    """World up for the paper's height constraints: +z of the static object's frame; without one,
    from the wand's centroid towards the cameras' centroid (cameras on a ring above the volume)."""
    if rig.static_markers is not None or not len(setup.model.m0):
        return np.array([0.0, 0.0, 1.0])
    v = camera_centers(R, t).mean(0) - setup.model.m0.mean(0)
    return v / np.linalg.norm(v)
