"""A start refused because a camera is out of time names the camera and its shift
(calib/judge/faults/start_timing.py), on simulated captures whose offsets are known."""

from __future__ import annotations

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.faults.start_timing import out_of_time_refusal, resampled
from wandcal.calib.observations import WandPairs, wand_pairs
from wandcal.calib.sim.simulate import simulate_capture

NOISE_PX = 0.3


def _linear_pairs(frames: int = 12) -> WandPairs:
    """Two cameras' pairs on a linear track: end 0 moves 0.01 a frame in x, end 1 0.02 in y
    (normalised units), the second camera's ends in the other order."""
    k = np.arange(frames, dtype=float)
    ends = np.stack([np.stack([0.01 * k, np.zeros(frames)], 1), np.stack([np.full(frames, 0.5), 0.02 * k], 1)], 1)
    xy = np.concatenate([ends, ends[:, ::-1]])
    camera = np.repeat([0, 1], frames)
    frame = np.tile(np.arange(frames), 2)
    order = np.lexsort((camera, frame))
    return WandPairs(frame[order], camera[order], xy[order], 100 * xy[order], np.arange(frames, dtype=np.int64))


@pytest.mark.parametrize("shift", [0.25, -0.5, 2.0, -1.0])
def test_resampling_a_linear_track_puts_each_end_where_it_was_then(shift):
    pairs = _linear_pairs()
    moved = resampled(pairs, 1, shift)
    mine = moved.camera == 1
    k = moved.frames[moved.frame[mine]].astype(float)
    # camera 1 at frame k shows its own time k + shift; a linear track interpolates exactly
    np.testing.assert_allclose(moved.xy[mine, 1, 0], 0.01 * (k + shift), atol=1e-12)
    np.testing.assert_allclose(moved.xy[mine, 0, 1], 0.02 * (k + shift), atol=1e-12)
    assert len(k) == 12 - int(np.ceil(abs(shift)))  # only the frames past the recording's end are lost
    other = moved.camera == 0
    np.testing.assert_array_equal(moved.xy[other], pairs.xy[pairs.camera == 0])


@pytest.mark.parametrize("drift", [1.0, -0.5])
def test_resampling_with_a_drift_shifts_each_frame_in_proportion_through_the_cameras_frames(drift):
    pairs = _linear_pairs()
    moved = resampled(pairs, 1, 0.0, drift)
    mine = moved.camera == 1
    k = moved.frames[moved.frame[mine]].astype(float)
    here = k + drift * k / 11  # its frames are 0..11: 0 at the first, ``drift`` at the last
    np.testing.assert_allclose(moved.xy[mine, 1, 0], 0.01 * here, atol=1e-12)
    np.testing.assert_allclose(moved.xy[mine, 0, 1], 0.02 * here, atol=1e-12)
    assert np.all((here >= 0) & (here <= 11))  # only samples with both neighbours are kept


@pytest.mark.parametrize("offset", [2, -1])
def test_a_camera_whole_frames_out_of_time_is_named_with_its_shift(offset):
    offsets = np.zeros(4)
    offsets[2] = offset  # docs/result-format.md: its frame k shows the wand at the others' k + offset
    sim = simulate_capture(4, 300, NOISE_PX, static=False, seed=5, offsets=offsets)
    refused = CalibrationError("camera 'cam2' cannot be placed")
    found = out_of_time_refusal(refused, sim.rig, wand_pairs(sim.rig, sim.wand), None, None)
    cam = sim.rig.cameras[2].id
    message = str(found)
    assert message.startswith(f"{cam} is out of time"), message
    assert f"offset {offset:+d}" in message and ("late" if offset > 0 else "early") in message
    assert "--sync auto" in message and message.endswith(str(refused))  # the start's own reason kept


def test_a_refusal_of_cameras_in_time_is_left_as_it_was():
    sim = simulate_capture(4, 300, NOISE_PX, static=False, seed=5)
    refused = CalibrationError("camera 'cam2' cannot be placed")
    assert out_of_time_refusal(refused, sim.rig, wand_pairs(sim.rig, sim.wand), None, None) is refused


def test_a_camera_whose_clock_drifts_is_named_where_only_the_drift_places_it(monkeypatch):
    # the start places every camera only with camera 2's samples resampled by an offset growing to +1
    # frame (as if it ran 1 frame early by its last): the refusal names it, with --sync auto
    import wandcal.calib.judge.faults.start_timing as st

    sim = simulate_capture(4, 300, NOISE_PX, static=False, seed=5)
    monkeypatch.setattr(st, "whole_frame_shifts", lambda *a: {})
    monkeypatch.setattr(st, "fractional_shift", lambda *a: None)
    monkeypatch.setattr(st, "resampled", lambda pairs, c, shift, drift=0.0: (c, shift, drift))
    monkeypatch.setattr(st, "_places", lambda rig, tried, static_poses, tracks: tried == (2, 0.0, 1.0))
    refused = st.UnplacedCamera("camera 'cam2' cannot be placed", 2)
    message = str(st.out_of_time_refusal(refused, sim.rig, wand_pairs(sim.rig, sim.wand), None, None))
    cam = sim.rig.cameras[2].id
    assert message.startswith(f"{cam} is out of time") and "1 frame early at its last" in message, message
    assert "offset -1 at its last frame" in message and "--sync auto" in message and message.endswith(str(refused))


def test_a_drift_that_places_the_camera_either_way_names_nothing(monkeypatch):
    import wandcal.calib.judge.faults.start_timing as st

    sim = simulate_capture(4, 300, NOISE_PX, static=False, seed=5)
    monkeypatch.setattr(st, "whole_frame_shifts", lambda *a: {})
    monkeypatch.setattr(st, "fractional_shift", lambda *a: None)
    monkeypatch.setattr(st, "_places", lambda *a: True)
    refused = st.UnplacedCamera("camera 'cam2' cannot be placed", 2)
    assert st.out_of_time_refusal(refused, sim.rig, wand_pairs(sim.rig, sim.wand), None, None) is refused
