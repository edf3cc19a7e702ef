"""Properties of the geometry, checked by Hypothesis over random scenes: projection and
triangulation round trips; a rigid motion of the world moves the refined rig with it; the
cameras' order and the wand ends' order change nothing; garbage rows never crash the pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import FUZZ, FUZZ_PIPELINE, FUZZ_SLOW, TRIED
from tests.reliability.test_degenerate import ABSOLUTE_TOL_M
from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import (
    camera_centers,
    distort_points,
    project_normalized,
    rotvec_to_matrix,
    undistort_points,
)
from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.rig import Camera, Rig, StaticObservations, WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene
from wandcal.calib.sim.simulate import look_at, simulate_capture
from wandcal.calib.solve import ba
from wandcal.calib.solve.wandmodel import WandModel
from wandcal.calib.triangulate import triangulate_points

NOISE_PX = 0.3
# Two runs that end at the same optimum differ by the stopping rule's slack: each parameter
# within ba.STOP_SE of its standard error, ~1 mm for these rigs' centres (0.3 px, f ~1100 px,
# 4.5 m: tests/reliability/test_degenerate.py); twice that per run bounds their difference.
SAME_OPTIMUM_M = 2 * 2 * ba.STOP_SE * 2 * NOISE_PX / 1100.0 * 4.5
ROUND_TRIP_PX = 1e-6  # noise-free round trips are exact up to the iterative undistortion's 1e-12
# Lenses of motion-capture cameras: 1280 px wide at 40-80 degrees of field. Wider (f = 400 px,
# k2 = 0.06) the undistortion's 40 fixed-point steps leave 0.03 px at the image corners (found by
# this test; docs/reliability.md), still far below the blobs' 0.1-0.3 px noise.
FOCAL_RANGE_PX = (800.0, 3000.0)


def unit_vectors():
    return st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1).map(
        lambda v: np.array(v) / np.linalg.norm(v))


@FUZZ
@given(seed=st.integers(0, 2**32 - 1), n_cams=st.integers(2, 6), spread_m=st.floats(0.05, 3.0))
def test_projection_and_triangulation_round_trip(seed, n_cams, spread_m):
    """Points seen without noise by cameras around them triangulate back to themselves."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-spread_m, spread_m, (40, 3))
    poses = []
    for _ in range(n_cams):
        direction = rng.normal(size=3)
        centre = direction / np.linalg.norm(direction) * (3 * spread_m + rng.uniform(1, 5))
        poses.append(look_at(centre, rng.uniform(-0.1, 0.1, 3), roll=rng.uniform(-np.pi, np.pi)))
    R, t = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
    point = np.tile(np.arange(len(X)), n_cams)
    camera = np.repeat(np.arange(n_cams), len(X))
    xy = project_normalized(R[camera], t[camera], X[point])
    back = triangulate_points(R, t, point, camera, xy, len(X))
    TRIED["property: triangulation round trip"] += 1
    scale = np.abs(X).max() + np.linalg.norm(camera_centers(R, t), axis=1).max()
    assert np.abs(back - X).max() < 1e-9 * scale


@FUZZ
@given(k1=st.floats(-0.3, 0.1), k2=st.floats(-0.05, 0.1), p=st.tuples(st.floats(-2e-3, 2e-3), st.floats(-2e-3, 2e-3)),
       f=st.floats(*FOCAL_RANGE_PX), seed=st.integers(0, 2**32 - 1))
def test_distortion_round_trip_over_the_image(k1, k2, p, f, seed):
    """Pixels -> normalised -> pixels returns the pixel anywhere in a lens's image circle where the
    lens model is one-to-one (radius where d(r(1 + k1 r^2 + k2 r^4))/dr stays positive)."""
    cam = Camera("c", 1280, 1024, np.array([[f, 0, 640], [0, f, 512], [0, 0, 1]]), np.array([k1, k2, *p, 0.0]))
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.8, 0.8, (200, 2)) * (640 / f)
    r2 = np.sum(xy**2, axis=1)
    monotone = 1 + 3 * k1 * r2 + 5 * k2 * r2**2 > 0.2  # well inside the one-to-one part
    uv = distort_points(cam, xy[monotone])
    TRIED["property: distortion round trip"] += 1
    assert np.abs(distort_points(cam, undistort_points(cam, uv)) - uv).max() < ROUND_TRIP_PX


@FUZZ_SLOW
@given(axis=unit_vectors(), angle=st.floats(-np.pi, np.pi), shift=st.tuples(*[st.floats(-50, 50)] * 3))
def test_a_rigid_motion_of_the_world_leaves_the_refined_rig_unchanged(refined_scene, axis, angle, shift):
    """Bundle adjustment started from the same poses in a moved world frame ends at the same rig:
    the same relative poses, to the stopping rule's slack in standard errors."""
    scene, start, x_ref, bound = refined_scene
    Q, q = rotvec_to_matrix(axis * angle), np.array(shift)
    R0, t0 = start.poses(start.x0())
    R1 = R0 @ Q.T
    moved = WandModel(scene.setup.problem, R1, t0 - np.einsum("nij,j->ni", R1, q), start.wand(start.x0()) @ Q.T + q,
                      start.fixed)
    x, info = ba.bundle_adjust(moved)
    TRIED["property: rigid motion of the world"] += 1
    assert info["status"] == "converged"
    centre, rotation = gauge_errors(*moved.poses(x), *start.poses(x_ref), 0)
    assert np.all(centre[1:] < 4 * ba.STOP_SE * bound[0][1:])
    assert np.all(rotation[1:] < 4 * ba.STOP_SE * bound[1][1:])


def _refined_scene():
    scene = prepared_scene(cameras=4, frames=150, noise_px=NOISE_PX, seed=4)
    start = perturbed_model(scene, degrees=1.0, metres=0.03, seed=4)
    x_ref, _ = ba.bundle_adjust(start)
    T = scene.sim.truth
    bound = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE_PX)
    return scene, start, x_ref, bound


@pytest.fixture(scope="module")
def refined_scene():
    return _refined_scene()


@pytest.fixture(scope="module")
def base():
    sim = simulate_capture(4, 200, NOISE_PX, seed=5)
    return sim, calibrate(sim.rig, sim.wand, sim.static)


@FUZZ_PIPELINE
@given(perm=st.permutations(range(4)))
def test_the_cameras_order_changes_nothing(base, perm):
    sim, reference = base
    perm = np.array(perm)
    new_index = np.argsort(perm)  # old camera c becomes camera new_index[c]
    rig = Rig(tuple(sim.rig.cameras[p] for p in perm), sim.rig.wand_length, sim.rig.static_markers)
    wand = WandObservations(sim.wand.frame, new_index[sim.wand.camera], sim.wand.uv)
    static = StaticObservations(new_index[sim.static.camera], sim.static.uv)
    result = calibrate(rig, wand, static)
    TRIED["property: camera order"] += 1
    assert [c.id for c in result.rig.cameras] == [sim.rig.cameras[p].id for p in perm]
    assert np.abs(result.centers[new_index] - reference.centers).max() < SAME_OPTIMUM_M


@FUZZ_PIPELINE
@given(swap=st.lists(st.booleans(), min_size=64, max_size=64))
def test_the_wand_ends_order_changes_nothing(base, swap):
    """Which of a camera-frame's two blobs comes first (the detector's order) does not matter."""
    sim, reference = base
    rows = np.arange(len(sim.wand))
    key = sim.wand.frame * 16 + sim.wand.camera
    flip = np.array(swap)[key % len(swap)]
    order = np.lexsort((np.where(flip[rows], -rows, rows), sim.wand.camera, sim.wand.frame))
    wand = WandObservations(sim.wand.frame[order], sim.wand.camera[order], sim.wand.uv[order])
    result = calibrate(sim.rig, wand, sim.static)
    TRIED["property: wand end order"] += 1
    assert np.abs(result.centers - reference.centers).max() < SAME_OPTIMUM_M


GARBAGE = st.lists(st.tuples(st.integers(0, 10**15), st.integers(0, 3),
                             st.floats(-1e12, 1e12, allow_nan=False), st.floats(-1e12, 1e12, allow_nan=False)),
                   min_size=1, max_size=60)


@FUZZ_PIPELINE
@given(rows=GARBAGE, near=st.booleans())
def test_garbage_rows_never_crash_the_pipeline(base, rows, near):
    """Random extra rows (any frame, camera and pixel, or pixels near the wand's own) are
    counted and dropped, or refused with a reason; never a traceback."""
    sim, _ = base
    frame, camera, u, v = (np.array(c) for c in zip(*rows))
    if near:  # plausible blobs inside existing frames: extra blobs, not far-away junk
        frame, u, v = frame % 200, np.abs(u) % 1280, np.abs(v) % 1024
    wand = WandObservations(np.r_[sim.wand.frame, frame], np.r_[sim.wand.camera, camera],
                            np.r_[sim.wand.uv, np.c_[u, v]])
    TRIED["property: garbage wand rows"] += 1
    try:
        result = calibrate(sim.rig, wand, sim.static)
    except CalibrationError:
        return
    # a camera-frame with an extra blob is dropped; new frames seen by one camera add nothing:
    # at most a few dozen of ~800 camera-frames change, so the rig stays within the noise's bound
    assert np.linalg.norm(result.centers - sim.truth.centers, axis=1).max() < ABSOLUTE_TOL_M
