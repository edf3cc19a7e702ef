"""One number everywhere: the views of one result (the command line's table, the verdict, the
report's page and histogram) and of one capture (capture's summary, the guidance, the live status
line) give each figure from one definition, or say in their labels which figure they give."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from wandcal.calib.run.result import camera_observations
from wandcal.capture.folder import read_capture
from wandcal.service.cli import main
from wandcal.service.cli.support.summary import format_summary

pytestmark = pytest.mark.usefixtures("patient_stall_limit")  # in-process recordings on a loaded box

CAMERAS = 4


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A simulated capture with gross outliers (so "with and without outliers" differ), calibrated."""
    out = tmp_path_factory.mktemp("views") / "cap"
    assert main(["simulate", str(out), "--cameras", str(CAMERAS), "--frames", "300", "--outliers", "0.05",
                 "--seed", "7"]) == 0
    assert main(["calibrate", str(out), "--quiet"]) == 0
    return out, json.loads((out / "result.json").read_text())


def table_rows(summary: str) -> dict[str, list[str]]:
    lines = summary.splitlines()
    head = lines[0].split()
    assert "obs" in head
    return {line.split()[0]: line.split() for line in lines[1:] if line.split() and line.split()[0].startswith("cam")}


def test_the_table_the_verdict_and_the_result_count_the_same_observations(calibrated):
    _, doc = calibrated
    summary = format_summary(doc)
    rows = table_rows(summary)
    obs_column = 9  # id, x, y, z, geom, world, rms, resid, outl %, obs
    for cam in doc["cameras"]:
        count = camera_observations(cam)
        assert int(rows[cam["id"]][obs_column]) == count, (cam["id"], rows[cam["id"]])
        # wherever the verdict gives this camera's count, it is the same number
        for said in re.findall(rf"{cam['id']}: (\d+) observations", json.dumps(cam.get("verdict"))):
            assert int(said) == count


def test_the_wand_line_says_which_frames_it_counts(calibrated):
    # import counts frames with both ends per camera; the summary counts the solve's frames (both
    # ends in 2+ cameras): the label says which, so the two are not read as one figure
    _, doc = calibrated
    summary = format_summary(doc)
    assert f"over {doc['wand']['frames_used']} frames in the solve (both ends in 2+ cameras" in summary
    # and why it can be fewer than import's count of the same frames: outliers cost frames their second camera
    dropped = doc["dropped"]["outliers"]
    said = "once its one gross-outlier camera-frame was dropped" if dropped == 1 else \
        f"once the {dropped} gross-outlier camera-frames were dropped"
    assert (said in summary) == (dropped > 0), summary


def test_worst_frames_name_each_frame_once_worst_first(calibrated):
    _, doc = calibrated
    for cam in doc["cameras"]:
        frames = [w["frame"] for w in cam["worst_frames"]]
        errors = [w["error_px"] for w in cam["worst_frames"]]
        assert len(frames) == len(set(frames)), (cam["id"], frames)
        assert errors == sorted(errors, reverse=True)


def test_the_histogram_line_is_the_rms_the_page_and_the_table_give(calibrated):
    pytest.importorskip("matplotlib")
    from wandcal.capture.result_file import read_result
    from wandcal.service.report.analysis import analyse
    from wandcal.service.report.figures import histogram_rms

    out, doc = calibrated
    data = analyse(read_result(out / "result.json"), read_capture(out))
    rows = table_rows(format_summary(doc))
    for cam in data.cameras:
        inliers = np.linalg.norm(cam.residual_px, axis=1)[~cam.outlier]
        rms, label = histogram_rms(cam, inliers)
        assert rms == cam.doc["reprojection_rms_px"]
        assert f"{rms:.2f} px" in label and "wand ends the solve kept" in label
        assert float(rows[cam.id][6]) == pytest.approx(rms, abs=5e-4)  # the table's rms px, 3 decimals


def test_the_live_status_line_counts_cameras_not_advice(calibrated):
    from wandcal.calib.run.guidance import wanding_guidance
    from wandcal.service.cli.recording.guidance import summary

    out, _ = calibrated
    capture = read_capture(out)
    document = wanding_guidance(capture.rig, capture.wand, capture.static, None).document
    needing = [c["id"] for c in document["cameras"] if c["advice"]]
    line = summary(document)
    if document["enough"]:
        assert "ENOUGH" in line
    elif needing:
        assert f"{len(needing)} of {CAMERAS} camera(s) need more" in line
    # rig-wide advice (a failed solve, a camera out of time) is not counted as a camera
    rigwide = {**document, "enough": False, "advice": ["the fast solve failed", *document["advice"]],
               "cameras": [{**c, "advice": None} for c in document["cameras"]]}
    assert "camera(s) need more" not in summary(rigwide)


def test_capture_and_guidance_label_their_frame_counts(tmp_path, capsys):
    out = tmp_path / "cap"
    assert main(["capture", "--camera", "sim://?cameras=3&seed=2", "--frames", "60", "--images", "none",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    delivered = dict(re.findall(r"^(cam\d): (\d+) frames? delivered", text, re.M))
    assert set(delivered) == {"cam1", "cam2", "cam3"}
    log = json.loads((out / "capture.json").read_text())
    assert {cid: int(n) for cid, n in delivered.items()} == {cid: c["delivered"] for cid, c in log["cameras"].items()}
    assert "both ends" in text  # the guidance's column: frames with both wand ends, another count
    assert main(["guidance", str(out)]) == 0
    again = capsys.readouterr().out
    table = text[text.index("camera "):]  # capture's guidance on what it recorded is the guidance command's
    assert again.splitlines()[:4] == table.splitlines()[:4]


def test_a_frame_whose_two_ends_are_the_worst_is_listed_once():
    from types import SimpleNamespace

    from wandcal.calib.judge.quality import WORST_FRAMES, camera_report

    # one camera, 8 frames, two ends each; frame 3's ends are the two largest errors
    frame = np.repeat(np.arange(8), 2)
    errors = np.linspace(0.1, 0.8, 16)
    errors[6:8] = [5.0, 4.0]
    report = camera_report(errors, SimpleNamespace(camera=np.zeros(16, int), frame=frame), np.arange(100, 108), 0)
    listed = [w["frame"] for w in report["worst_frames"]]
    assert listed[0] == 103 and len(listed) == len(set(listed)) == WORST_FRAMES
    assert report["worst_frames"][0]["error_px"] == 5.0
