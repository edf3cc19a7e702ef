"""``wandcal report`` and the report route: real captures, real files, a real server on loopback."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from html import escape
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.conftest import SHARED_DATA
from tests.service.conftest import EMPTY_CAMERA, capture_files, wait_job, wandcal
from tests.service.test_cli_imports import loaded_packages
from tests.service.test_http import ABSOLUTE_TOL_M
from wandcal.calib.judge.coverage import GRID
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import Capture, read_capture, write_capture
from wandcal.capture.result_file import read_result, result_from_json
from wandcal.service.report import INSTALL_HINT, RIG_PNG, WAND_PNG, ReportUnavailable, camera_png
from wandcal.service.report.analysis import analyse, rim_ratio
from wandcal.service.report.figures import (
    CAMERA_SIZE_PX,
    RIG_SIZE_PX,
    WAND_SIZE_PX,
    frustum,
)
from wandcal.service.report.store import rendered_report, report_folder

pytest.importorskip("matplotlib", reason="matplotlib is a dependency of wandcal: reinstall it")

WEB_FRAMEWORK = {"fastapi", "uvicorn", "starlette", "pydantic", "pydantic_settings", "multipart", "httpx"}
# an image is "not empty" when this share of its pixels differs from the background: a figure
# with its axes, labels and data drawn covers far more (a blank canvas covers none)
MIN_INK = 0.02
BROWN = SHARED_DATA / "easywand_brown_windtunnel_4cam" / "calibration1" / "extrinsicCalib_20230228_easyWandData.mat"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class Page(HTMLParser):
    """The images (src, alt) and the text of a report page."""

    def __init__(self, text: str):
        super().__init__()
        self.images: list[tuple[str, str]] = []
        self.text: list[str] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            a = dict(attrs)
            self.images.append((a.get("src"), a.get("alt")))

    def handle_data(self, data):
        self.text.append(data)


def assert_figure(path: Path, size_px: tuple[int, int]) -> None:
    image = cv2.imread(str(path))
    assert image is not None, f"{path.name} does not decode as an image"
    assert (image.shape[1], image.shape[0]) == size_px, path.name
    background = np.median(image.reshape(-1, 3), axis=0)
    ink = np.mean(np.any(np.abs(image.astype(int) - background) > 30, axis=2))
    assert ink > MIN_INK, f"{path.name} is nearly blank ({ink:.1%} drawn)"


def test_report_of_a_simulated_capture(sim_report):
    tmp, sim, run = sim_report
    out = tmp / "out"
    doc = json.loads((tmp / "result.json").read_text())
    ids = sim.rig.ids
    assert str(out / "index.html") in run.stdout
    expected = {RIG_PNG: RIG_SIZE_PX, WAND_PNG: WAND_SIZE_PX}
    expected |= {camera_png(i, cid): CAMERA_SIZE_PX for i, cid in enumerate(ids)}
    assert {p.name for p in out.glob("*.png")} == set(expected)
    for name, size in expected.items():
        assert_figure(out / name, size)

    html = (out / "index.html").read_text()
    page = Page(html)
    assert {src for src, _ in page.images} == set(expected)  # every PNG is on the page
    assert all(alt and len(alt) > 20 for _, alt in page.images)
    for cam in doc["cameras"]:
        assert f'data-camera="{cam["id"]}"' in html
        assert f'id="camera-{cam["id"]}"' in html
        assert f'{cam["reprojection_rms_px"]:.3f}' in html
        assert f'{cam["center_std_mm"]:.2f} mm' in html
        assert f'>{cam["verdict"]["level"]}<' in html
        for worst in cam["worst_frames"]:
            assert f'{worst["frame"]} ({worst["error_px"]:.2f} px)' in html
    assert f'>{doc["verdict"]["level"]}<' in html
    for warning in doc["warnings"]:
        assert escape(warning) in html
    # the wand never reached cam2's left third: the page says so, in words an operator acts on
    assert f"{ids[EMPTY_CAMERA]}: no wand samples in the left third" in " ".join(page.text)
    assert "http://" not in html and "https://" not in html and "<script" not in html  # self-contained


def test_analysis_agrees_with_the_capture(sim_report):
    """The coverage grid counts the samples the capture holds, the empty third is empty, and every
    frustum points from its camera towards the wand."""
    tmp, sim, _ = sim_report
    result = read_result(tmp / "result.json")
    data = analyse(result, read_capture(tmp / "capture"))
    empty = data.cameras[EMPTY_CAMERA].coverage
    assert empty[:, : round(GRID[1] / 3)].sum() == 0 and empty.sum() == len(data.cameras[EMPTY_CAMERA].uv)
    volume = data.trajectory.mean(axis=0)
    for cam in data.cameras:
        corners = frustum(cam.doc, 1.0)
        axis = corners[1:].mean(axis=0) - corners[0]
        np.testing.assert_allclose(axis / np.linalg.norm(axis), np.array(cam.doc["R"])[2], atol=0.05)
        assert axis @ (volume - corners[0]) > 0, f"{cam.id} looks away from the wand"
    # the wand's midpoints are where the simulator waved it, within the world frame's own error
    # (the same 4-camera, 300-frame, 0.3 px capture as test_http's)
    truth = sim.truth.wand.mean(axis=1)[data.trajectory_frames]
    assert np.median(np.linalg.norm(data.trajectory - truth, axis=1)) < ABSOLUTE_TOL_M


@pytest.mark.parametrize("k1_error", [0.0, 0.25])
def test_residuals_growing_away_from_the_centre_point_at_the_lens(k1_error):
    """A lens model off by 0.25 in k1 leaves residuals that grow with the distance from the image
    centre, and the advice says so; with the right lens it stays quiet (EDGE_RATIO is five
    standard deviations of the noise-only ratio)."""
    sim = simulate_capture(4, 600, 0.3, 0.0, True, 11)
    cams = [Camera(c.id, c.width, c.height, c.K, c.dist + np.r_[k1_error, 0, 0, 0, 0]) for c in sim.rig.cameras]
    rig = Rig(cams, sim.rig.wand_length, sim.rig.static_markers)
    result = result_from_json(calibrate(rig, sim.wand, sim.static).to_json())
    data = analyse(result, Capture(rig, sim.wand, sim.static))
    said = [a for a in data.advice if "grow away from the image centre" in a]
    if k1_error:
        assert said, [rim_ratio(c) for c in data.cameras]
    else:
        assert not said, said


def test_report_without_capture_and_an_older_result(sim_report, tmp_path):
    """An older result (no center_std_mm, rotation_std_deg, verdict): the page shows a dash; with
    no capture, the rig alone and a word on what needs the capture."""
    tmp, _, _ = sim_report
    doc = json.loads((tmp / "result.json").read_text())
    doc.pop("verdict")
    for cam in doc["cameras"]:
        for key in ("center_std_mm", "rotation_std_deg", "verdict", "coverage", "uncovered"):
            cam.pop(key, None)
    (tmp_path / "old.json").write_text(json.dumps(doc))
    run = wandcal("report", str(tmp_path / "old.json"), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["index.html", RIG_PNG]
    assert_figure(tmp_path / "out" / RIG_PNG, RIG_SIZE_PX)
    html = (tmp_path / "out" / "index.html").read_text()
    assert "--capture CAPTURE" in html
    assert "Rig verdict: \u2014" in html
    row = html[html.index('<tr data-camera="cam1">'):]
    row = row[: row.index("</tr>")]
    assert row.count("\u2014") >= 3  # centre +-, rotation +-, verdict (and coverage)


def test_bad_input_exits_2_with_a_message(sim_report, tmp_path):
    tmp, _, _ = sim_report
    out = str(tmp_path / "out")
    (tmp_path / "not.json").write_text("{ nope")
    run = wandcal("report", str(tmp_path / "not.json"), "--out", out)
    assert run.returncode == 2 and "not.json" in run.stderr and "Traceback" not in run.stderr
    doc = json.loads((tmp / "result.json").read_text())
    del doc["cameras"][2]["R"]
    (tmp_path / "broken.json").write_text(json.dumps(doc))
    run = wandcal("report", str(tmp_path / "broken.json"), "--out", out)
    assert run.returncode == 2 and "camera 'cam3'" in run.stderr and "'R'" in run.stderr, run.stderr
    other = simulate_capture(3, 50, 0.3, 0.0, False, 2)  # a capture of another rig
    write_capture(tmp_path / "other", other.rig, other.wand, None)
    run = wandcal("report", str(tmp / "result.json"), "--capture", str(tmp_path / "other"), "--out", out)
    assert run.returncode == 2 and "the capture the result was calibrated from" in run.stderr, run.stderr


def test_without_matplotlib_the_command_says_what_to_install(sim_report, monkeypatch, capsys, tmp_path):
    from wandcal.service.cli import main

    tmp, _, _ = sim_report
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now fails, as when it is absent
    code = main(["report", str(tmp / "result.json"), "--out", str(tmp_path / "out")])
    assert code == 2
    assert INSTALL_HINT in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_the_service_without_matplotlib_draws_nothing(sim_report, monkeypatch, tmp_path):
    """The route answers 503 with this message (service/api/routes/jobs.py); no half report is left."""
    tmp, _, _ = sim_report
    doc = json.loads((tmp / "result.json").read_text())
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ReportUnavailable, match=re.escape(INSTALL_HINT)):
        rendered_report(tmp_path, "job1", doc, lambda: None)
    assert not report_folder(tmp_path, "job1").exists()


def test_report_command_loads_no_web_framework(sim_report, tmp_path):
    tmp, _, _ = sim_report
    loaded = loaded_packages("report", str(tmp / "result.json"), "--out", str(tmp_path / "out"))
    assert (tmp_path / "out" / RIG_PNG).is_file()
    assert "matplotlib" in loaded  # the probe saw the report drawn
    assert not loaded & WEB_FRAMEWORK, sorted(loaded & WEB_FRAMEWORK)


@pytest.mark.shared_data
def test_report_of_the_real_easywand_session(tmp_path):
    """Brown's wind-tunnel session 1 (easyWand): sparse wand, background points, axis points."""
    if not BROWN.is_file():
        pytest.skip(f"third-party data not found at {BROWN.parent}")
    capture = tmp_path / "brown"
    run = wandcal("import", "easywand", str(BROWN), "--out", str(capture))
    assert run.returncode == 0, run.stderr
    run = wandcal("calibrate", str(capture), "--out", str(tmp_path / "result.json"), "--quiet")
    assert run.returncode == 0, run.stderr
    run = wandcal("report", str(tmp_path / "result.json"), "--capture", str(capture), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    doc = json.loads((tmp_path / "result.json").read_text())
    ids = [c["id"] for c in doc["cameras"]]
    assert ids == ["cam1", "cam2", "cam3", "cam4"]
    assert_figure(tmp_path / "out" / RIG_PNG, RIG_SIZE_PX)
    assert_figure(tmp_path / "out" / WAND_PNG, WAND_SIZE_PX)
    for i, cid in enumerate(ids):
        assert_figure(tmp_path / "out" / camera_png(i, cid), CAMERA_SIZE_PX)
    html = (tmp_path / "out" / "index.html").read_text()
    assert all(f'id="camera-{cid}"' in html for cid in ids)
    data = analyse(read_result(tmp_path / "result.json"), read_capture(capture))
    # the world is the axis points' frame: the report's own triangulation puts the origin at 0
    assert doc["world"]["frame"] == "axis"
    np.testing.assert_allclose(data.axis["origin"], 0, atol=1e-6)
    assert len(data.points) > 300 and all(len(c.point_uv) for c in data.cameras)


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_report_over_http(make_server, small_capture, tmp_path):
    folder, sim = small_capture
    server = make_server(workers=1, token="lab-token").start()
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        job = wait_job(c, c.post("/jobs", json={"capture_id": capture_id}).json()["id"])
        assert job["state"] == "done", job["error"]
        job_id = job["id"]
        assert c.get("/jobs/" + "0" * 32 + "/report").status_code == 404

        r = c.get(f"/jobs/{job_id}/report")
        assert r.status_code == 307 and r.headers["location"] == "report/"
        page = c.get(f"/jobs/{job_id}/report", follow_redirects=True)
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert str(page.url).endswith(f"/jobs/{job_id}/report/")
        assert "default-src 'none'" in page.headers["content-security-policy"]
        images = Page(page.text).images
        # drawn with the job's capture: a figure per camera besides the rig and the wand
        assert {src for src, _ in images} == {RIG_PNG, WAND_PNG} | {camera_png(i, cid) for i, cid in enumerate(sim.rig.ids)}
        for src, _ in images:
            png = c.get(f"/jobs/{job_id}/report/{src}")
            assert png.status_code == 200 and png.headers["content-type"] == "image/png"
            image = cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_COLOR)
            size = RIG_SIZE_PX if src == RIG_PNG else WAND_SIZE_PX if src == WAND_PNG else CAMERA_SIZE_PX
            assert (image.shape[1], image.shape[0]) == size
        index = tmp_path / "data" / "reports" / job_id / "index.html"
        drawn = index.stat().st_mtime_ns
        assert c.get(f"/jobs/{job_id}/report/index.html").text == page.text
        assert index.stat().st_mtime_ns == drawn  # drawn once, then served

        for name in ("..%2F..%2Fwandcal.sqlite3", "..%2Fwandcal.sqlite3", ".hidden.png", "index.htm", "rig.png.bak",
                     "%2Fetc%2Fpasswd", "%2E%2E", "x" * 300 + ".png", "missing.png"):
            bad = c.get(f"/jobs/{job_id}/report/{name}")
            assert bad.status_code == 404, (name, bad.status_code)
            assert "SQLite" not in bad.text

    # a link the page opens in a tab of its own sends no Authorization header: the token comes from
    # the page's cookie, honoured for reads only
    import httpx

    report = f"{server.url}/api/v1/jobs/{job_id}/report/"
    assert httpx.get(report).status_code == 401
    assert httpx.get(report, cookies={"wandcal_token": "not-it"}).status_code == 401
    for name in ("", RIG_PNG):
        assert httpx.get(report + name, cookies={"wandcal_token": "lab-token"}).status_code == 200
    riding = httpx.post(f"{server.url}/api/v1/jobs", json={"capture_id": capture_id}, cookies={"wandcal_token": "lab-token"})
    assert riding.status_code == 401  # a cookie cannot be ridden into a change

    if CHROMIUM:  # the page links the report of a finished job
        dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                              "--disable-background-networking", f"--user-data-dir={tmp_path / 'profile'}",
                              "--virtual-time-budget=5000", "--dump-dom", server.url + "/#token=lab-token"],
                             capture_output=True, text=True, timeout=120, check=False)
        assert f'href="/api/v1/jobs/{job_id}/report"' in dom.stdout


def test_report_of_a_job_not_done_is_409(make_server, small_capture):
    folder, _ = small_capture
    server = make_server(workers=0).start()  # no worker: the job stays queued
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        job_id = c.post("/jobs", json={"capture_id": capture_id}).json()["id"]
        for path in ("report", "report/", "report/rig.png"):
            r = c.get(f"/jobs/{job_id}/{path}")
            assert r.status_code == 409 and "queued" in r.json()["detail"], r.text


def test_the_report_shows_the_judgement(sim_report, tmp_path):
    """The fields of issue 19's judgement, added by hand to a real result (results before it lack them)."""
    from tests.service.test_page import FAULT, GEOMETRY_MM, judged, older_result

    tmp, _, _ = sim_report
    doc = judged(json.loads((tmp / "result.json").read_text()))
    doc["cameras"] = doc["cameras"][:len(GEOMETRY_MM)]  # the rig's own cameras, not the page test's crowd
    (tmp_path / "judged.json").write_text(json.dumps(doc))
    run = wandcal("report", str(tmp_path / "judged.json"), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    html = (tmp_path / "out" / "index.html").read_text()
    text = " ".join(Page(html).text)
    for cam, geometry in zip(doc["cameras"], GEOMETRY_MM):
        row = html[html.index(f'<tr data-camera="{cam["id"]}">'):]
        row = row[: row.index("</tr>")]
        for shown in (f"{geometry:.2f}", f"{geometry / 10:.4f}", "0.05", "1.2%", ">good<"):
            assert shown in row, (shown, row)
        assert f"{geometry:.2f} mm" in html and f"wave nearer {cam['id']}" in text
    assert "intrinsics (cam3): " + FAULT["message"] in text and "timing: the cameras are out of step" in text
    assert "check cam3's intrinsics" in text
    assert "World frame placement: origin \u00b1 0.42 mm, axes \u00b1 0.031 deg" in text and "L-frame seen by 4" in text

    older = older_result(json.loads((tmp / "result.json").read_text()))  # no judgement fields: dashes
    (tmp_path / "older.json").write_text(json.dumps(older))
    run = wandcal("report", str(tmp_path / "older.json"), "--out", str(tmp_path / "out-older"))
    assert run.returncode == 0, run.stderr
    text = " ".join(Page((tmp_path / "out-older" / "index.html").read_text()).text)
    assert "World frame placement: origin \u00b1 \u2014, axes \u00b1 \u2014" in text and "Faults: \u2014" in text


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_the_report_shows_the_time_offsets(tmp_path):
    """A result of ``--sync auto`` (cam3 two and a half frames late): the page's "Time offsets"
    table gives each camera's offset and standard error in frames and ms, and marks cam3 out of
    time; a result under ``--sync none`` has no such section."""
    off = np.array([0.0, 0.0, 2.5, 0.0])
    sim = simulate_capture(4, 400, 0.3, static=False, seed=5, offsets=off)
    result = calibrate(sim.rig, sim.wand, options=CalibrationOptions(sync="auto", frame_rate_hz=100.0)).to_json()
    (tmp_path / "result.json").write_text(json.dumps(result))
    run = wandcal("report", str(tmp_path / "result.json"), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    html = (tmp_path / "out" / "index.html").read_text()
    section = html[html.index('<section id="sync">'):]
    section = section[: section.index("</section>")]
    for cam in result["sync"]["cameras"]:
        row = section[section.index(f'<tr data-camera="{cam["id"]}"'):]
        row = row[: row.index("</tr>")]
        assert f'{cam["offset_frames"]:+.3f}' in row and f'{cam["offset_std_frames"]:.3f}' in row
        assert f'{1000 * cam["offset_frames"] / 100.0:+.2f}' in row  # ms at 100 fps
        assert ('class="out-of-time"' in row) == (cam["id"] == "cam3") == cam["out_of_time"]
    assert "Found out of time, against what the frame numbers (or timestamps) said: cam3" in section
    plain = calibrate(sim.rig, sim.wand, options=CalibrationOptions(sync="none")).to_json()
    (tmp_path / "plain.json").write_text(json.dumps(plain))
    assert wandcal("report", str(tmp_path / "plain.json"), "--out", str(tmp_path / "plain")).returncode == 0
    assert 'id="sync"' not in (tmp_path / "plain" / "index.html").read_text()


def test_each_camera_section_shows_its_own_warning_when_the_result_folds_them(sim_report, tmp_path):
    """A warning several cameras share is one line of the result's ``warnings`` ("cam1, cam2, ...: ...",
    or "all 64 cameras: ..." on a big rig, wandcal.calib.run.camera_reports.fold_camera_warnings); each camera's
    section still shows it, from the camera's own ``warnings``."""
    tmp, _, _ = sim_report
    doc = json.loads((tmp / "result.json").read_text())
    said = ": static-object pose is ambiguous (planar flip); placed from the wand"
    ids = [cam["id"] for cam in doc["cameras"]]
    doc["warnings"] = ["all 64 cameras" + said]  # as a big rig's reads: no id of its own
    for cam in doc["cameras"]:
        cam["warnings"] = [cam["id"] + said]
    (tmp_path / "folded.json").write_text(json.dumps(doc))
    run = wandcal("report", str(tmp_path / "folded.json"), "--out", str(tmp_path / "out"))
    assert run.returncode == 0, run.stderr
    html = (tmp_path / "out" / "index.html").read_text()
    for cam_id in ids:
        section = html[html.index(f'<section class="camera" id="camera-{cam_id}"'):]
        assert escape(cam_id + said) in section[: section.index("</section>")], cam_id
    assert escape("all 64 cameras" + said) in html  # and the result's own list


def test_the_report_says_the_criteria_at_the_limit_and_no_placement_without_a_reference(sim_report, tmp_path):
    """A criterion within one standard error of the limit of poor is said beside the rig's verdict;
    a world the wand volume set (no L-frame, no axis points) is said to have no reference, ungraded."""
    from wandcal.calib.judge.placement import NO_REFERENCE
    from wandcal.service.report.analysis import analyse
    from wandcal.service.report.page import render_page

    tmp, _, _ = sim_report
    doc = json.loads((tmp / "result.json").read_text())
    doc["verdict"]["at_limit"] = [{"criterion": "geometry", "camera": doc["cameras"][0]["id"], "value": 0.75,
                                   "limit": 0.805, "std": 0.082, "unit": "mm", "levels": ["good", "poor"]}]
    doc["world"]["frame"] = "wand_volume"
    (tmp_path / "result.json").write_text(json.dumps(doc))
    text = " ".join(Page(render_page(analyse(read_result(tmp_path / "result.json"), None), {})).text)
    assert f"{doc['cameras'][0]['id']} geometry at the limit of poor (0.75 +- 0.082 mm against 0.805 mm)" in text
    assert f"World frame: {NO_REFERENCE}" in text and "World frame placement" not in text


def test_the_report_lists_the_intrinsics_that_limit_the_cameras(sim_report, tmp_path):
    """The verdict's limits (intrinsics given, not refined, that a camera's position hinges on) are
    said as the CLI summary says them (the dominant intrinsics and what to do); an older result's
    without figures by camera with their message."""
    from wandcal.service.cli.support.summary import _limit_lines
    from wandcal.service.report.analysis import analyse
    from wandcal.service.report.page import render_page

    tmp, _, _ = sim_report
    doc = json.loads((tmp / "result.json").read_text())
    said = _limit_lines(doc["verdict"]["limits"], len(doc["cameras"]))
    assert said and "hinge" in said[0]
    page = " ".join(Page(render_page(analyse(read_result(tmp / "result.json"), None), {})).text)
    assert all(line.strip() in page for line in said)
    cam = doc["cameras"][0]["id"]
    doc["verdict"]["limits"] = [{"camera": cam, "parameter": "cy", "evidence": {},
                                 "message": f"{cam}'s position moves 1.2 mm for 21 px of its principal point's y (cy)"}]
    (tmp_path / "result.json").write_text(json.dumps(doc))
    text = " ".join(Page(render_page(analyse(read_result(tmp_path / "result.json"), None), {})).text)
    assert f"limit ({cam}): {cam}'s position moves 1.2 mm for 21 px of its principal point's y (cy)" in text
