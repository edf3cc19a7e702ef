"""Live capture over HTTP: start, watch, stop, and the capture it leaves for ``POST /jobs``."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.service.conftest import wait_job
from wandcal.drivers.registry import open_cameras
from wandcal.drivers.trigger_emulator import EmulatorProcess
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

SIM_URL = "sim://?cameras=3&seed=2&frames=60&static=10"
WAND_SETS, STATIC_SETS = 60, 10
# A long simulated run (40 s at 50 Hz) that the tests stop after a few sets.
LONG_URL = "sim://?cameras=3&seed=2&frames=2000"
LONG_RATE_HZ = 50.0
CAPTURE_TIMEOUT_S = 180.0  # a poll's limit, not a speed claim: CI's busy 2-core machine needed over 60 s (decision 0109)
# The rendered blobs are found to a few hundredths of a pixel (wandcal.calib.detect's tests: 0.05 px).
# The world frame comes from PnP on the L-frame (0.5 m arm) seen from ~4.5 m at f ~1000 px: its
# depth error z^2 * sigma / (f * arm) is ~2 mm, and its tilt moves the centres about as much again.
DETECT_PX, RANGE_M, FOCAL_PX, ARM_M = 0.05, 4.5, 1000.0, 0.5
ABSOLUTE_TOL_M = 2 * RANGE_M**2 * DETECT_PX / (FOCAL_PX * ARM_M)
ENDED = ("done", "failed")
PAUSED_RATE_HZ = 200.0
# Guidance: a long triggered run that the guidance ends. The simulated wand path keeps to the
# middle of each view (about a quarter of it covered), so the goal here is a tenth of the image
# and a 1 mm centre, met after a few hundred sets; updates four times a second to be seen often.
GUIDED_URL = "sim://?cameras=4&seed=2&frames=3000&static=10"
GUIDED_SETS, GUIDED_RATE_HZ = 3000, 100.0
LOOSE_GUIDANCE = {"target_std_mm": 1.0, "min_coverage": 0.1, "update_interval_s": 0.25}
SIGMA_SCATTER = 0.03  # the subsampled sigma estimate scatters 0.7-2.0% about the full solve's (decision 0010); a short live take, a little more
GUIDANCE_UPDATES = 3  # distinct solved updates watched over HTTP before the automatic stop is switched on


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
        if c.get("/capture").json()["state"] in ("running", "waiting_for_wand", "stopping"):
            c.post("/capture/stop")
            wait_capture(c)


def test_live_capture_over_http_then_calibrate(make_server, tmp_path):
    server = make_server(workers=1).start()
    with server.client() as c:
        assert c.get("/capture").json()["state"] == "idle"
        # a scripted run asks for no pause after the static object; 50 sets a second, which three simulated cameras
        # keep up with on a busy 2-core machine (at 200 one dropped 12 of 70 frames there, session 23)
        r = c.post("/capture/start", json={"cameras": [SIM_URL], "trigger": None, "frames": WAND_SETS,
                                           "static_frames": STATIC_SETS, "rate_hz": 50, "pause_after_static": False})
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


def start_triggered(c, emu: EmulatorProcess) -> dict:
    """Start a triggered capture with static frames (it pauses after them by default)."""
    r = c.post("/capture/start", json={"cameras": [SIM_URL], "trigger": emu.url, "frames": WAND_SETS,
                                       "static_frames": STATIC_SETS, "rate_hz": PAUSED_RATE_HZ})
    assert r.status_code == 202, r.text
    return r.json()


def start_paused(c, emu: EmulatorProcess) -> tuple[dict, dict]:
    """A triggered capture with static frames: its start answer and its status once it waits for the wand."""
    started = start_triggered(c, emu)
    waiting = wait_capture(c, until=("waiting_for_wand", *ENDED))
    assert waiting["state"] == "waiting_for_wand", waiting["error"]
    return started, waiting


def test_capture_pauses_after_the_static_object_until_continue(make_server):
    server = make_server(workers=0).start()
    with EmulatorProcess() as emu, server.client() as c:
        r = c.post("/capture/continue")  # nothing is waiting yet
        assert r.status_code == 409 and "waiting for the wand" in r.json()["detail"]
        started, waiting = start_paused(c, emu)
        assert waiting["phase"] == "waiting" and waiting["frames_recorded"] == STATIC_SETS
        assert "remove the L-frame" in waiting["prompt"] and "press Continue" in waiting["prompt"]
        assert "POST" not in waiting["prompt"]  # words for the operator, not for a program
        assert waiting["wait_deadline"] > waiting["started"]
        # nothing more is recorded while the operator swaps the L-frame for the wand
        assert c.get("/capture").json()["frames_recorded"] == STATIC_SETS

        r = c.post("/capture/continue")
        assert r.status_code == 202, r.text
        assert r.json()["state"] == "running" and r.json()["prompt"] is None
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]
        assert status["frames_recorded"] == STATIC_SETS + WAND_SETS and not status["stopped"]
        r = c.post("/capture/continue")  # ended: nothing to continue
        assert r.status_code == 409 and "done" in r.json()["detail"]

        capture = c.get(f"/captures/{started['capture_id']}").json()
        assert capture["has_static"] and 0 < capture["frames"] <= WAND_SETS


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_free_running_cameras_pause_until_continue_too(make_server):
    server = make_server(workers=0).start()
    with server.client() as c:
        r = c.post("/capture/start", json={"cameras": [SIM_URL], "trigger": None, "frames": WAND_SETS,
                                           "static_frames": STATIC_SETS, "rate_hz": PAUSED_RATE_HZ})
        assert r.status_code == 202, r.text
        waiting = wait_capture(c, until=("waiting_for_wand", *ENDED))
        assert waiting["state"] == "waiting_for_wand", waiting["error"]
        assert waiting["frames_recorded"] == STATIC_SETS and "remove the L-frame" in waiting["prompt"]
        r = c.post("/capture/continue")
        assert r.status_code == 202, r.text
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]
        # the cameras were drained in the pause; the simulated script held, so every wand set came
        assert status["frames_recorded"] == STATIC_SETS + WAND_SETS
        assert status["dropped"] == {"cam1": 0, "cam2": 0, "cam3": 0}


def test_stop_while_waiting_keeps_the_static_recording(make_server):
    server = make_server(workers=0).start()
    with EmulatorProcess() as emu, server.client() as c:
        started, _ = start_paused(c, emu)
        r = c.post("/capture/stop")
        assert r.status_code == 202, r.text
        assert r.json()["state"] in ("stopping", "done")
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]
        assert status["stopped"] and status["frames_recorded"] == STATIC_SETS
        assert status["capture_id"] == started["capture_id"]
        assert any("only the static object was recorded" in m for m in status["messages"])

        capture = c.get(f"/captures/{started['capture_id']}").json()
        assert capture["has_static"] and capture["frames"] == 0
        # the kept static recording is good for what it is for: each camera's pose from the L-frame
        solution = c.post(f"/captures/{started['capture_id']}/static").json()
        assert [cam["ok"] for cam in solution["cameras"]] == [True] * len(capture["cameras"]), solution
        r = c.post("/jobs", json={"capture_id": started["capture_id"]})
        assert r.status_code == 422  # no wand sets to calibrate


def test_no_continue_in_time_fails_and_keeps_the_static_recording(make_server):
    server = make_server(workers=0, capture_continue_timeout_s=0.5).start()
    with EmulatorProcess() as emu, server.client() as c:
        started = start_triggered(c, emu)
        status = wait_capture(c)  # the wait may be over before a poll sees it
        assert status["state"] == "failed"
        assert "capture_continue_timeout_s" in status["error"] and started["capture_id"] in status["error"]
        assert status["capture_id"] == started["capture_id"] and not status["stopped"]
        assert c.get(f"/captures/{started['capture_id']}").json()["has_static"]
        r = c.post("/capture/continue")
        assert r.status_code == 409 and "failed" in r.json()["detail"]


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


def start_guided(c, emu: EmulatorProcess) -> dict:
    """Start the long triggered capture that the guidance is to end."""
    r = c.post("/capture/start", json={"cameras": [GUIDED_URL], "trigger": emu.url, "frames": GUIDED_SETS,
                                       "static_frames": 10, "rate_hz": GUIDED_RATE_HZ, "pause_after_static": False,
                                       "images": "none"})
    assert r.status_code == 202, r.text
    return r.json()


def watch_guidance(c, capture_id: str, updates: int = GUIDANCE_UPDATES) -> list[dict]:
    """Poll the live capture's guidance until ``updates`` distinct solved documents were seen."""
    seen = []
    deadline = time.monotonic() + CAPTURE_TIMEOUT_S
    while len(seen) < updates and time.monotonic() < deadline:
        r = c.get(f"/captures/{capture_id}/guidance")  # the capture is not stored yet: the live document
        assert r.status_code == 200, r.text
        doc = r.json()
        assert doc["live"]
        if doc["solve"]["ok"] and (not seen or doc["updated"] != seen[-1]["updated"]):
            seen.append(doc)
        time.sleep(0.05)
    assert len(seen) == updates, "the guidance did not update while recording"
    return seen


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_guidance_changes_over_http_while_recording_and_can_end_the_capture(make_server):
    server = make_server(workers=0, guidance=json.dumps(LOOSE_GUIDANCE)).start()
    with EmulatorProcess() as emu, server.client() as c:
        started = start_guided(c, emu)
        assert started["images"] == "none" and not started["stop_when_enough"]
        capture_id = started["capture_id"]
        updates = watch_guidance(c, capture_id)
        assert c.get("/capture").json()["state"] == "running"
        frames = [d["frames"] for d in updates]
        assert frames == sorted(frames) and frames[-1] > frames[0]
        first, last = (np.array([cam["center_std_mm"] for cam in d["cameras"]]) for d in (updates[0], updates[-1]))
        # the rig's predicted sigma falls as the sets arrive; a camera that saw few of the new sets may hold
        # level within the subsampled estimate's own scatter (2% at 16 x 2500, decision 0010)
        assert np.median(last) < np.median(first) and np.all(last < first * (1 + SIGMA_SCATTER)), (first, last)

        r = c.patch("/capture", json={"stop_when_enough": True})
        assert r.status_code == 200 and r.json()["stop_when_enough"]
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]
        assert status["enough"] and not status["stopped"] and status["frames_recorded"] < GUIDED_SETS + 10
        assert any("the guidance says enough" in m for m in status["messages"])

        stored = c.get(f"/captures/{capture_id}/guidance").json()  # now from the stored capture
        assert not stored["live"] and stored["enough"] and stored["frames"] >= updates[-1]["frames"]
        assert c.get(f"/captures/{capture_id}").json()["frames"] == stored["frames"]
