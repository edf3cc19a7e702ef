"""``wandcal detect`` on several threads: the same points level as on one, and bad files named."""

import json
import shutil

import cv2
import numpy as np
import pytest

from wandcal.calib.sim.render import render_blobs
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import CaptureFormatError, read_capture, rig_to_json
from wandcal.capture.images import PROGRESS_EVERY, detect_capture
from wandcal.service.cli import main

SHAPE = (240, 320)  # small frames keep the test fast; detection does not care about the size
FRAMES = 30
STATIC = 5
MISSING = {"cam3": 12}  # a slot the camera missed: no file, the numbering goes on
BIT_DEPTH = {"cam1": 8, "cam2": 16, "cam3": 8}
L_FRAME = np.array([[40.0, 200.0], [100.0, 200.0], [190.0, 201.0], [40.0, 150.0]])


def _too_many(i: int) -> bool:
    return i % 7 == 3  # a reflection next to the wand


def _too_few(i: int) -> bool:
    return i % 11 == 5  # the wand out of view


def _spots(c: int, i: int) -> np.ndarray:
    if _too_few(i):
        return np.zeros((0, 2))
    wand = np.array([[40.0 + 6 * i + 3 * c, 40.0 + 2 * i], [70.0 + 6 * i, 110.0 - i + 2 * c]])
    return np.vstack((wand, [[290.0, 20.0 + 5 * c]])) if _too_many(i) else wand


def _write(path, uv, bits, rng) -> None:
    peak, background, noise = (200.0, 10.0, 2.0) if bits == 8 else (40000.0, 2000.0, 300.0)
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), render_blobs(SHAPE, uv, 1.4, peak, background, noise, bits, rng))


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """An image-level capture of three cameras with rendered wand and L-frame images."""
    folder = tmp_path_factory.mktemp("made") / "cap"
    folder.mkdir()
    rig = simulate_capture(3, 10, 0.3, seed=1).rig
    (folder / "rig.json").write_text(json.dumps(rig_to_json(rig)))
    rng = np.random.default_rng(3)
    for c, cid in enumerate(rig.ids):
        for i in range(FRAMES):
            if MISSING.get(cid) != i:
                _write(folder / f"frames/{cid}/{i:06d}.png", _spots(c, i), BIT_DEPTH[cid], rng)
        for n in range(STATIC):
            _write(folder / f"static/{cid}/{n:06d}.png", L_FRAME + [0.0, 4.0 * c], BIT_DEPTH[cid], rng)
    return folder


@pytest.fixture
def folder(made, tmp_path):
    return shutil.copytree(made, tmp_path / "cap")


def _points_level(folder) -> tuple[bytes, bytes]:
    return (folder / "wand.csv").read_bytes(), (folder / "static.csv").read_bytes()


def test_threads_write_the_same_points_level_as_one_thread(folder, tmp_path):
    serial = shutil.copytree(folder, tmp_path / "serial")
    events = []
    reports = detect_capture(folder, workers=2, progress=events.append)
    assert reports == detect_capture(serial, workers=1)
    assert _points_level(folder) == _points_level(serial)
    # ... and it is the rendered truth, not merely the same output twice.
    for report in reports:
        listed = [i for i in range(FRAMES) if MISSING.get(report.camera_id) != i]
        assert report.images == len(listed) and report.static_images == STATIC
        assert report.too_few == sum(map(_too_few, listed)) and report.too_many == sum(map(_too_many, listed))
        assert report.wand_frames == len(listed) - report.too_few - report.too_many
        assert report.static_markers == len(L_FRAME) and not report.unreadable
    cap = read_capture(folder)
    assert 12 not in cap.wand.frame[cap.wand.camera == 2] and 11 in cap.wand.frame[cap.wand.camera == 2]
    assert len(cap.static.uv) == 3 * len(L_FRAME)
    total = 3 * (FRAMES + STATIC) - len(MISSING)
    done = [e["done"] for e in events]
    assert done == sorted(done) and done[-1] == total and len(done) == total // PROGRESS_EVERY + 1
    assert {e["total"] for e in events} == {total} and events[-1]["message"] == "detecting blobs (cam3)"


def test_a_corrupt_png_read_by_a_worker_is_named_and_skipped(folder, tmp_path, capsys):
    bad = folder / "frames/cam2/000009.png"
    bad.write_bytes(bad.read_bytes()[:300])  # cut short, as a crash mid-write would leave it
    serial = shutil.copytree(folder, tmp_path / "serial")
    assert main(["detect", str(folder), "--workers", "2"]) == 0
    out = capsys.readouterr().out
    cam2 = next(line for line in out.splitlines() if line.startswith("cam2:"))
    assert "1 unreadable image(s)" in cam2 and "frames/cam2/000009.png" in cam2
    detect_capture(serial, workers=1)
    assert _points_level(folder) == _points_level(serial)
    cap = read_capture(folder)
    assert 9 not in cap.wand.frame[cap.wand.camera == 1] and 8 in cap.wand.frame[cap.wand.camera == 1]


def test_an_image_the_detector_cannot_take_stops_detection_with_its_name(folder, capsys):
    # cv2.imread goes by the content, not the suffix: a float TIFF named .png decodes to float32.
    assert cv2.imwrite(str(folder / "frames/cam3/000004.tiff"), np.zeros(SHAPE, np.float32))
    (folder / "frames/cam3/000004.tiff").replace(folder / "frames/cam3/000004.png")
    with pytest.raises(CaptureFormatError, match=r"frames/cam3/000004\.png: .*8- or 16-bit grey PNGs"):
        detect_capture(folder, workers=2)
    assert main(["detect", str(folder), "--workers", "2"]) == 2
    assert "frames/cam3/000004.png" in capsys.readouterr().err
    assert not (folder / "wand.csv").exists()


def test_workers_must_be_at_least_one(folder, capsys):
    with pytest.raises(SystemExit):
        main(["detect", str(folder), "--workers", "0"])
    assert "must be at least 1" in capsys.readouterr().err
    with pytest.raises(ValueError, match="workers must be at least 1"):
        detect_capture(folder, workers=0)
