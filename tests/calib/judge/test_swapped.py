"""Two cameras whose observations are swapped (calib/judge/faults/swapped.py), on a simulated rig of
four cameras whose intrinsics differ as real ones do (focal lengths a few per cent apart, principal
points tens of pixels apart)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from wandcal.calib.judge.faults.swapped import Gain, block_gain, swap_faults, swapped_pair
from wandcal.calib.observations import wand_pairs
from wandcal.calib.run.rig_faults import _solved_again
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.labels import label_ends

NOISE_PX = 0.3  # per axis, injected
# each camera's true intrinsics as factors of the simulator's focal length and shifts of its
# principal point (pixels): Brown 2's four cameras span 1671-1736 px and 47 px in cy
FOCAL = (1.00, 1.04, 0.97, 1.02)
CENTRE = ((0.0, 0.0), (25.0, -30.0), (-20.0, 35.0), (10.0, 15.0))


def _rig_of_different_lenses():
    """A simulated capture whose cameras have the intrinsics above: each camera's blobs moved from
    the simulator's K to its own (the same normalised coordinates, so the same rays)."""
    sim = simulate_capture(4, 400, NOISE_PX, 0.0, False, 5)
    cams, uv = list(sim.rig.cameras), sim.wand.uv.copy()
    for c, cam in enumerate(sim.rig.cameras):
        K = cam.K.copy()
        K[0, 0] *= FOCAL[c]
        K[1, 1] *= FOCAL[c]
        K[:2, 2] += CENTRE[c]
        mine = sim.wand.camera == c
        h = np.c_[uv[mine], np.ones(mine.sum())] @ np.linalg.inv(cam.K).T @ K.T
        uv[mine] = h[:, :2] / h[:, 2:]
        cams[c] = replace(cam, K=K)
    # the simulator's noise is per axis at its own focal length: scaled with it, within 4%
    return replace(sim, rig=replace(sim.rig, cameras=tuple(cams)), wand=replace(sim.wand, uv=uv))


def _given(sim, rig):
    """The wand pairs normalised with ``rig`` (the intrinsics given), labelled, and the rig solved
    with them from the truth (the solve a mislabelled capture gives)."""
    R, t = sim.truth.R, sim.truth.t
    pairs = label_ends(R, t, wand_pairs(rig, sim.wand), np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    R2, t2 = _solved_again(rig, pairs, None, R, t)
    return pairs, R2, t2


def _exchanged(rig, a, b):
    cams = list(rig.cameras)
    cams[a], cams[b] = replace(cams[a], K=rig.cameras[b].K), replace(cams[b], K=rig.cameras[a].K)
    return replace(rig, cameras=tuple(cams))


@pytest.fixture(scope="module")
def sim():
    return _rig_of_different_lenses()


def test_no_pair_is_named_on_a_clean_rig(sim):
    pairs, R, t = _given(sim, sim.rig)
    assert swap_faults(sim.rig, pairs, None, R, t, _solved_again) == []


def test_two_cameras_given_each_others_intrinsics_are_named_swapped(sim):
    """cam2's and cam3's intrinsics exchanged in rig.json: the same as their columns exchanged (the
    poses follow the observations). Both are named, and with the exchange undone the rig fits to
    the others' intrinsics better."""
    rig = _exchanged(sim.rig, 1, 2)
    pairs, R, t = _given(sim, rig)
    faults = swap_faults(rig, pairs, None, R, t, _solved_again)
    assert sorted((f["kind"], f["camera"]) for f in faults) == [("intrinsics", rig.cameras[1].id),
                                                              ("intrinsics", rig.cameras[2].id)]
    assert "look swapped" in faults[0]["message"]
    found = swapped_pair(rig, pairs, None, R, t, _solved_again)
    assert found.rig.p < 1e-4 and found.own_a.mean_px2 > 0 and found.own_b.mean_px2 > 0
    # the given intrinsics put both cameras past the rig's noise (a reprojection's 2D RMS is under
    # sqrt(2) times its per-axis sigma); exchanged, both fit better
    assert min(found.rms_given_px) > np.sqrt(2) * NOISE_PX * max(FOCAL)
    assert all(e < g for e, g in zip(found.rms_exchanged_px, found.rms_given_px))


def test_one_cameras_wrong_focal_length_is_not_a_swap(sim):
    """cam1's focal length given 8% high, with cam4's (2% above cam1's truth) between its truth and
    what is given: the exchange brings cam1 nearer its truth, but cam4 then fits its images with
    cam1's wrong focal length, and its own gain is negative. No swap."""
    cams = list(sim.rig.cameras)
    K = cams[0].K.copy()
    K[0, 0] *= 1.08
    K[1, 1] *= 1.08
    cams[0] = replace(cams[0], K=K)
    rig = replace(sim.rig, cameras=tuple(cams))
    pairs, R, t = _given(sim, rig)
    assert swap_faults(rig, pairs, None, R, t, _solved_again) == []


def test_the_block_jackknife_error_of_a_mean_is_the_usual_one_on_independent_blocks():
    """On independent rows in G blocks the delete-a-block jackknife's standard error of a mean is
    the rows' sigma over sqrt(n), within its own sampling error (a relative ~1/sqrt(2 (G - 1)))."""
    rng = np.random.default_rng(1)
    g = rng.normal(0.0, 2.0, 4000)
    block = np.arange(4000) // 100  # G = 40
    gain = block_gain(g, block)
    assert gain.blocks == 40 and gain.observations == 4000
    assert abs(gain.std_px2 / (2.0 / np.sqrt(4000)) - 1) < 3 / np.sqrt(2 * 39)


def test_a_negative_gain_never_passes():
    assert Gain(-1.0, 0.01, 30, 300).p == 1.0
    assert Gain(1.0, 0.1, 30, 300).p < 1e-6  # t = 10 on 29 degrees of freedom


@pytest.mark.shared_data
def test_multicamselfcals_two_cameras_swapped_are_named_and_its_clean_run_is_not():
    """MultiCamSelfCal's Basler_21275577 and Basler_21283677 (focal lengths 3% and principal points
    29 px apart) swapped: before, "good" with nothing named; both named now, and nothing on the
    clean session (decision 0078)."""
    from bench import held_out_faults as ho
    from bench import real_faults as rf

    if not rf.available():
        pytest.skip(f"third-party data not found at {rf.SHARED_DATA}")
    session = rf.LOADERS["svoboda"]()
    clean = rf.clean_run(session)
    assert not any(kind == "intrinsics" for kind, _ in clean.faults)
    case = next(c for c in ho.held_out_cases(session) if c.family == "swapped")
    out = ho.run_held_out_case(session, clean, case)
    ids = {session.rig.cameras[case.camera].id, session.rig.cameras[int(case.size)].id}
    assert set(out.named) == {("intrinsics", cam) for cam in ids}, rf.case_line(out)
    assert "look swapped" in out.message


def test_a_camera_seen_through_another_lens_keeps_the_points_the_others_triangulate(sim):
    """The swap screen reads camera c through another camera's lens against c's own held-out points
    (leave_one_out.seen_again, issue 31's cost): the very numbers held_out_views gives when it
    triangulates the others' views again, since they do not change."""
    from wandcal.calib.judge.faults.leave_one_out import held_out_views, seen_again
    from wandcal.calib.judge.faults.swapped import _seen_through

    rig = sim.rig
    pairs, R, t = _given(sim, rig)
    for c, d in ((0, 1), (2, 3)):
        lab, tracks = _seen_through(pairs, None, c, rig.cameras[d])
        again, shared = held_out_views(R, t, lab, tracks, c), seen_again(held_out_views(R, t, pairs, None, c), lab, tracks)
        assert len(again.X) > 100 and not np.array_equal(again.xy, held_out_views(R, t, pairs, None, c).xy)
        for name in ("X", "xy", "frame", "timed"):
            assert np.array_equal(getattr(again, name), getattr(shared, name)), name
