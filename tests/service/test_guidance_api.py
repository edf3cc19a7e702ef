"""``GET /captures/{id}/guidance`` for uploaded and streamed captures (in-process ``TestClient``)."""

from __future__ import annotations

import json

import pytest

from tests.service.test_api import _frameset_files, app_client, upload  # noqa: F401 (app_client: a fixture)
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import rig_to_json
from wandcal.drivers.capture_files import RIG_FILE

STREAMED_SETS = 40


def test_guidance_of_an_uploaded_capture(app_client, small_capture):  # noqa: F811 (the fixture imported above)
    folder, sim = small_capture
    app, c = app_client()
    capture = upload(c, folder)
    r = c.get(f"/captures/{capture['id']}/guidance")
    assert r.status_code == 200, r.text
    doc = r.json()
    assert doc["format"] == "wandcal-guidance/1" and not doc["live"] and doc["solve"]["ok"]
    assert [cam["id"] for cam in doc["cameras"]] == sim.rig.ids
    pairs = {cov["id"]: cov["pairs"] for cov in capture["coverage"]}
    assert {cam["id"]: cam["frames"] for cam in doc["cameras"]} == pairs
    assert all(cam["center_std_mm"] > 0 and len(cam["grid"]) == 8 for cam in doc["cameras"])
    # the simulated path stays in the middle of each view: every camera is sent to its gaps
    assert not doc["enough"] and len(doc["advice"]) == 4
    again = c.get(f"/captures/{capture['id']}/guidance").json()
    assert again["updated"] == doc["updated"]  # nothing changed: the cached document
    r = c.get(f"/captures/{'0' * 32}/guidance")
    assert r.status_code == 404 and "no capture with id" in r.json()["detail"]
    r = c.get("/captures/not-an-id/guidance")
    assert r.status_code == 404


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
def test_guidance_of_a_streamed_capture_follows_the_frame_sets(app_client):  # noqa: F811 (the fixture imported above)
    sim = simulate_capture(cameras=3, frames=STREAMED_SETS, noise_px=0.3, seed=2, occlusion=0.0)
    # no wait between updates, so each request sees the frame sets sent before it
    app, c = app_client(framesets_per_second=1000, guidance={"update_interval_s": 1e-3})
    capture = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())}).json()
    empty = c.get(f"/captures/{capture['id']}/guidance").json()
    assert empty["frames"] == 0 and not empty["enough"] and not empty["solve"]["ok"]
    docs = []
    for frame in range(STREAMED_SETS):
        files, _ = _frameset_files(sim, frame)
        assert c.post(f"/captures/{capture['id']}/framesets", data={"frame": str(frame)}, files=files).status_code == 201
        if frame + 1 in (STREAMED_SETS // 2, STREAMED_SETS):
            docs.append(c.get(f"/captures/{capture['id']}/guidance").json())
    half, full = docs
    stored = c.get(f"/captures/{capture['id']}").json()
    assert full["frames"] == stored["frames"] > half["frames"] > 0
    assert half["solve"]["ok"] and full["solve"]["ok"] and full["solve"]["warm_start"]
    for a, b in zip(half["cameras"], full["cameras"]):
        assert b["center_std_mm"] < a["center_std_mm"]


def test_stop_when_enough_needs_a_running_capture(app_client):  # noqa: F811 (the fixture imported above)
    app, c = app_client()
    r = c.patch("/capture", json={"stop_when_enough": True})
    assert r.status_code == 409 and "no live capture is running" in r.json()["detail"]
    r = c.patch("/capture", json={"stop_when_enough": "sometimes"})
    assert r.status_code == 422
