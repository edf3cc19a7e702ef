"""Every camera driver keeps the same contract (parametrized over the implementations)."""

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from wandcal.drivers.camera import CameraSettings, RunState, TriggerMode
from wandcal.drivers.errors import DriverError
from wandcal.drivers.registry import open_cameras


@pytest.fixture(params=["sim", "replay", "opencv"])
def camera(request, tmp_path):
    if request.param == "sim":
        return open_cameras("sim://?cameras=2&frames=5")[0]
    if request.param == "replay":
        for i in range(5):
            (tmp_path / "frames/cam1").mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(tmp_path / f"frames/cam1/{i:06d}.png"), np.full((16, 16), i, np.uint8))
        return open_cameras(f"replay://{tmp_path}")[0]
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"img_{i:06d}.png"), np.full((16, 16), i, np.uint8))
    return open_cameras(f"opencv:{tmp_path}/img_%06d.png")[0]


def test_open_is_reentrant(camera):
    assert camera.state is RunState.CLOSED
    with camera:
        with camera:
            assert camera.read() is not None
        assert camera.state is RunState.OPEN  # the inner exit does not close it
        assert camera.read() is not None
    assert camera.state is RunState.CLOSED
    with pytest.raises(DriverError, match="not open"):
        camera.read()


def test_frames_carry_metadata_and_the_source_ends(camera):
    with camera:
        frames = []
        while (f := camera.read(timeout=1.0)) is not None:
            frames.append(f)
    assert len(frames) == 5
    assert [f.sequence for f in frames] == list(range(5))
    assert all(f.camera_id == camera.camera_id and f.image.ndim == 2 for f in frames)
    assert all(f.image.dtype in (np.uint8, np.uint16) for f in frames)
    assert all(b.timestamp_us > a.timestamp_us for a, b in zip(frames, frames[1:]))


def test_settings_are_validated_and_frozen(camera):
    s = camera.configure(exposure_us=800, gain=2.0)
    assert s.exposure_us == 800 and camera.settings is s
    with pytest.raises(ValidationError):
        s.exposure_us = 100  # frozen
    with pytest.raises(ValidationError):
        CameraSettings(exposure=5)  # unknown field
    with pytest.raises(ValidationError):
        camera.configure(exposure_us=-1)
    with pytest.raises(ValidationError):
        CameraSettings(trigger_mode="sometimes")
    assert CameraSettings(trigger_mode="external").trigger_mode is TriggerMode.EXTERNAL


def test_discard_takes_a_frame_or_holds_a_script_and_the_source_still_ends(camera):
    """A free-running capture's pause drains with ``discard``: a streaming source spends the frame
    (opencv), a scripted one (sim, replay) holds; either way it answers the last sequence number
    taken, the frames after it come in order, and the source ends with None."""
    with pytest.raises(DriverError, match="not open"):
        camera.discard()
    with camera:
        first = camera.read(timeout=1.0)
        taken = camera.discard(timeout=1.0)
        assert taken is not None and taken >= first.sequence
        rest = []
        while (f := camera.read(timeout=1.0)) is not None:
            rest.append(f.sequence)
        assert rest == list(range(taken + 1, 5)) and camera.discard(timeout=1.0) is None
