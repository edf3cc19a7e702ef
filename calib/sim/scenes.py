"""Seeded scenes taken part-way through the pipeline, for tests and benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import distort_points, project_normalized, rotvec_to_matrix
from wandcal.calib.observations import WandPairs, wand_pairs
from wandcal.calib.rig import PointObservations, WandObservations
from wandcal.calib.run.refine import Setup, build_problem
from wandcal.calib.sim.simulate import SimulatedCapture, simulate_capture
from wandcal.calib.solve.wandmodel import WandModel
from wandcal.calib.start.initial import Initial, initial_poses
from wandcal.calib.start.labels import label_ends
from wandcal.calib.start.static import solve_static
from wandcal.calib.triangulate import triangulate_points

THIRD_VIEW = 0.1  # fraction of the frames of a pairwise scene that a third camera also sees


@dataclass(frozen=True, eq=False)
class PreparedScene:
    sim: SimulatedCapture
    pairs: WandPairs
    init: Initial
    labelled: WandPairs
    setup: Setup


def prepared_scene(cameras=5, frames=300, noise_px=0.5, seed=0, outliers=0.0, static=True) -> PreparedScene:
    """Simulate a capture and take it through observations, initial poses, labels and problem set-up."""
    sim = simulate_capture(cameras, frames, noise_px, outliers, static, seed)
    pairs = wand_pairs(sim.rig, sim.wand)
    init = initial_poses(sim.rig, pairs, solve_static(sim.rig, sim.static) if sim.static is not None else None)
    labelled, _ = label_ends(init.R, init.t, pairs, np.ones(cameras, bool), sim.rig.wand_length)
    setup = build_problem(sim.rig, labelled, init.R, init.t)
    return PreparedScene(sim, pairs, init, labelled, setup)


def perturbed_model(scene, degrees: float, metres: float, seed: int) -> WandModel:
    """The scene's problem started from the true poses moved by ``degrees`` about a random axis
    and ``metres`` in a random direction (every camera but the gauge), frames triangulated there."""
    rng = np.random.default_rng(seed)
    T, p = scene.sim.truth, scene.setup.problem
    R, t = T.R.copy(), T.t.copy()
    for n in range(1, len(R)):
        axis = rng.normal(size=3)
        R[n] = rotvec_to_matrix(axis / np.linalg.norm(axis) * np.radians(degrees)) @ R[n]
        shift = rng.normal(size=3)
        C = -R[n].T @ t[n] + shift / np.linalg.norm(shift) * metres
        t[n] = -R[n] @ C
    X = triangulate_points(R, t, p.point, p.camera, p.xy, 2 * p.n_frames).reshape(-1, 2, 3)
    return WandModel(p, R, t, X, scene.setup.model.fixed)


def _ring_mask(seen: np.ndarray, rng: np.random.Generator, third: float = THIRD_VIEW) -> np.ndarray:
    """Keep, of each frame (row of ``seen`` (F, N) bool), one ring-neighbour pair of cameras
    (k, k+1) that both see it, and with probability ``third`` the next camera k+2 as well."""
    F, N = seen.shape
    keep = np.zeros_like(seen)
    k = np.arange(N)
    for f in range(F):
        ok = np.flatnonzero(seen[f, k] & seen[f, (k + 1) % N])
        if len(ok) == 0:
            continue
        a = rng.choice(ok)
        keep[f, [a, (a + 1) % N]] = True
        if rng.random() < third and seen[f, (a + 2) % N]:
            keep[f, (a + 2) % N] = True
    return keep


def pairwise_wand(sim, rng, third: float = THIRD_VIEW) -> WandObservations:
    """The capture's wand blobs, each frame kept only in a ring pair (or triple) of cameras."""
    w = sim.wand
    F, N = len(sim.truth.wand), len(sim.rig.cameras)
    blobs = np.zeros((F, N), dtype=np.int64)
    np.add.at(blobs, (w.frame, w.camera), 1)
    keep = _ring_mask(blobs == 2, rng, third)
    sel = keep[w.frame, w.camera]
    return WandObservations(w.frame[sel], w.camera[sel], w.uv[sel])


def pairwise_points(sim, n: int, rng, third: float = THIRD_VIEW, noise_px: float = 0.5) -> PointObservations:
    """``n`` points spread through the wand's volume, seen (with blob noise) by ring pairs of
    cameras; the point index is the frame."""
    X = rng.uniform([-0.9, -0.9, 0.3], [0.9, 0.9, 1.7], (n, 3))
    cams = sim.rig.cameras
    uv = np.stack([distort_points(c, project_normalized(sim.truth.R[i], sim.truth.t[i], X)) for i, c in enumerate(cams)], 1)
    uv += rng.normal(0, noise_px, uv.shape)
    inside = (uv[..., 0] > 0) & (uv[..., 0] < cams[0].width) & (uv[..., 1] > 0) & (uv[..., 1] < cams[0].height)
    keep = _ring_mask(inside, rng, third)
    frame, camera = np.nonzero(keep)
    return PointObservations(frame, camera, uv[frame, camera])


def knocked_capture(sim: SimulatedCapture, camera: int, degrees: float, metres: float, frames: int, seed: int):
    """A fresh wand capture of ``sim``'s rig after camera ``camera`` was knocked by ``degrees``
    about a random axis and moved ``metres`` in a random direction: (wand observations, R, t)
    with the rig's true poses after the knock."""
    from wandcal.calib.sim.simulate import observe_wand, wand_path

    if sim.rig.wand_length is None:
        raise ValueError("knocked_capture: the simulated rig has no wand to film")
    rng = np.random.default_rng(seed)
    R, t = sim.truth.R.copy(), sim.truth.t.copy()
    axis = rng.normal(size=3)
    move = rng.normal(size=3)
    C = -R[camera].T @ t[camera] + metres * move / np.linalg.norm(move)
    R[camera] = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis)) @ R[camera]
    t[camera] = -R[camera] @ C
    wand = wand_path(frames, sim.rig.wand_length, rng)
    if sim.rig.wand_markers is not None:  # every marker of a multi-marker wand, rolling about its axis
        from wandcal.calib.sim.simulate import ROLL_STREAM, place_markers, wand_roll
        from wandcal.calib.wandlayout import plane_offsets

        roll = wand_roll(np.random.default_rng([seed, ROLL_STREAM]))
        wand = place_markers(wand, plane_offsets(sim.rig.wand_markers), roll(np.arange(frames, dtype=float)),
                             sim.rig.wand_length)
    noise = 0.3
    return observe_wand(sim.rig.cameras, R, t, wand, noise, 0.0, 0.03, rng), R, t
