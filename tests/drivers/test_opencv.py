"""The OpenCV driver through a real cv2.VideoCapture, on a video file and an image sequence that
the test writes (no camera is attached here)."""

import cv2
import numpy as np
import pytest

from wandcal.calib.detect import detect_blobs
from wandcal.calib.sim.render import render_blobs
from wandcal.drivers.camera import TriggerMode
from wandcal.drivers.errors import DriverError
from wandcal.drivers.registry import open_cameras

SHAPE = (120, 160)
N = 12


def spot(i):
    return np.array([40.0 + 6.5 * i, 30.0 + 4.25 * i])


def frames():
    rng = np.random.default_rng(0)
    return [render_blobs(SHAPE, [spot(i)], 2.0, 200.0, 8.0, 1.0, 8, rng) for i in range(N)]


def read_all(cam):
    out = []
    with cam:
        while (f := cam.read(timeout=1.0)) is not None:
            out.append(f)
    return out


def test_image_sequence_is_read_exactly(tmp_path):
    images = frames()
    for i, im in enumerate(images):
        cv2.imwrite(str(tmp_path / f"ir_{i:06d}.png"), im)
    (cam,) = open_cameras(f"opencv:{tmp_path}/ir_%06d.png?id=cam7")
    got = read_all(cam)
    assert cam.camera_id == "cam7" and len(got) == N
    assert [f.sequence for f in got] == list(range(N))
    for f, im in zip(got, images):
        assert f.image.dtype == np.uint8 and f.image.ndim == 2
        np.testing.assert_array_equal(f.image, im)  # PNG is lossless
    assert all(b.timestamp_us > a.timestamp_us for a, b in zip(got, got[1:]))


def test_video_file_frames_timestamps_and_blobs(tmp_path):
    path = tmp_path / "ir.avi"
    fps = 25.0
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, SHAPE[::-1], isColor=False)
    assert writer.isOpened(), "this OpenCV build cannot write MJPG AVI"
    for im in frames():
        writer.write(im)
    writer.release()
    (cam,) = open_cameras(f"opencv:{path}")
    got = read_all(cam)
    assert len(got) == N and cam.camera_id == "ir"
    steps = np.diff([f.timestamp_us for f in got])
    assert np.allclose(steps, 1e6 / fps, atol=1000)  # presentation times of a 25 fps file
    for i, f in enumerate(got):
        blobs = detect_blobs(f.image)
        assert len(blobs) == 1
        # MJPG is lossy; its 8x8 DCT blocks move a smooth spot's centroid by a few hundredths of a pixel
        assert np.linalg.norm(blobs.uv[0] - spot(i)) < 0.25


def test_files_cannot_be_triggered_and_missing_files_are_named(tmp_path):
    for i, im in enumerate(frames()[:2]):
        cv2.imwrite(str(tmp_path / f"f_{i:06d}.png"), im)
    (cam,) = open_cameras(f"opencv:{tmp_path}/f_%06d.png")
    cam.configure(trigger_mode=TriggerMode.EXTERNAL)
    with pytest.raises(DriverError, match="cannot be triggered"):
        cam.open()
    (missing,) = open_cameras(f"opencv:{tmp_path}/nothing.avi")
    with pytest.raises(DriverError, match="nothing.avi does not exist"):
        missing.open()


def test_absent_v4l2_device_fails_with_advice():
    (cam,) = open_cameras("v4l2:///dev/video-wandcal-absent")
    with pytest.raises(DriverError, match="could not open.*v4l2-ctl --list-devices"):
        cam.open()
