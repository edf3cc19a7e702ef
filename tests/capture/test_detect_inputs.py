"""``wandcal detect`` with detection options, per-camera masks and empty-volume recordings
(docs/capture-format.md, "Detection inputs"), on rendered image-level captures."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from wandcal.calib.sim.render import render_blobs
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import read_capture, rig_to_json
from wandcal.capture.images import detect_capture
from wandcal.service.cli import main

SHAPE = (240, 320)  # simulate_capture's rig says 1280x1024; rig.json is rewritten at this size
FRAMES = 24
EMPTY = 8
REFLECTION = np.array([[280.0, 40.0]])  # a flickering reflection: a round bright spot


def _flickers(i: int) -> bool:
    return i % 3 == 0  # a third of the frames: under the 50 % that makes a blob a still marker


def _wand(i: int) -> np.ndarray:
    return np.array([[40.0 + 7 * i, 90.0 + 2 * i], [70.0 + 7 * i, 150.0 - i]])


def _write(path, uv, rng) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), render_blobs(SHAPE, uv, 1.4, 180.0, 10.0, 2.0, 8, rng))


@pytest.fixture
def capture(tmp_path):
    """Two cameras, wand frames with a flickering reflection, and an empty-volume recording."""
    folder = tmp_path / "cap"
    rig = rig_to_json(simulate_capture(2, 10, 0.3, seed=1).rig)
    for cam in rig["cameras"]:
        cam["width"], cam["height"] = SHAPE[1], SHAPE[0]
    folder.mkdir()
    (folder / "rig.json").write_text(json.dumps(rig))
    rng = np.random.default_rng(2)
    for cam in rig["cameras"]:
        for i in range(FRAMES):
            spots = np.vstack((_wand(i), REFLECTION)) if _flickers(i) else _wand(i)
            _write(folder / f"frames/{cam['id']}/{i:06d}.png", spots, rng)
        for n in range(EMPTY):
            _write(folder / f"background/{cam['id']}/{n:06d}.png", REFLECTION if _flickers(n) else np.zeros((0, 2)), rng)
    return folder


def _kept(folder, camera_index=0) -> set[int]:
    cap = read_capture(folder)
    return set(cap.wand.frame[cap.wand.camera == camera_index].tolist())


def test_auto_mask_blocks_the_reflection_and_is_saved(capture, capsys):
    assert main(["detect", str(capture), "--mask", "none"]) == 0
    assert _kept(capture) == {i for i in range(FRAMES) if not _flickers(i)}  # the reflection spoils a third
    assert main(["detect", str(capture), "--mask", "auto"]) == 0
    out = capsys.readouterr().out
    assert _kept(capture) == set(range(FRAMES))
    for cam in ("cam1", "cam2"):
        mask = cv2.imread(str(capture / f"masks/{cam}.png"), cv2.IMREAD_GRAYSCALE)
        assert mask.shape == SHAPE and mask[40, 280] == 0 and mask[120, 160] == 255
        assert f"mask {capture / 'masks' / cam}.png blocks" in out
    # The saved masks are used by default from now on, also by 'wandcal calibrate's detection.
    detect_capture(capture)
    assert _kept(capture) == set(range(FRAMES))


def test_empty_volume_background_from_the_capture_or_another_folder(capture, tmp_path, capsys):
    assert main(["detect", str(capture), "--background", "empty"]) == 0
    assert "empty volume from 8 frames" in capsys.readouterr().out
    other = tmp_path / "empty-run"  # an image-level capture recorded of the empty volume
    for png in (capture / "background").rglob("*.png"):
        target = other / "frames" / png.parent.name / png.name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(png.read_bytes())
    assert main(["detect", str(capture), "--background", f"empty:{other}", "--mask", "none"]) == 0
    assert "empty volume from 8 frames" in capsys.readouterr().out
    # The median of the empty frames is not bright where the reflection flickers in a third of
    # them, so only a mask removes it: the frames where it shows are still dropped.
    assert _kept(capture) == {i for i in range(FRAMES) if not _flickers(i)}


def test_running_background_gives_the_same_points_on_one_and_two_workers(capture):
    wand = {}
    for workers in (1, 2):
        assert main(["detect", str(capture), "--background", "running:10", "--workers", str(workers),
                     "--mask", "none"]) == 0
        wand[workers] = (capture / "wand.csv").read_bytes()
    assert wand[1] == wand[2]
    assert _kept(capture) == {i for i in range(FRAMES) if not _flickers(i)}


def test_detection_options_reach_the_detector(capture):
    # A minimum area above a marker's size leaves no blobs; a threshold above the peaks neither.
    assert main(["detect", str(capture), "--min-area", "500", "--max-area", "900"]) == 0
    assert _kept(capture) == set()
    assert main(["detect", str(capture), "--threshold", "250"]) == 0
    assert _kept(capture) == set()
    assert main(["detect", str(capture), "--threshold", "40", "--seed-ratio", "2", "--weights", "signal",
                 "--connectivity", "4", "--min-roundness", "0.3", "--background", "highpass:6"]) == 0
    assert _kept(capture) == {i for i in range(FRAMES) if not _flickers(i)}


def test_min_roundness_auto_leaves_the_choice_to_the_detector():
    import argparse

    from wandcal.calib.detect.config import DetectConfig
    from wandcal.service.cli.recording.detect import add_detect_options, config_from_args

    parser = argparse.ArgumentParser()
    add_detect_options(parser)
    assert config_from_args(parser.parse_args([])) == DetectConfig()
    assert config_from_args(parser.parse_args(["--min-roundness", "auto"])).min_roundness is None
    assert config_from_args(parser.parse_args(["--min-roundness", "0.5"])).min_roundness == 0.5


@pytest.mark.parametrize(
    "args, message",
    [
        (["--background", "median"], "choose auto, none, highpass"),
        (["--background", "highpass:2.5"], "whole number of pixels"),
        (["--background", "running:1"], "frames > 1"),
        (["--threshold", "-3"], "whole grey level"),
        (["--min-roundness", "2"], "at least 0 and at most 1"),
        (["--seed-ratio", "0.5"], "must be at least 1, got 0.5"),
    ],
)
def test_bad_options_are_refused_by_the_parser(capture, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        main(["detect", str(capture), *args])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_bad_inputs_name_the_file_and_say_what_to_do(capture, tmp_path, capsys):
    assert main(["detect", str(capture), "--min-area", "9", "--max-area", "5"]) == 2
    assert "max_area_px must be a whole number >= min_area_px (9)" in capsys.readouterr().err
    nowhere = tmp_path / "nowhere"
    assert main(["detect", str(capture), "--background", f"empty:{nowhere}"]) == 2
    err = capsys.readouterr().err
    assert "camera cam1: no empty-volume frames" in err and str(nowhere / "background" / "cam1") in err
    masks = tmp_path / "masks"
    masks.mkdir()
    cv2.imwrite(str(masks / "cam1.png"), np.full((10, 10), 255, np.uint8))
    assert main(["detect", str(capture), "--mask", str(masks)]) == 2
    assert f"{masks / 'cam1.png'}: 10x10, but camera cam1 is 320x240" in capsys.readouterr().err
    cv2.imwrite(str(masks / "cam1.png"), np.full(SHAPE, 255, np.uint8))
    assert main(["detect", str(capture), "--mask", str(masks)]) == 2
    assert f"{masks / 'cam2.png'}: no mask for camera cam2" in capsys.readouterr().err
    (capture / "background").rename(tmp_path / "moved")
    assert main(["detect", str(capture), "--mask", "auto"]) == 2
    assert "no empty-volume frames in" in capsys.readouterr().err


def test_live_capture_detects_with_the_options(tmp_path):
    out = tmp_path / "live"
    base = ["capture", "--camera", "sim://?cameras=2&seed=1&frames=6", "--frames", "6", "--images", "none",
            "--no-guidance", "--out"]
    assert main([*base, str(out)]) == 0
    assert len(read_capture(out).wand.frame) > 0
    # No 8-bit pixel is brighter than 255: with that threshold the live detector finds nothing.
    assert main([*base, str(tmp_path / "dark"), "--threshold", "255"]) == 0
    assert len(read_capture(tmp_path / "dark").wand.frame) == 0
