"""A camera's rejected camera-frames bunched at one end of its time (calib/judge/faults/rejected_runs.py,
decision 0084): the block test's arithmetic is the binomial's, its false-alarm rate at the rig's
outlier rate is at most its level, and on a seeded four-camera wand rig a camera knocked
5 degrees (its later views all beyond the outlier limit) is named moved at its frame while gross
outliers spread in time name nothing."""

from __future__ import annotations

from math import comb

import numpy as np
import pytest

from tests.calib.judge.test_own_errors import FOCAL_PX, NOISE_PX, _rig
from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.faults.f_distribution import binomial_tail as binomial_sf
from wandcal.calib.judge.faults.f_distribution import binomial_upper
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA
from wandcal.calib.judge.faults.rejected_runs import (
    MIN_LENS_FRAMES,
    block_against_rate,
    camera_runs,
    lens_predicts_block,
    rejected_moved,
)
from wandcal.calib.judge.residuals import observation_residuals
from wandcal.calib.observations import WandPairs

WAND_FRAMES = 60


def test_the_binomial_tail_and_bound_are_exact():
    for x, n, q in [(3, 10, 0.1), (14, 14, 0.3), (1, 5, 0.02)]:
        exact = sum(comb(n, j) * q**j * (1 - q) ** (n - j) for j in range(x, n + 1))
        assert binomial_sf(x, n, q) == pytest.approx(exact, rel=1e-9)
    # the Clopper-Pearson upper bound: k or fewer of n at that rate with probability 2.5%
    for k, n in [(0, 30), (5, 46), (14, 46)]:
        q = binomial_upper(k, n)
        assert 1 - binomial_sf(k + 1, n, q) == pytest.approx(0.025, abs=1e-6)
    assert binomial_upper(0, 30) == pytest.approx(1 - 0.025 ** (1 / 30), rel=1e-6)


def test_the_bounds_newton_steps_land_on_the_binomial_sums_root_at_large_counts():
    # a 128-camera rig's others: hundreds rejected of thousands; Newton's root of the exact sum
    for k, n in [(244, 8000), (3000, 90000), (0, 300000), (7, 12)]:
        q = binomial_upper(k, n)
        assert 1 - binomial_sf(k + 1, n, q) == pytest.approx(0.025, abs=1e-10)


def test_a_block_names_the_frame_it_ends_at():
    rejected = np.r_[np.ones(10, bool), np.zeros(20, bool)]
    run = block_against_rate(rejected, 2 * np.arange(30), 0.1)
    assert run is not None and not run.tail and run.frame == 18 and run.rejected == run.block == 10
    assert run.p_value == pytest.approx(2 * 29 * 0.1**10, rel=1e-9)  # q^10, times 2 (n - 1) blocks
    run = block_against_rate(rejected[::-1], 2 * np.arange(30), 0.1)
    assert run is not None and run.tail and run.frame == 38
    assert block_against_rate(np.zeros(5, bool), np.arange(5), 0.1) is None


@pytest.mark.parametrize("n, rate", [(20, 0.1), (40, 0.3), (200, 0.02)])
def test_outliers_at_the_rigs_rate_raise_alarms_at_most_at_the_level(n, rate):
    """Under the null every camera-frame is rejected at the rate: the Bonferroni p is
    conservative, so at a level of 1% at most 1% of 500 seeded sequences fall under it (plus two
    of the count's binomial standard errors)."""
    rng = np.random.default_rng(n)
    runs = [block_against_rate(rng.random(n) < rate, np.arange(n), rate) for _ in range(500)]
    alarms = sum(r is not None and r.p_value < 0.01 for r in runs)
    assert alarms <= 500 * 0.01 + 2 * np.sqrt(500 * 0.01 * 0.99)


def _wand(R, t, rng, knock=None, outliers=0.0, lens=None) -> tuple[WandPairs, np.ndarray]:
    """WAND_FRAMES frames of a 0.5 m wand seen by every camera, NOISE_PX; ``outliers`` of the
    camera-frames with one end 20-40 px off (spread in time); knock: (camera, frame, rotation
    vector) turns that camera after that frame; lens: (camera, scale) that camera's views scaled
    about its image centre (its focal length off), the wand moving outwards from the rig's centre
    in time (so its views beyond the limit bunch late)."""
    n = len(R)
    mid = rng.uniform(-0.5, 0.5, (WAND_FRAMES, 3))
    if lens is not None:
        mid = mid[np.argsort(np.linalg.norm(mid, axis=1))]
    d = rng.normal(size=(WAND_FRAMES, 3))
    ends = mid[:, None] + 0.25 * np.array([-1.0, 1.0])[None, :, None] * (d / np.linalg.norm(d, axis=1, keepdims=True))[:, None]
    frame, camera, xy = [], [], []
    for f in range(WAND_FRAMES):
        for c in range(n):
            Xc = ends[f] @ R[c].T + t[c]
            if knock is not None and knock[0] == c and f > knock[1]:
                Xc = Xc @ rotvec_to_matrix(knock[2]).T
            scale = lens[1] if lens is not None and lens[0] == c else 1.0
            p = Xc[:, :2] / Xc[:, 2:] * scale + rng.normal(0, NOISE_PX / FOCAL_PX, (2, 2))
            if rng.random() < outliers:
                p[0] += rng.uniform(20, 40) / FOCAL_PX * np.sign(rng.normal(size=2))
            frame.append(f)
            camera.append(c)
            xy.append(p)
    xy = np.array(xy)
    return WandPairs(np.array(frame), np.array(camera), xy, xy * FOCAL_PX, np.arange(WAND_FRAMES) * 3), ends


def _named(wand: tuple[WandPairs, np.ndarray], R, t) -> list[dict]:
    """The faults rejected_moved names, the wand's true ends standing for the solver's (which the
    outlier pass kept free of the rejected views)."""
    labelled, ends = wand
    res = observation_residuals(R, t, labelled, None, np.full((len(R), 2), FOCAL_PX), (labelled.frames, ends))
    return rejected_moved([f"cam{k}" for k in range(len(R))], res, R, t)


@pytest.mark.parametrize("camera, at", [(1, 20), (3, 40)])
def test_a_camera_whose_later_views_are_all_rejected_is_named_at_its_frame(camera, at):
    R, t = _rig()
    rng = np.random.default_rng(40 + camera)
    axis = rng.normal(size=3)
    knock = (camera, at, np.radians(5.0) * axis / np.linalg.norm(axis))
    found = _named(_wand(R, t, rng, knock, outliers=0.02), R, t)
    assert [f["camera"] for f in found] == [f"cam{camera}"]
    ev = found[0]["evidence"]
    assert ev["frame"] == 3 * at and ev["p_value"] < STEP_ALPHA


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_gross_outliers_spread_in_time_name_nothing(seed):
    R, t = _rig()
    rng = np.random.default_rng(seed)
    assert _named(_wand(R, t, rng, outliers=0.1), R, t) == []


def test_a_rig_of_three_names_nothing_from_its_rejects():
    """With three cameras the outlier pass may reject the unmoved camera of a pair: the rejects
    do not say which camera moved, and nothing is named from them."""
    R, t = _rig(3)
    rng = np.random.default_rng(7)
    axis = rng.normal(size=3)
    wand = _wand(R, t, rng, (1, 20, np.radians(5.0) * axis / np.linalg.norm(axis)))
    assert _named(wand, R, t) == []


PAIRS = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]  # each wand frame seen by two cameras, in turn


def _in_pairs(wand: tuple[WandPairs, np.ndarray]) -> tuple[WandPairs, np.ndarray]:
    """The wand with each frame kept in one pair of cameras only (Brown's sparse sessions): the
    other cameras never place a frame without the one judged, so only its partners' rays test it."""
    labelled, ends = wand
    pair = np.array(PAIRS)[labelled.frame % len(PAIRS)]
    return labelled.subset((pair == labelled.camera[:, None]).any(axis=1)), ends


def test_a_knocked_camera_seen_in_pairs_is_named_by_its_turn_against_its_partners():
    """Camera 1 turned 2 degrees for the last 6 frames (three of its camera-frames, each with
    another partner): three rejects are too few for the count's level (q^3 times the blocks), but
    one turn of it brings them back to its partners' rays, far beyond its own scatter before (the
    F test of turn_against_partners)."""
    R, t = _rig()
    rng = np.random.default_rng(5)
    axis = rng.normal(size=3)
    found = _named(_in_pairs(_wand(R, t, rng, (1, 53, np.radians(2.0) * axis / np.linalg.norm(axis)))), R, t)
    assert [f["camera"] for f in found] == ["cam1"]
    ev = found[0]["evidence"]
    assert ev["turn_against_partners"] and ev["p_value"] < STEP_ALPHA and 3 * 52 <= ev["frame"] < 3 * 54  # its last camera-frame before the knock


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_gross_outliers_in_a_rig_seen_in_pairs_name_nothing(seed):
    R, t = _rig()
    rng = np.random.default_rng(seed)
    assert _named(_in_pairs(_wand(R, t, rng, outliers=0.1)), R, t) == []


def _run_and_lens(wand: tuple[WandPairs, np.ndarray], R, t, camera: int) -> tuple[float, bool]:
    """(camera's rejected-run p-value, whether the lens fitted outside its block predicts the block)."""
    labelled, ends = wand
    res = observation_residuals(R, t, labelled, None, np.full((len(R), 2), FOCAL_PX), (labelled.frames, ends))
    found = camera_runs(res, len(R))[camera]
    assert found is not None
    return found[0].p_value, lens_predicts_block(res, R, t, camera, *found)


@pytest.mark.parametrize("camera, scale, seed", [(0, 0.99, 0), (1, 0.99, 0), (2, 0.99, 0)])
def test_rejects_that_grow_with_where_the_wand_went_are_the_lens_not_a_move(camera, scale, seed):
    """A focal length 1% off puts the views far from the image centre beyond the limit; the wand
    moving outwards in time bunches them late, a run in time as strong as a knock's. The lens fitted
    to the frames before the block alone predicts the block (decision 0100's open row): not moved."""
    R, t = _rig()
    wand = _wand(R, t, np.random.default_rng(seed), lens=(camera, scale))
    p, lens = _run_and_lens(wand, R, t, camera)
    assert p < STEP_ALPHA and lens
    assert _named(wand, R, t) == []


@pytest.mark.parametrize("degrees, seed", [(5.0, 41), (1.0, 42)])
def test_a_knocks_block_is_not_predicted_by_the_lens_before_it(degrees, seed):
    """The knock's later views: the pose, focal length and k1 fitted to the frames before it leave
    the block turned (a change in time), so the camera is still named moved."""
    R, t = _rig()
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    wand = _wand(R, t, rng, (1, 50, np.radians(degrees) * axis / np.linalg.norm(axis)))
    p, lens = _run_and_lens(wand, R, t, 1)
    assert p < STEP_ALPHA and not lens
    assert [f["camera"] for f in _named(wand, R, t)] == ["cam1"]


def test_the_lens_is_not_fitted_to_fewer_frames_than_it_can_hold():
    """Where fewer than MIN_LENS_FRAMES camera-frames lie outside the block, the lens is not trusted
    to predict it (eight columns over a handful of frames absorb a knock): the move stands."""
    R, t = _rig()
    rng = np.random.default_rng(41)
    axis = rng.normal(size=3)
    at = MIN_LENS_FRAMES // 2
    wand = _wand(R, t, rng, (1, at, np.radians(5.0) * axis / np.linalg.norm(axis)))
    p, lens = _run_and_lens(wand, R, t, 1)
    assert p < STEP_ALPHA and not lens
    assert [f["camera"] for f in _named(wand, R, t)] == ["cam1"]
