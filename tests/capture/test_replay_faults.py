"""A corrupt PNG in an image-level capture: detection and re-recording carry on, say which file,
and keep everything else."""

import csv

import numpy as np
import pytest

from wandcal.capture.folder import read_capture
from wandcal.capture.images import ensure_points_level
from wandcal.capture.recording.session import record
from wandcal.drivers.registry import open_cameras
from wandcal.service.cli import main

pytestmark = pytest.mark.usefixtures("patient_stall_limit")  # in-process recordings on a loaded box

FRAMES = 40


@pytest.fixture
def folder(tmp_path):
    cams = open_cameras(f"sim://?cameras=3&seed=5&frames={FRAMES}&static=6")
    record(cams, None, tmp_path / "cap", cams[0].scene.rig, frames=FRAMES, static_frames=6, rate_hz=200)
    for name in ("wand.csv", "static.csv", "blobs.csv"):  # the image level alone, as another tool leaves it
        (tmp_path / "cap" / name).unlink()
    bad = tmp_path / "cap/frames/cam3/000007.png"
    bad.write_bytes(bad.read_bytes()[:200])  # cut short, as a crash mid-write would leave it
    return tmp_path / "cap"


def test_detect_skips_the_corrupt_png_and_names_it(folder, capsys):
    assert main(["detect", str(folder)]) == 0
    out = capsys.readouterr().out
    assert "cam3:" in out and "1 unreadable image(s)" in out and "000007.png" in out
    cap = read_capture(folder)
    cam3 = cap.rig.index("cam3")
    seen = set(cap.wand.frame[cap.wand.camera == cam3].tolist())
    assert 7 not in seen and len(seen) >= FRAMES - 1 - 4  # the others are kept (a few may show < 2 blobs)
    assert len(cap.static.uv) == 3 * 4  # every camera's four L-frame markers


def test_rerecording_a_replay_leaves_the_slot_empty_and_goes_on(folder, tmp_path, capsys):
    out = tmp_path / "again"
    code = main(["capture", "--camera", f"replay://{folder}", "--trigger", "none", "--frames", str(FRAMES),
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0
    assert "camera cam3" in err and "000007.png" in err
    with open(out / "sync.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == FRAMES and rows[7]["cam3_ts"] == "" and rows[7]["cam1_ts"]
    assert rows[7]["trigger_count"] == "" and rows[7]["trigger_us"] == ""
    assert not (out / "frames/cam3/000007.png").exists() and (out / "frames/cam3/000008.png").is_file()


def test_ensure_points_level_runs_detection_once(folder):
    assert not (folder / "wand.csv").exists()
    seen = []
    assert ensure_points_level(folder, progress=seen.append) == folder
    assert (folder / "wand.csv").is_file() and seen[-1]["done"] == seen[-1]["total"]
    stamp = (folder / "wand.csv").stat().st_mtime_ns
    ensure_points_level(folder)
    assert (folder / "wand.csv").stat().st_mtime_ns == stamp
    assert np.all(read_capture(folder).wand.frame < FRAMES)
