"""Replaying an image-level capture: frames as recorded, pacing, and a corrupt PNG."""

import cv2
import numpy as np
import pytest

from wandcal.capture.recording.session import record
from wandcal.drivers.errors import DriverError, FrameError
from wandcal.drivers.registry import open_cameras

pytestmark = pytest.mark.usefixtures("patient_stall_limit")  # in-process recordings on a loaded box


@pytest.fixture
def recorded(tmp_path):
    cams = open_cameras("sim://?cameras=2&seed=4&frames=12&drop=cam2:5")
    record(cams, None, tmp_path / "cap", cams[0].scene.rig, frames=12, rate_hz=50)
    return tmp_path / "cap"


def drain(cam):
    frames, errors = [], []
    with cam:
        while True:
            try:
                f = cam.read()
            except FrameError as exc:
                errors.append(exc)
                continue
            if f is None:
                return frames, errors
            frames.append(f)


def test_replay_gives_the_recorded_frames_and_gaps(recorded):
    cam1, cam2 = open_cameras(f"replay://{recorded}")
    frames, errors = drain(cam2)
    assert not errors and [f.sequence for f in frames] == [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]
    stored = cv2.imread(str(recorded / "frames/cam2/000006.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(frames[5].image, stored)
    assert cam1.intrinsics is not None and cam1.intrinsics.width == 1280


def test_corrupt_png_names_camera_and_file_and_the_rest_is_replayed(recorded):
    bad = recorded / "frames/cam1/000003.png"
    bad.write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    cam1, _ = open_cameras(f"replay://{recorded}?cameras=cam1,cam2")
    frames, errors = drain(cam1)
    assert len(errors) == 1 and errors[0].sequence == 3
    assert "camera cam1" in str(errors[0]) and str(bad) in str(errors[0])
    assert [f.sequence for f in frames] == [0, 1, 2, *range(4, 12)]


def test_recorded_rate_pacing_uses_the_timestamps(recorded):
    (cam,) = open_cameras(f"replay://{recorded}?rate=recorded&cameras=cam1")
    now, slept = [0.0], []

    def sleep(dt):
        slept.append(dt)
        now[0] += dt

    cam._clock, cam._sleep = (lambda: now[0]), sleep
    frames, _ = drain(cam)
    gaps = np.diff([f.timestamp_us for f in frames]) / 1e6
    assert len(slept) == len(frames) - 1
    np.testing.assert_allclose(slept, gaps, rtol=1e-6)  # 1/50 s apart on the camera clock


def test_replay_of_a_missing_folder_or_bad_option(tmp_path, recorded):
    with pytest.raises(DriverError, match="not a folder"):
        open_cameras(f"replay://{tmp_path}/nope")
    with pytest.raises(DriverError, match="rate must be"):
        open_cameras(f"replay://{recorded}?rate=fast")
