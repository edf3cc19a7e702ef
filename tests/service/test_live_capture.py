"""Live capture over HTTP: start, watch, stop, and the capture it leaves for ``POST /jobs``."""

from __future__ import annotations

import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from drivers.registry import open_cameras
from service.main import create_app
from service.settings import Settings
from tests.service.conftest import wait_job

SIM_URL = "sim://?cameras=3&seed=2&frames=60&static=10"
WAND_SETS, STATIC_SETS = 60, 10
# A long simulated run (40 s at 50 Hz) that the tests stop after a few sets.
LONG_URL = "sim://?cameras=3&seed=2&frames=2000"
LONG_RATE_HZ = 50.0
CAPTURE_TIMEOUT_S = 60.0
# The rendered blobs are found to a few hundredths of a pixel (calib.detect's tests: 0.05 px).
# The world frame comes from PnP on the L-frame (0.5 m arm) seen from ~4.5 m at f ~1000 px: its
# depth error z^2 * sigma / (f * arm) is ~2 mm, and its tilt moves the centres about as much again.
DETECT_PX, RANGE_M, FOCAL_PX, ARM_M = 0.05, 4.5, 1000.0, 0.5
ABSOLUTE_TOL_M = 2 * RANGE_M**2 * DETECT_PX / (FOCAL_PX * ARM_M)
ENDED = ("done", "failed")


def wait_capture(client, until=ENDED, timeout_s: float = CAPTURE_TIMEOUT_S, check=lambda s: True) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status = client.get("/capture").json()
        if status["state"] in until and check(status):
            return status
        time.sleep(0.05)
    raise AssertionError(f"live capture still {status['state']} ({status['phase']}) after {timeout_s} s")


@pytest.fixture
def client(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        yield c
        if c.get("/capture").json()["state"] in ("running", "stopping"):
            c.post("/capture/stop")
            wait_capture(c)


def test_live_capture_over_http_then_calibrate(make_server, tmp_path):
    server = make_server(workers=1).start()
    with server.client() as c:
        assert c.get("/capture").json()["state"] == "idle"
        r = c.post("/capture/start", json={"cameras": [SIM_URL], "trigger": None, "frames": WAND_SETS,
                                           "static_frames": STATIC_SETS, "rate_hz": 200})
        assert r.status_code == 202, r.text
        started = r.json()
        assert started["state"] == "running" and started["capture_id"] and started["id"]
        assert started["cameras"] == ["cam1", "cam2", "cam3"]
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]
        assert status["id"] == started["id"] and status["capture_id"] == started["capture_id"]
        assert status["frames_recorded"] == WAND_SETS + STATIC_SETS
        assert status["dropped"] == {"cam1": 0, "cam2": 0, "cam3": 0}
        assert not status["stopped"] and status["fps"] > 0

        capture = c.get(f"/captures/{started['capture_id']}").json()
        assert capture["source"] == "live" and capture["has_static"]
        assert capture["cameras"] == started["cameras"]
        # every stored wand row is a detected pair in one of the recorded wand sets
        assert 0 < capture["frames"] <= WAND_SETS
        assert all(0 < cov["pairs"] <= WAND_SETS and cov["blobs"] == 2 * cov["pairs"] for cov in capture["coverage"])
        assert (tmp_path / "data" / "captures" / started["capture_id"] / "frames" / "cam1").is_dir()
        assert not list((tmp_path / "data" / "captures").glob(".*.partial"))

        r = c.post("/jobs", json={"capture_id": started["capture_id"], "method": "ba"})
        assert r.status_code == 202, r.text
        job = wait_job(c, r.json()["id"])
        assert job["state"] == "done", job["error"]
    truth = open_cameras(SIM_URL)[0].scene.truth.centers
    centers = np.array([cam["center"] for cam in job["result"]["cameras"]])
    assert np.linalg.norm(centers - truth, axis=1).max() < ABSOLUTE_TOL_M


def test_second_start_conflicts_and_stop_keeps_what_was_recorded(client):
    body = {"cameras": [LONG_URL], "frames": 2000, "rate_hz": LONG_RATE_HZ}
    r = client.post("/capture/start", json=body)
    assert r.status_code == 202, r.text
    live_id = r.json()["id"]
    r = client.post("/capture/start", json=body)
    assert r.status_code == 409
    assert live_id in r.json()["detail"]

    wait_capture(client, until=("running",), check=lambda s: s["frames_recorded"] >= 5)
    r = client.post("/capture/stop")
    assert r.status_code == 202, r.text
    assert r.json()["state"] in ("stopping", "done")
    status = wait_capture(client)
    assert status["state"] == "done", status["error"]
    assert status["stopped"] and 5 <= status["frames_recorded"] < 2000
    capture = client.get(f"/captures/{status['capture_id']}").json()
    assert 0 < capture["frames"] <= status["frames_recorded"]
    r = client.post("/jobs", json={"capture_id": status["capture_id"], "method": "ba"})
    assert r.status_code == 202, r.text

    r = client.post("/capture/stop")  # the capture has ended: nothing to stop
    assert r.status_code == 409


def test_stop_with_nothing_running(client):
    r = client.post("/capture/stop")
    assert r.status_code == 409
    assert "no live capture is running" in r.json()["detail"]
    assert client.get("/capture").json()["state"] == "idle"


@pytest.mark.parametrize(
    "body, named",
    [
        ({"cameras": ["gige://10.0.0.7"], "frames": 10}, "gige://10.0.0.7"),
        ({"cameras": [SIM_URL], "trigger": "/dev/wandcal-no-such-port", "frames": 10}, "/dev/wandcal-no-such-port"),
        ({"cameras": [SIM_URL], "trigger": "socket://10.0.0.7:7000", "frames": 10}, "socket://10.0.0.7:7000"),
        ({"cameras": [SIM_URL], "frames": 10, "out": "/tmp/elsewhere"}, "out"),
        ({"cameras": [SIM_URL], "frames": 0}, "frames"),
    ],
)
def test_refused_starts_name_the_problem_and_change_nothing(client, body, named):
    r = client.post("/capture/start", json=body)
    assert r.status_code == 422, r.text
    assert named in r.json()["detail"]
    assert client.get("/capture").json()["state"] == "idle"


@pytest.mark.parametrize("url", ["replay:///etc", "opencv:/etc/passwd", "opencv:rtsp://10.0.0.1/stream", "v4l2:///etc/passwd"])
def test_camera_urls_that_would_read_outside_the_server_are_refused(client, url):
    r = client.post("/capture/start", json={"cameras": [url], "frames": 5})
    assert r.status_code == 422
    assert url in r.json()["detail"]
