"""The service's ``[detect]`` settings group: read from TOML and the environment, validated by
``DetectConfig``'s rules, and used by frame-set and static-image detection."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from wandcal.calib.detect import DetectConfig
from wandcal.calib.sim.render import render_blobs
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import rig_to_json
from wandcal.drivers.capture_files import RIG_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings, SettingsError

SPOTS = np.array([[300.0, 400.0], [900.5, 610.2]])  # two wand markers in a 1280x1024 frame


@pytest.fixture
def serve(tmp_path):
    clients = []

    def make(**overrides):
        app = create_app(Settings(data_dir=tmp_path / f"data{len(clients)}", workers=0, framesets_per_second=1000,
                                  **overrides))
        client = TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False)
        client.__enter__()
        clients.append(client)
        return client

    yield make
    for c in clients:
        c.__exit__(None, None, None)


def _glare_frameset(rig) -> dict:
    """One image per camera: the two markers on a background that glows from 20 to 120 grey."""
    rng = np.random.default_rng(1)
    files = {}
    for cam in rig.cameras:
        image = render_blobs((cam.height, cam.width), SPOTS, 1.5, 150.0, 20.0, 2.0, 8, rng).astype(float)
        image += np.linspace(0.0, 100.0, cam.width)[None, :]
        image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
        files[cam.id] = (f"{cam.id}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png")
    return files


def _blobs(client, rig) -> dict:
    capture = client.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(rig)).encode())}).json()
    r = client.post(f"/captures/{capture['id']}/framesets", data={"frame": "0"}, files=_glare_frameset(rig))
    assert r.status_code == 201, r.text
    return r.json()["blobs"]


def test_streamed_frame_sets_are_detected_with_the_detect_settings(serve):
    rig = simulate_capture(2, 3, seed=3).rig
    assert set(_blobs(serve(), rig).values()) == {2}  # defaults: "auto" sees the uneven background
    # One threshold for the whole glowing frame takes the bright side for a blob: no wand frame.
    assert set(_blobs(serve(detect={"background": "none"}), rig).values()) != {2}
    assert set(_blobs(serve(detect={"threshold": 255}), rig).values()) == {0}


def test_detect_settings_from_toml_and_environment(tmp_path, monkeypatch):
    monkeypatch.delenv("WANDCAL_DETECT", raising=False)
    assert Settings().detect.config() == DetectConfig()  # no settings: the detector's own defaults
    config = tmp_path / "wandcal.toml"
    config.write_text('workers = 1\n\n[detect]\nthreshold = 9\nseed_ratio = 2.0\nweights = "signal"\n')
    settings = Settings.load(config)
    assert settings.detect.config() == DetectConfig(threshold=9, seed_ratio=2.0, weights="signal")
    monkeypatch.setenv("WANDCAL_DETECT", json.dumps({"background": "highpass", "highpass_px": 6}))
    assert Settings.load().detect.config() == DetectConfig(background="highpass", highpass_px=6)
    monkeypatch.setenv("WANDCAL_DETECT", json.dumps({"min_area_px": 9, "max_area_px": 5}))
    # a wrong setting is refused naming it (SettingsError, the CLI's exit 2), not a pydantic traceback
    with pytest.raises(SettingsError, match="max_area_px must be a whole number >= min_area_px"):
        Settings.load()
    monkeypatch.setenv("WANDCAL_DETECT", json.dumps({"background": "running"}))
    with pytest.raises(SettingsError, match="background"):
        Settings.load()
