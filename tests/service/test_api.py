"""The API in-process (``TestClient``, no worker processes; ``drain()`` runs the queue)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.service.conftest import capture_files, simulated_capture
from wandcal.calib.sim.render import render_blobs
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import read_capture, rig_to_json, write_capture
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.jobs.records import MAX_ATTEMPTS, JobState, JobStore
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

# Detection of a rendered spot without read noise is exact to a few hundredths of a pixel
# (wandcal.calib.detect's own tests); 0.05 px is that bound.
DETECT_TOL_PX = 0.05


@pytest.fixture
def app_client(tmp_path):
    (tmp_path / "replay").mkdir()

    def make(**overrides):
        settings = Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0, **overrides)
        app = create_app(settings)
        client = TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False)
        client.__enter__()
        clients.append(client)
        return app, client

    clients = []
    yield make
    for c in clients:
        c.__exit__(None, None, None)


def upload(client, folder) -> dict:
    r = client.post("/captures", files=capture_files(folder))
    assert r.status_code == 201, r.text
    return r.json()


def test_bad_requests_get_4xx_naming_the_problem(app_client, small_capture, tmp_path):
    folder, sim = small_capture
    app, c = app_client(max_upload_bytes=200_000)
    capture = upload(c, folder) if (folder / WAND_FILE).stat().st_size < 200_000 else None
    checks = []

    r = c.post("/jobs", content=b'{"capture_id": ', headers={"content-type": "application/json"})
    checks.append((r, 422, "not valid JSON"))
    r = c.post("/jobs", content=b"capture_id=x", headers={"content-type": "text/plain"})
    checks.append((r, 415, "Content-Type must be application/json"))
    r = c.post("/captures", json={"path": "x"})
    checks.append((r, 415, "Content-Type must be multipart/form-data"))
    checks.append((c.get("/captures/0123456789abcdef0123456789abcdef"), 404, "no capture with id"))
    checks.append((c.get("/captures/../../etc/passwd"), 404, "Not Found"))
    checks.append((c.post("/jobs", json={"capture_id": "nope"}), 404, "no capture with id 'nope'"))
    checks.append((c.post("/jobs", json={"capture_id": "x", "method": "magic"}), 422, "method"))
    checks.append((c.post("/jobs", json={"capture_id": "x", "colour": 1}), 422, "colour"))
    checks.append((c.get("/jobs/nope"), 404, "no job with id"))
    huge = {RIG_FILE: (RIG_FILE, b"{}"), WAND_FILE: (WAND_FILE, b"0" * 300_000)}
    checks.append((c.post("/captures", files=huge), 413, "larger than this server's limit of 200000 bytes"))
    checks.append((c.post("/captures", data={"path": "../../etc"}), 403, "outside the replay root"))
    checks.append((c.post("/captures", data={"path": "/etc"}), 403, "outside the replay root"))
    checks.append((c.post("/captures", data={"path": "missing"}), 422, "no such folder"))
    checks.append((c.post("/captures", files={"wand.csv": ("wand.csv", b"frame,camera,u,v\n")}), 422, "rig.json"))
    checks.append((c.post("/captures", files={RIG_FILE: (RIG_FILE, b"{not json")}), 422, "rig.json: not valid JSON"))
    rig_doc = rig_to_json(sim.rig)
    one = dict(rig_doc, cameras=rig_doc["cameras"][:1])
    checks.append((c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(one).encode())}), 422, "at least two"))
    bad_csv = b"frame,camera,u,v\n0,cam1,10,20\n1,cam9,3,4\n"
    files = {RIG_FILE: (RIG_FILE, json.dumps(rig_doc).encode()), WAND_FILE: (WAND_FILE, bad_csv)}
    checks.append((c.post("/captures", files=files), 422, "wand.csv line 3: unknown camera id 'cam9'"))
    # a capture in which only one camera saw the wand cannot be calibrated
    lonely = b"frame,camera,u,v\n" + b"".join(f"{f},cam1,{100 + f},{200 + f}\n".encode() for f in range(50))
    files = {RIG_FILE: (RIG_FILE, json.dumps(rig_doc).encode()), WAND_FILE: (WAND_FILE, lonely)}
    lonely_id = c.post("/captures", files=files).json()["id"]
    checks.append((c.post("/jobs", json={"capture_id": lonely_id}), 422, "only camera 'cam1' saw the wand"))
    empty_id = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_doc).encode())}).json()["id"]
    checks.append((c.post("/jobs", json={"capture_id": empty_id}), 422, "no camera has wand observations"))
    if capture is not None:
        job = c.post("/jobs", json={"capture_id": capture["id"]}).json()
        checks.append((c.get(f"/jobs/{job['id']}/result"), 409, "is queued, it has no result"))
        checks.append((c.get(f"/jobs/{job['id']}/result", params={"format": "pdf"}), 422, "format"))
    for response, status, words in checks:
        assert response.status_code == status, (response.request.url, response.text)
        assert words in response.json()["detail"], (response.request.url, response.text)
    # nothing was written outside the data directory's captures
    assert not (tmp_path / "etc").exists()


def test_job_lifecycle_drain_cancel_and_exports(app_client, small_capture):
    folder, sim = small_capture
    app, c = app_client()
    capture = upload(c, folder)
    first = c.post("/jobs", json={"capture_id": capture["id"], "method": "ba"}).json()
    second = c.post("/jobs", json={"capture_id": capture["id"], "options": {"use_static": False}}).json()
    assert first["state"] == "queued" and first["attempts"] == 0
    cancelled = c.delete(f"/jobs/{second['id']}").json()
    assert cancelled["state"] == "cancelled"
    removed = c.delete(f"/jobs/{second['id']}")  # finished (cancelled): a second DELETE removes it
    assert removed.status_code == 200 and removed.json()["state"] == "cancelled"
    assert "Wandcal-Kept-Result" not in removed.headers
    assert c.get(f"/jobs/{second['id']}").status_code == 404 and c.delete(f"/jobs/{second['id']}").status_code == 404
    ran = app.state.wandcal.queue.drain()
    assert [j.id for j in ran] == [first["id"]]
    job = c.get(f"/jobs/{first['id']}").json()
    assert job["state"] == "done" and job["attempts"] == 1 and job["finished"] >= job["started"]
    assert job["result"]["format"] == "wandcal-result/1"
    assert [cam["id"] for cam in job["result"]["cameras"]] == sim.rig.ids
    toml = c.get(f"/jobs/{first['id']}/result", params={"format": "anipose-toml", "unit": "mm"})
    assert toml.headers["content-type"].startswith("application/toml")
    import tomllib

    doc = tomllib.loads(toml.text)
    assert doc["cam_0"]["name"] == "cam1"
    np.testing.assert_allclose(np.array(doc["cam_0"]["translation"]) / 1000, job["result"]["cameras"][0]["t"])
    yaml = c.get(f"/jobs/{first['id']}/result", params={"format": "opencv-yaml"})
    assert yaml.status_code == 200 and yaml.text.startswith("%YAML:1.0")
    assert len(c.get(f"/jobs/{first['id']}/result", params={"format": "dlt-csv"}).text.splitlines()) == 11
    assert c.get("/health").json()["jobs_queued"] == 0


def test_a_finished_job_is_deleted_with_or_without_its_result(app_client, small_capture):
    folder, _ = small_capture
    app, c = app_client()
    capture = upload(c, folder)
    kept_id, gone_id = (c.post("/jobs", json={"capture_id": capture["id"]}).json()["id"] for _ in range(2))
    app.state.wandcal.queue.drain()
    data_dir = app.state.wandcal.settings.data_dir
    result = c.get(f"/jobs/{kept_id}").json()["result"]
    assert c.get(f"/jobs/{kept_id}/report").status_code == 200  # drawn, so its folder exists
    answer = c.delete(f"/jobs/{kept_id}", params={"keep_result": True})
    assert answer.status_code == 200 and answer.json()["state"] == "done"
    kept = data_dir / answer.headers["Wandcal-Kept-Result"]
    assert kept == data_dir / "results" / f"{kept_id}.json" and json.loads(kept.read_text()) == result
    assert not (data_dir / "reports" / kept_id).exists()
    assert c.delete(f"/jobs/{gone_id}").status_code == 200 and not (data_dir / "results" / f"{gone_id}.json").exists()
    listed = [j["id"] for j in c.get("/jobs").json()["jobs"]]
    assert kept_id not in listed and gone_id not in listed
    assert c.get(f"/jobs/{kept_id}").status_code == 404


def test_running_job_is_requeued_once_then_failed(app_client, small_capture):
    folder, _ = small_capture
    app, c = app_client()
    capture = upload(c, folder)
    job_id = c.post("/jobs", json={"capture_id": capture["id"]}).json()["id"]
    store: JobStore = app.state.wandcal.queue.store
    for attempt in range(1, MAX_ATTEMPTS + 1):
        claim = store.claim(worker_pid=1)
        assert claim.job.id == job_id and claim.job.attempts == attempt
        store.recover("the server stopped while the job was running")
    job = store.get(job_id)
    assert job.state is JobState.failed
    assert "the server stopped while the job was running during attempt 2 of 2" in job.error
    # a stale worker of an earlier attempt cannot write an outcome
    assert not store.finish(job_id, claim.token, JobState.done, result={"x": 1})


def _frameset_files(sim, frame: int) -> tuple[dict, dict[str, np.ndarray]]:
    files, truth = {}, {}
    for i, cam in enumerate(sim.rig.cameras):
        rows = (sim.wand.frame == frame) & (sim.wand.camera == i)
        uv = sim.wand.uv[rows]
        image = render_blobs((cam.height, cam.width), uv, sigma_px=1.5, peak=200.0)
        files[cam.id] = (f"{cam.id}.png", cv2.imencode(".png", image)[1].tobytes(), "image/png")
        truth[cam.id] = uv
    return files, truth


def test_stream_framesets_detects_and_appends_wand_rows(app_client, tmp_path):
    sim = simulate_capture(cameras=3, frames=6, noise_px=0.3, seed=2, occlusion=0.2)
    app, c = app_client(framesets_per_second=1000)
    rig_only = {RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())}
    capture = c.post("/captures", files=rig_only).json()
    assert capture["source"] == "stream" and capture["frames"] == 0
    expected_rows = []
    for frame in range(6):
        files, truth = _frameset_files(sim, frame)
        r = c.post(f"/captures/{capture['id']}/framesets", data={"frame": str(frame), "trigger_count": "7"}, files=files)
        assert r.status_code == 201, r.text
        assert r.json()["blobs"] == {cid: len(uv) for cid, uv in truth.items()}
        expected_rows += [(frame, cid, uv) for cid, uv in truth.items() if len(uv) == 2]
    files, _ = _frameset_files(sim, 0)
    assert c.post(f"/captures/{capture['id']}/framesets", data={"frame": "0"}, files=files).status_code == 409
    bad = c.post(f"/captures/{capture['id']}/framesets", data={"frame": "9"}, files={"camX": ("x.png", b"x")})
    assert bad.status_code == 422 and "'camX' is not a camera" in bad.json()["detail"]
    small = cv2.imencode(".png", np.zeros((10, 10), np.uint8))[1].tobytes()
    bad = c.post(f"/captures/{capture['id']}/framesets", data={"frame": "9"}, files={"cam1": ("x.png", small)})
    assert bad.status_code == 422 and "is 10x10 but rig.json says 1280x1024" in bad.json()["detail"]

    stored = read_capture(app.state.wandcal.captures.folder(capture["id"]))
    assert len(stored.wand) == 2 * len(expected_rows)
    for frame, cid, uv in expected_rows:
        got = stored.wand.uv[(stored.wand.frame == frame) & (stored.wand.camera == sim.rig.index(cid))]
        # blobs come back sorted by row; match each true spot to its nearest detection
        dist = np.linalg.norm(got[:, None] - uv[None], axis=2).min(axis=0)
        assert dist.max() < DETECT_TOL_PX
    summary = c.get(f"/captures/{capture['id']}").json()
    assert summary["framesets"] == 6
    pairs = {cov["id"]: cov["pairs"] for cov in summary["coverage"]}
    assert pairs == {cid: sum(1 for _, k, _ in expected_rows if k == cid) for cid in sim.rig.ids}
    assert sum(summary["coverage"][0]["framesets"].values()) == 6


def test_frameset_rate_limit_answers_429(app_client):
    sim = simulate_capture(cameras=2, frames=3, seed=4)
    app, c = app_client(framesets_per_second=1)
    capture = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())}).json()
    files, _ = _frameset_files(sim, 0)
    assert c.post(f"/captures/{capture['id']}/framesets", data={"frame": "0"}, files=files).status_code == 201
    r = c.post(f"/captures/{capture['id']}/framesets", data={"frame": "1"}, files=files)
    assert r.status_code == 429 and "faster than 1 per second" in r.json()["detail"]
    assert int(r.headers["retry-after"]) >= 1


def test_static_pnp_from_static_csv(app_client, small_capture):
    folder, sim = small_capture
    app, c = app_client()
    capture = upload(c, folder)
    r = c.post(f"/captures/{capture['id']}/static")
    assert r.status_code == 200, r.text
    cams = r.json()["cameras"]
    assert [cam["id"] for cam in cams] == sim.rig.ids
    solved = [i for i, cam in enumerate(cams) if cam["ok"]]
    assert solved, cams
    for i in solved:
        assert cams[i]["rms_px"] < 1.0  # static blobs carry 0.06 px of noise
        # PnP on a 0.5 m L-frame from ~4.5 m: depth error ~z^2 sigma/(f L) = 2.4 mm; 3 cm bounds it
        assert np.linalg.norm(np.array(cams[i]["center"]) - sim.truth.centers[i]) < 0.03
    for cam in cams:
        assert cam["ok"] or cam["reason"]
    assert c.get(f"/captures/{capture['id']}").json()["static_solution"]["cameras"] == cams


def test_replay_copies_the_folder_into_the_data_dir(app_client, small_capture, tmp_path):
    folder, sim = small_capture
    write_capture(tmp_path / "replay" / "session1", sim.rig, sim.wand, sim.static)
    app, c = app_client()
    r = c.post("/captures", data={"path": "session1"})
    assert r.status_code == 201, r.text
    stored = app.state.wandcal.captures.folder(r.json()["id"])
    assert stored.is_relative_to((tmp_path / "data").resolve())
    assert (stored / WAND_FILE).read_text() == (tmp_path / "replay" / "session1" / WAND_FILE).read_text()


def test_settings_from_toml_and_env(tmp_path, monkeypatch):
    config = tmp_path / "wandcal.toml"
    config.write_text('data_dir = "/srv/wandcal"\nworkers = 3\nframesets_per_second = 30.0\n')
    monkeypatch.setenv("WANDCAL_WORKERS", "2")
    settings = Settings.load(config)
    assert str(settings.data_dir) == "/srv/wandcal" and settings.framesets_per_second == 30.0
    assert settings.workers == 2  # the environment overrides the file
    assert Settings.load(config, workers=5).workers == 5
    with pytest.raises(FileNotFoundError, match="not found"):
        Settings.load(tmp_path / "missing.toml")
    assert Settings(host="127.0.0.1").loopback and Settings(host="::1").loopback
    assert not Settings(host="0.0.0.0").loopback


def test_sync_job_options_reach_the_solver_and_bad_ones_get_422(app_client, tmp_path):
    """The command line's --sync-max-offset, --sync-drift and the frame rate as job options: a camera
    2.5 frames late is found in a search window of 4 frames, its offset reported in seconds at the
    rate given; out-of-range values are refused with a 422 naming the option. The guidance takes
    the same mode: under auto cam3's frames are realigned, under none it is a camera out of time."""
    folder, _ = simulated_capture(tmp_path / "late", cameras=4, frames=400, noise_px=0.3, static=False, seed=5,
                                  offsets=np.array([0.0, 0.0, 2.5, 0.0]))
    app, c = app_client()
    capture = upload(c, folder)
    auto = c.get(f"/captures/{capture['id']}/guidance", params={"sync": "auto"}).json()
    none = c.get(f"/captures/{capture['id']}/guidance").json()
    assert set(auto["solve"]["offsets"]) == {"cam3"} and not auto["solve"]["out_of_time"]
    assert set(none["solve"]["out_of_time"]) == {"cam3"} and none["solve"]["offsets"] is None
    r = c.get(f"/captures/{capture['id']}/guidance", params={"sync": "sometimes"})
    assert r.status_code == 422 and "sync" in r.text
    for bad in ({"frame_rate_hz": 0}, {"sync_max_offset": 0}, {"sync_drift": "sometimes"}):
        r = c.post("/jobs", json={"capture_id": capture["id"], "options": {"sync": "auto"} | bad})
        assert r.status_code == 422 and next(iter(bad)) in r.text, r.text
    options = {"sync": "auto", "sync_max_offset": 4, "sync_drift": True, "frame_rate_hz": 100.0}
    job = c.post("/jobs", json={"capture_id": capture["id"], "options": options}).json()
    app.state.wandcal.queue.drain()
    job = c.get(f"/jobs/{job['id']}").json()
    assert job["state"] == "done", job["error"]
    sync = job["result"]["sync"]
    assert sync["rate_hz"] == 100.0
    late = next(cam for cam in sync["cameras"] if cam["id"] == "cam3")
    assert late["out_of_time"] and late["offset_s"] == pytest.approx(late["offset_frames"] / 100.0)
    assert all(cam["drift_ppm"] is not None for cam in sync["cameras"])  # --sync-drift's estimate
