"""Centroid recording: a capture detects every frame as it arrives and writes its points level as
it goes, with images as asked; the live guidance follows it; the guidance can end it."""

import json

import numpy as np
import pytest

from wandcal.calib.run.guidance import GuidanceSettings
from wandcal.capture.folder import read_capture
from wandcal.capture.images import detect_capture
from wandcal.capture.recording.centroids import STILL_WINDOW_SETS
from wandcal.capture.recording.live_guidance import LiveGuidance
from wandcal.capture.recording.record import ImagePolicy
from wandcal.capture.recording.session import record
from wandcal.drivers.capture_files import BLOBS_FILE
from wandcal.drivers.registry import open_cameras

FRAMES, STATIC = 240, 20
SIM = f"sim://?cameras=4&seed=3&frames={FRAMES}&static={STATIC}"
FAST_HZ = 2000.0  # free-running simulated cameras: as fast as they render

pytestmark = pytest.mark.usefixtures("patient_stall_limit")


def capture(tmp_path, name: str, url: str = SIM, images: str = "all", **kwargs):
    cams = open_cameras(url)
    scene = cams[0].scene
    out = tmp_path / name
    result = record(cams, None, out, scene.rig, frames=scene.wand_frames, static_frames=scene.static_frames,
                    rate_hz=FAST_HZ, images=ImagePolicy.parse(images), **kwargs)
    return out, result


@pytest.mark.long
def test_the_points_level_written_as_it_goes_is_what_detection_of_the_images_gives(tmp_path):
    with_images, result = capture(tmp_path, "all")
    assert result.error is None and result.frame_sets == FRAMES
    recorded = {name: (with_images / name).read_text() for name in ("wand.csv", "static.csv")}
    detect_capture(with_images)  # the images of the same capture, detected afterwards
    for name, text in recorded.items():
        assert (with_images / name).read_text() == text, name

    without, result = capture(tmp_path, "none", images="none")
    assert result.error is None and result.frame_sets == FRAMES
    assert not (without / "frames").exists() and not (without / "static").exists()
    for name, text in recorded.items():  # the same seeded frames: the same centroids, no image written
        assert (without / name).read_text() == text, name
    log = json.loads((without / "capture.json").read_text())
    assert log["images"] == "none"
    cap = read_capture(without)
    per_camera = np.bincount(cap.wand.camera, minlength=4) // 2
    assert [log["detection"][cid]["wand_frames"] for cid in cap.rig.ids] == per_camera.tolist()
    assert cap.static is not None and len(cap.static.uv) == 4 * 4  # every camera sees the L-frame's 4 markers
    # blobs.csv keeps every blob of every wand frame, the pairs among them
    blobs = (without / BLOBS_FILE).read_text().splitlines()
    assert blobs[0] == "frame,camera,u,v" and len(blobs) - 1 >= len(cap.wand)


@pytest.mark.parametrize("images, every, static", [("3", 3, True), ("static", 0, True), ("all", 1, True)])
def test_images_are_written_as_the_policy_says(tmp_path, images, every, static):
    out, result = capture(tmp_path, "cap", url="sim://?cameras=2&seed=1&frames=30&static=5", images=images)
    written = sorted(int(p.stem) for p in (out / "frames" / "cam1").glob("*.png")) if every else []
    assert written == (list(range(0, 30, every)) if every else [])
    assert len(list((out / "static" / "cam2").glob("*.png"))) == (5 if static else 0)
    assert result.frame_sets == 30


def test_bad_image_policies_are_refused():
    for text in ("some", "0", "-2", ""):
        with pytest.raises(ValueError, match="images"):
            ImagePolicy.parse(text)
    assert str(ImagePolicy.parse("4")) == "every 4"


class Pairs:
    """A listener that keeps the live wand pairs."""

    def __init__(self):
        self.frames, self.static = [], None

    def add_pair(self, frame, camera, uv):
        self.frames.append((frame, camera))

    def set_static(self, static):
        self.static = static


def test_an_lframe_left_in_view_without_a_static_recording_is_found_while_recording(tmp_path):
    frames = 2 * STILL_WINDOW_SETS + 50
    listener = Pairs()
    out, result = capture(tmp_path, "keep", url=f"sim://?cameras=3&seed=5&frames={frames}&lframe=keep",
                          images="none", guidance=listener)
    assert result.error is None
    cap = read_capture(out)
    final = {(int(f), int(c)) for f, c in zip(cap.wand.frame, cap.wand.camera)}
    live = set(listener.frames)
    # the L-frame's four blobs make every frame "too many" until the first window has seen them
    # stay put; from then on the live pairs are the final ones
    assert live == {(f, c) for f, c in final if f >= STILL_WINDOW_SETS}
    assert len(final) > 0.8 * 3 * frames  # most frames show both wand ends in every camera


def test_the_live_guidance_follows_the_capture_and_can_end_it(tmp_path):
    docs = []
    cams = open_cameras("sim://?cameras=4&seed=2&frames=3000&static=10")
    rig = cams[0].scene.rig
    # a loose goal that the simulated path meets after a few hundred sets (its coverage is ~25%)
    settings = GuidanceSettings(target_std_mm=1.0, min_coverage=0.1)
    watched = 3  # solved updates seen before the capture may end, so the test sees the guidance change

    def enough() -> bool:
        return guidance.enough and sum(d["solve"]["ok"] for d in docs) >= watched

    with LiveGuidance(rig, settings, interval_s=0.2, on_update=docs.append) as guidance:
        result = record(cams, None, tmp_path / "cap", rig, frames=3000, static_frames=10, rate_hz=200.0,
                        images=ImagePolicy.parse("none"), guidance=guidance, until=enough)
    assert result.error is None and 0 < result.frame_sets < 3000
    assert any("the guidance says enough" in m for m in result.messages)
    solved = [d for d in docs if d["solve"]["ok"]]
    assert len(solved) >= watched and solved[-1]["enough"]
    assert solved[-1]["frames"] > solved[0]["frames"]
    first, last = (np.array([c["center_std_mm"] for c in d["cameras"]]) for d in (solved[0], solved[-1]))
    # the rig's sigma falls as frames arrive; a camera the wand did not pass in between keeps its own
    # (information only adds at a fixed pose, but each update re-solves the poses: a few per cent either way)
    assert np.median(last) < np.median(first)
    assert np.all(last < 1.1 * first)
    assert (tmp_path / "cap" / "static.csv").is_file()  # the static recording's markers, averaged
    assert read_capture(tmp_path / "cap").wand.frame.max() < result.frame_sets
