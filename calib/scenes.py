"""Seeded scenes taken part-way through the pipeline, for tests and benchmarks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.initial import Initial, initial_poses
from calib.labels import label_ends
from calib.observations import WandPairs, wand_pairs
from calib.refine import Setup, build_problem
from calib.simulate import SimulatedCapture, simulate_capture
from calib.static import solve_static


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
    init = initial_poses(sim.rig, pairs, solve_static(sim.rig, sim.static) if static else None)
    labelled, _ = label_ends(init.R, init.t, pairs, np.ones(cameras, bool), sim.rig.wand_length)
    setup = build_problem(sim.rig, labelled, init.R, init.t)
    return PreparedScene(sim, pairs, init, labelled, setup)
