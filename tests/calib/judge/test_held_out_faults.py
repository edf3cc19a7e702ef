"""The held-out faults' injectors (bench/held_out_faults.py), on a made-up track: each makes the
fault its table says, and nothing else. The suite itself is ``python bench/bench_real_faults.py
--held-out``."""

from __future__ import annotations

import numpy as np
import pytest

from bench import held_out_faults as ho
from bench import real_faults as rf


def _track_session(n_frames: int = 20) -> rf.Session:
    """Two cameras, each a wand of two ends a frame: end 0 moves 3 px a frame right, end 1 2 px a
    frame down, so a sample's time reads off its position exactly."""
    from wandcal.calib.rig import Camera, Rig, WandObservations

    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    cams = tuple(Camera(f"cam{k}", 640, 480, K, np.zeros(5)) for k in range(2))
    frame = np.repeat(np.arange(n_frames), 4)
    camera = np.tile([0, 0, 1, 1], n_frames)
    end = np.tile([0, 1], 2 * n_frames)
    uv = np.where(end[:, None] == 0, np.stack([100 + 3.0 * frame, np.full(len(frame), 100.0)], 1),
                  np.stack([np.full(len(frame), 300.0), 200 + 2.0 * frame], 1))
    return rf.Session("track", Rig(cams, 0.5), WandObservations(frame, camera, uv), None, None, (0, 1))


def test_a_slow_clock_drifts_from_in_time_to_its_offset_at_the_end():
    session = _track_session()
    drifted = ho.slow_clock(session, 0, 1.0).wand
    mine = drifted.camera == 0
    frame, uv = drifted.frame[mine], drifted.uv[mine]
    # its frame k exposed at k + k/19 (0 at the first frame, 1 at the last): on the linear track
    # each blob sits where it was then; the last frame, past the track, is left out
    time = frame + frame / 19.0
    ends = uv[:, 1] == 100.0
    np.testing.assert_allclose(uv[ends, 0], 100 + 3.0 * time[ends], atol=1e-9)
    np.testing.assert_allclose(uv[~ends, 1], 200 + 2.0 * time[~ends], atol=1e-9)
    assert set(frame.tolist()) == set(range(19))
    np.testing.assert_array_equal(drifted.uv[drifted.camera == 1], session.wand.uv[session.wand.camera == 1])


def test_a_dropped_block_takes_the_middle_of_one_cameras_frames_only():
    session = _track_session()
    dropped = ho.dropped_block(session, 0, 0.3).wand
    kept = set(dropped.frame[dropped.camera == 0].tolist())
    gone = set(range(20)) - kept
    assert gone == set(range(7, 14))  # 30% of 20 frames and the one at the block's end, in the middle
    assert np.sum(dropped.camera == 1) == np.sum(session.wand.camera == 1)


def test_a_swap_exchanges_the_two_cameras_observations():
    session = _track_session()
    swapped = ho.swapped(session, 0, 1).wand
    np.testing.assert_array_equal(swapped.uv[swapped.camera == 0], session.wand.uv[session.wand.camera == 1])
    np.testing.assert_array_equal(swapped.uv[swapped.camera == 1], session.wand.uv[session.wand.camera == 0])
    assert ho.same_intrinsics(session, 0, 1)  # two alike cameras: a swap the data cannot tell
    assert not ho.same_intrinsics(ho.with_fy(session, 1, 1.03), 0, 1)


@pytest.mark.parametrize("inject, changed", [
    (lambda s: ho.without_k2(s, 0), lambda cam: cam.dist[1] == ho.K2_WHERE_NONE),
    (lambda s: ho.with_tangential(s, 0), lambda cam: np.all(cam.dist[2:4] == ho.TANGENTIAL)),
    (lambda s: ho.with_fy(s, 0), lambda cam: cam.K[1, 1] == 1030.0 and cam.K[0, 0] == 1000.0),
    (lambda s: ho.with_principal_y(s, 0), lambda cam: cam.K[1, 2] == 240 + 0.02 * 640 and cam.K[0, 2] == 320),
])
def test_the_intrinsics_faults_change_one_cameras_rig_json_only(inject, changed):
    session = _track_session()
    broken = inject(session)
    assert changed(broken.rig.cameras[0])
    assert broken.rig.cameras[1] is session.rig.cameras[1] and broken.wand is session.wand


def test_every_held_out_case_is_made_and_labelled_once():
    session = _track_session()
    cases = ho.held_out_cases(session)
    assert len({c.label for c in cases}) == len(cases)
    assert {c.family for c in cases} == set(ho.HELD_OUT_FAMILIES)
    for case in cases:
        assert ho.inject_held_out(session, case, [0.5, 0.5]) is not session


# -- a few held-out cases on the real sessions (the whole table: bench_real_faults.py --held-out) --

@pytest.fixture(scope="module")
def sessions():
    if not rf.available():
        pytest.skip(f"third-party data not found at {rf.SHARED_DATA}")
    loaded = {}
    for key in ("brown1", "brown2", "cpp"):
        session = rf.LOADERS[key]()
        loaded[key] = (session, rf.clean_run(session))
    return loaded



def test_a_swap_carries_the_clean_runs_own_faults_to_the_partners_name():
    # the published data's own fault (a camera out of time) is in its observations: swapped, it is
    # the partner's name that carries it, and naming it there is not a fault on another camera
    session = _track_session()
    clean = rf.Clean(np.zeros((2, 3)), [1.0, 1.0], "poor", frozenset({("timing", "cam1"), ("noise", None)}))
    moved = ho.swapped_clean(session, clean, 0, 1)
    assert moved.faults == frozenset({("timing", "cam0"), ("noise", None)})
    assert ho.swapped_clean(session, moved, 1, 0).faults == clean.faults


HELD_OUT_CASES = [
    ("brown2", "fy +3% cam3"),  # fy alone: the lens pattern's aspect column keeps it on its camera (not cam4)
    ("brown2", "fy +3% cam4"),  # ... not "outliers, cam1", the session's weakest camera
    ("brown1", "clock slow to 1 frame cam1"),  # an offset growing through the capture: timing
    ("brown1", "middle 30% of frames dropped cam3"),  # frames lost are no fault: nothing named, not poorer
    ("brown1", "cam1 and cam3 swapped"),  # mislabelled cameras of different intrinsics: named on one of them
    ("brown2", "noise 2x cam3"),  # 1.39 +- 0.12 times the others': at the limit, the camera named
    ("cpp", "clock slow to 1 frame cam1"),  # the start refused: the camera named with its drift, --sync auto
    ("brown1", "k2 off cam3"),  # limited: k2 named as what its position hinges on, within 3 honest sigma (0070)
    ("brown2", "principal point y +2% cam4"),  # limited: cy's part 0.39 mm, material against a 0.42 mm sigma (0086)
]


@pytest.mark.shared_data
@pytest.mark.parametrize("key, label", HELD_OUT_CASES)
def test_the_verdict_on_a_held_out_fault(sessions, key, label):
    session, clean = sessions[key]
    case = next(c for c in ho.held_out_cases(session) if c.label == label)
    out = ho.run_held_out_case(session, clean, case)
    assert out.right, rf.case_line(out)
