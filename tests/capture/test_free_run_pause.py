"""The pause after the static sets with free-running cameras (no trigger): the cameras are drained
while the L-frame leaves the volume, no frame shot during the pause enters a set, and the wand run
starts with the first frame every camera takes after it (decision 0040's amendment)."""

from __future__ import annotations

import csv
import time

import numpy as np
import pytest

from wandcal.capture.recording.session import record
from wandcal.drivers.camera import CameraDriver
from wandcal.drivers.registry import open_cameras
from wandcal.drivers.sim import SimCamera

STATIC, FRAMES, RATE_HZ = 5, 40, 200.0
PAUSE_S = 0.5  # the operator's pause: 100 frame periods at 200 Hz
PERIOD_US = 1e6 / RATE_HZ

pytestmark = pytest.mark.usefixtures("patient_stall_limit")


class _StreamingCamera(SimCamera):
    """A simulated camera that drains as a real one does: each discarded grab spends a frame of
    its sequence (and of its script, so the URL gives it a script long enough for the pause)."""

    _discard = CameraDriver._discard


def _sequences(cams, folder) -> np.ndarray:
    """(sets, cameras) the frame period behind each recorded wand set's timestamp: a simulated
    free-running camera stamps frame s at its clock's origin + s periods, + the periods its scene
    held (each camera's own count: free-running clocks share no origin)."""
    with open(folder / "sync.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    stamps = np.array([[float(r[f"{c.camera_id}_ts"]) for c in cams] for r in rows])
    origin = np.array([c._clock_offset_us for c in cams])
    scale = np.array([c._clock_scale for c in cams])
    return (stamps - origin) / scale / PERIOD_US


def _record(cams, out, between):
    rig = cams[0].scene.rig
    return record(cams, None, out, rig, frames=FRAMES, static_frames=STATIC, rate_hz=RATE_HZ, between=between)


def test_the_simulator_holds_its_script_through_the_pause(tmp_path):
    cams = open_cameras("sim://?cameras=3&seed=2")
    waited = []
    result = _record(cams, tmp_path / "cap", lambda: waited.append(time.sleep(PAUSE_S)))
    assert waited and result.error is None
    assert (result.static_sets, result.frame_sets, result.complete_sets) == (STATIC, FRAMES, STATIC + FRAMES)
    seq = _sequences(cams, tmp_path / "cap")
    # the scene held: the wand's first frame comes after the pause's time (the camera's clock ran on
    # at its rate, a frame behind at most), and all of the script's wand frames are kept
    first = seq[0] - STATIC
    assert np.all(first >= PAUSE_S * RATE_HZ - 1), first
    assert np.allclose(np.diff(seq, axis=0), 1.0, atol=0.01)  # no set lost, none doubled


def test_frames_shot_during_the_pause_enter_no_set(tmp_path):
    # cameras whose every grab spends a frame, as real ones do: the pause drains ~100 frames each
    scene_frames = FRAMES + 4 * int(PAUSE_S * RATE_HZ)
    cams = [_StreamingCamera(c.camera_id, c.url, c.scene, c.index)
            for c in open_cameras(f"sim://?cameras=3&seed=2&frames={scene_frames}")]
    result = _record(cams, tmp_path / "cap", lambda: time.sleep(PAUSE_S))
    assert result.error is None and (result.static_sets, result.frame_sets) == (STATIC, FRAMES)
    assert result.complete_sets == STATIC + FRAMES
    seq = _sequences(cams, tmp_path / "cap")
    drained = seq[0] - STATIC
    assert np.all(drained >= 1), drained  # how many a loaded machine renders in the pause varies
    assert np.ptp(seq[0]) < 0.01 and np.allclose(np.diff(seq, axis=0), 1.0, atol=0.01)
    assert all(s["missed"] == 0 for s in result.per_camera.values()), result.per_camera


def test_no_pause_records_the_wand_right_after_the_static_sets(tmp_path):
    cams = open_cameras("sim://?cameras=2&seed=4")
    result = _record(cams, tmp_path / "cap", None)
    assert result.error is None and result.frame_sets == FRAMES
    assert np.allclose(_sequences(cams, tmp_path / "cap")[0], STATIC, atol=0.01)


def test_a_starved_reader_still_sees_the_clock_run_through_the_pause():
    # a busy host drains a camera only a few times in the pause: the first wand frame still carries the
    # time its free-running clock reached, not a period per grab (a CI run drained 13 of 100, session 23)
    now = [0.0]
    base = open_cameras("sim://?cameras=2&seed=3")[0]
    cam = SimCamera(base.camera_id, base.url, base.scene, base.index, clock=lambda: now[0],
                    sleep=lambda s: now.__setitem__(0, now[0] + s))
    cam.script(STATIC, FRAMES)
    cam.open()
    cam.configure(fps=RATE_HZ)
    stamps = [cam.read(timeout=1.0).timestamp_us for _ in range(STATIC)]
    for _ in range(3):  # three grabs thrown away while the operator takes 0.5 s
        cam.discard(timeout=1.0)
    now[0] += PAUSE_S
    first = cam.read(timeout=1.0)
    assert first.sequence == STATIC  # the scene held
    periods = (first.timestamp_us - stamps[-1]) / cam._clock_scale / PERIOD_US
    assert periods >= PAUSE_S * RATE_HZ, periods
    second = cam.read(timeout=1.0)
    assert second.timestamp_us - first.timestamp_us == pytest.approx(PERIOD_US * cam._clock_scale, abs=1)
