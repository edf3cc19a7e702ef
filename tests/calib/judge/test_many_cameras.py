"""Each camera's own errors on a large rig (wandcal.calib.run.rig_faults.many_camera_faults): a
simulated 16-camera ring whose camera 4 is knocked halfway through the capture and whose camera 10
is three times as noisy as the others. The moved camera is named moved (not "intrinsics", which
the suspect screen alone calls its later views), the noisy one noise, and the step's full test
runs on at most a few cameras the cheap screen suspects. Tolerances: the estimates' own standard
errors and the split search's spacing."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wandcal.calib.geometry import distort_points, rotvec_to_matrix, undistort_points
from wandcal.calib.judge.faults import moved, pose_steps
from wandcal.calib.rig import WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture

CAMERAS, FRAMES, NOISE_PX = 16, 1200, 0.3
KNOCKED, KNOCK_DEG = 3, 0.5
NOISY, NOISE_FACTOR = 9, 3.0


def _knocked(sim, c: int, degrees: float, seed: int):
    """Camera c turned by ``degrees`` about a random axis after the middle of its frames: its later
    blobs seen through the turned camera (each ray undistorted, turned, projected, distorted)."""
    axis = np.random.default_rng(seed).normal(size=3)
    Rk = rotvec_to_matrix(np.radians(degrees) * axis / np.linalg.norm(axis))
    w = sim.wand
    mine = w.camera == c
    at = float(np.median(w.frame[mine]))
    after = mine & (w.frame > at)
    xy = undistort_points(sim.rig.cameras[c], w.uv[after])
    ray = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ Rk.T
    uv = w.uv.copy()
    uv[after] = distort_points(sim.rig.cameras[c], ray[:, :2] / ray[:, 2:])
    return replace(sim, wand=WandObservations(w.frame, w.camera, uv)), at


def _noisy(sim, c: int, factor: float, seed: int):
    w = sim.wand
    uv = w.uv.copy()
    mine = w.camera == c
    uv[mine] += np.random.default_rng(seed).normal(0, NOISE_PX * np.sqrt(factor**2 - 1), (int(mine.sum()), 2))
    return replace(sim, wand=WandObservations(w.frame, w.camera, uv))


@pytest.fixture(scope="module")
def judged():
    sim = simulate_capture(CAMERAS, FRAMES, NOISE_PX, 0.02, True, 7)
    sim, at = _knocked(sim, KNOCKED, KNOCK_DEG, 1)
    sim = _noisy(sim, NOISY, NOISE_FACTOR, 2)
    tested = []
    full = pose_steps.pose_step

    def counted(el, c):
        tested.append(c)
        return full(el, c)

    pose_steps.pose_step = counted
    try:
        doc = calibrate(sim.rig, sim.wand, sim.static).to_json()
    finally:
        pose_steps.pose_step = full
    return sim, at, doc, tested


def test_a_knocked_and_a_noisy_camera_of_sixteen_are_named_each_with_its_own_kind(judged):
    sim, at, doc, _ = judged
    faults = doc["verdict"]["faults"]
    ids = sim.rig.ids
    assert {(f["kind"], f["camera"]) for f in faults} == {("moved", ids[KNOCKED]), ("noise", ids[NOISY])}
    ev = next(f["evidence"] for f in faults if f["kind"] == "moved")
    # the split is searched among MAX_SPLITS candidates over the camera's frames
    assert abs(ev["frame"] - at) <= 2 * FRAMES / pose_steps.MAX_SPLITS
    assert abs(ev["degrees"] - KNOCK_DEG) < 4 * ev["degrees_std"]
    assert doc["verdict"]["level"] == "poor"


def test_the_full_step_test_runs_on_a_few_suspects_only(judged):
    _, _, _, tested = judged
    assert KNOCKED in tested
    # the screen's suspects, and each of them found stepping tested again without the one named
    assert len(set(tested)) <= moved.MAX_STEP_SUSPECTS
    assert len(tested) <= moved.MAX_STEP_SUSPECTS * (1 + moved.MAX_STEP_SUSPECTS)
