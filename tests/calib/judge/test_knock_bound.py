"""The turn a camera's step test can name (calib/judge/faults/pose_steps.py, decision 0083):
the F distribution's critical value, the bound's arithmetic, and on a seeded rig a step is named
exactly when its turn passes the bound the test gives it (the F is the turn's Wald statistic)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.calib.judge.test_own_errors import _rig, _tracks
from wandcal.calib.judge.faults import own_errors as oe
from wandcal.calib.judge.faults.f_distribution import critical_f, f_survival
from wandcal.calib.judge.faults.pose_steps import STEP_ALPHA, Step, detectable_turn, pose_step
from wandcal.calib.observations import WandPairs


@pytest.mark.parametrize("dof, alpha, table", [(3, 0.05, 9.28), (10, 0.01, 6.55), (30, 0.05, 2.92), (120, 0.01, 3.95)])
def test_the_critical_f_is_the_tables(dof, alpha, table):
    """Upper points of F(3, dof) as printed in the standard tables (two decimals)."""
    assert critical_f(3, dof, alpha) == pytest.approx(table, abs=0.006)
    assert f_survival(3, dof, critical_f(3, dof, alpha)) == pytest.approx(alpha, rel=1e-6)


def test_a_turn_at_the_bound_scores_the_critical_f():
    """theta = sqrt(3 F* / a^T C^-1 a): the Wald statistic of that turn over three is F*, about any
    axis; the bound is larger about the less certain axis."""
    cov = np.diag([0.01, 0.04, 0.25])  # deg^2: the third axis five times less certain than the first
    f_crit = critical_f(3, 8, STEP_ALPHA / 20)
    for axis in (np.array([1.0, 0, 0]), np.array([0, 0, 2.0]), np.array([1.0, -1.0, 0.5])):
        theta = detectable_turn(cov, axis, f_crit)
        w = theta * axis / np.linalg.norm(axis)
        assert float(w @ np.linalg.inv(cov) @ w) / 3 == pytest.approx(f_crit, rel=1e-9)
    assert detectable_turn(cov, np.array([0, 0, 1.0]), f_crit) == pytest.approx(5 * detectable_turn(cov, np.array([1.0, 0, 0]), f_crit))
    assert np.isnan(detectable_turn(None, np.ones(3), f_crit))
    assert np.isnan(Step(1, 0, 0, 0, 0, 1, 0.5, 0.1).detectable_deg)  # a step recorded without its covariance


@pytest.mark.parametrize("seed, degrees", [(1, 0.0), (1, 0.1), (2, 0.03), (2, 0.3), (3, 0.1)])
def test_a_step_is_named_exactly_when_it_passes_its_bound(seed, degrees):
    """A marker track seen by four cameras at 0.5 px (f = 1000 px), camera 1 turned after frame
    250: the step's p is under STEP_ALPHA exactly when its turn is above the bound about its own
    axis (the step's F is its turn's Wald statistic over three), whatever the knock's size."""
    R, t = _rig()
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    tracks = _tracks(R, t, rng, knock=(1, 250, np.radians(degrees) * axis / np.linalg.norm(axis)))
    step = pose_step(oe.eliminate(R, t, oe.views_of(WandPairs.empty(), tracks)), 1)
    assert step is not None and step.splits > 0
    # the F of the turn as estimated, scaled to the bound, is the critical F (to the rounding of the solves)
    assert step.f_stat * (step.detectable_deg / step.degrees) ** 2 == pytest.approx(step.critical_f, rel=1e-3)
    assert (step.p_value < STEP_ALPHA) == (step.degrees > step.detectable_deg)
    # and the knock's own axis: a turn well above its bound is named (noise moves F by ~ its sqrt(2 x 3) / 3)
    if degrees > 2 * step.detectable_along(axis):
        assert step.p_value < STEP_ALPHA


def test_the_benchs_knock_is_placed_among_the_frames_another_camera_shares():
    """bench/bench_knock_bound.py knocks after a share of the camera's *shared* frames (those a
    calibration can use), as bench/fault_injectors.knocked does at their middle (decision 0067)."""
    from types import SimpleNamespace

    from bench.bench_knock_bound import knock_at

    # camera 0 sees frames 0-9 alone and 10-19 with camera 1
    frame = np.r_[np.arange(20), np.arange(10, 20)]
    camera = np.r_[np.zeros(20, int), np.ones(10, int)]
    obs = SimpleNamespace(frame=frame, camera=camera)
    assert knock_at(obs, 0, 0.35) == 13.5  # the 4th of its 10 shared frames, 10-19
    assert knock_at(obs, 0, 0.0) == 10.5
    assert knock_at(obs, 1, 0.5) == 15.5
