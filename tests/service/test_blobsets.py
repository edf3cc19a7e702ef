"""POST /captures/{id}/blobsets: frame sets streamed as centroids, many per request."""

from __future__ import annotations

import json

import numpy as np

from tests.service.conftest import capture_files, wait_job
from tests.service.test_api import app_client  # noqa: F401 (a fixture)
from tests.service.test_http import SHAPE_TOL_M
from wandcal.calib.geometry import kabsch
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import read_capture, rig_to_json
from wandcal.drivers.capture_files import RIG_FILE
from wandcal.service.schemas import MAX_BLOB_SETS, MAX_BLOBS_PER_CAMERA


def blob_sets(sim, frames) -> list[dict]:
    """The simulated capture's wand blobs as the request's sets (cameras that saw nothing left out)."""
    w, ids = sim.wand, sim.rig.ids
    sets = []
    for f in frames:
        rows = np.flatnonzero(w.frame == f)
        blobs: dict[str, list] = {}
        for r in rows:
            blobs.setdefault(ids[w.camera[r]], []).append([float(u) for u in w.uv[r]])
        sets.append({"frame": int(f), "trigger_count": int(f) + 1000, "blobs": blobs})
    return sets


def stream_capture(c, sim) -> str:
    r = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_blob_sets_become_the_capture_an_upload_would_be(app_client):  # noqa: F811
    sim = simulate_capture(cameras=3, frames=120, noise_px=0.3, seed=4, occlusion=0.2, static=False)
    app, c = app_client()
    capture_id = stream_capture(c, sim)
    frames = np.unique(sim.wand.frame)
    for batch in np.array_split(frames, 3):
        r = c.post(f"/captures/{capture_id}/blobsets", json={"sets": blob_sets(sim, batch)})
        assert r.status_code == 201, r.text
        assert r.json()["stored"] == len(batch)
    summary = c.get(f"/captures/{capture_id}").json()
    assert summary["framesets"] == len(frames)
    stored = read_capture(app.state.wandcal.captures.folder(capture_id)).wand
    # a camera-frame with exactly two blobs is a wand observation; others (occluded ends) are not
    key = sim.wand.frame * 10 + sim.wand.camera
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    pair = counts[inverse] == 2
    order = lambda f, cam, uv: np.lexsort((uv[:, 1], uv[:, 0], cam, f))  # noqa: E731
    want = order(sim.wand.frame[pair], sim.wand.camera[pair], sim.wand.uv[pair])
    got = order(stored.frame, stored.camera, stored.uv)
    assert stored.frame[got].tolist() == sim.wand.frame[pair][want].tolist()
    assert stored.camera[got].tolist() == sim.wand.camera[pair][want].tolist()
    np.testing.assert_allclose(stored.uv[got], sim.wand.uv[pair][want], atol=5e-5)  # wand.csv's 4 decimals
    pairs = {cov["id"]: cov["pairs"] for cov in summary["coverage"]}
    assert sum(pairs.values()) == int(pair.sum()) // 2
    guidance = c.get(f"/captures/{capture_id}/guidance").json()
    assert guidance["frames"] == summary["frames"] > 0


def test_bad_blob_sets_are_refused_whole_with_the_set_and_camera_named(app_client):  # noqa: F811
    sim = simulate_capture(cameras=2, frames=10, noise_px=0.3, seed=1, occlusion=0.0, static=False)
    app, c = app_client()
    capture_id = stream_capture(c, sim)
    url = f"/captures/{capture_id}/blobsets"
    good = blob_sets(sim, range(5))
    assert c.post(url, json={"sets": good[:2]}).status_code == 201

    def refused(sets, status, *words):
        r = c.post(url, json={"sets": sets})
        assert r.status_code == status, r.text
        for word in words:
            assert word in r.json()["detail"], (word, r.json()["detail"])

    refused(good[1:4], 409, "frame 1 of capture", "nothing of this request was stored")
    refused([good[2], good[2]], 422, "sets[1] (frame 2)", "given twice")
    refused([good[2], {"frame": 3, "blobs": {"camX": [[1, 2]]}}], 422, "sets[1] (frame 3)", "'camX' is not a camera")
    refused([{"frame": 3, "blobs": {"cam1": [[10.0, 5000.0]]}}], 422, "camera cam1's blob (10, 5000) lies off its")
    refused([{"frame": 3, "blobs": {"cam1": [[-3.0, 5.0]]}}], 422, "lies off")
    refused([{"frame": 3, "blobs": {"cam1": [[1.0, 2.0]] * (MAX_BLOBS_PER_CAMERA + 1)}}], 422, "more than")
    refused([], 422)
    refused([{"frame": -1, "blobs": {}}], 422)
    refused([{"frame": 10**13, "blobs": {}}], 422)
    refused([{"frame": 3, "blobs": {"cam1": [[1.0]]}}], 422)
    refused([{"frame": 3, "blobs": {}, "extra": 1}], 422)
    refused([{"frame": 3, "blobs": {}}] * (MAX_BLOB_SETS + 1), 422)
    r = c.post(url, content=b'{"sets": [{"frame": 3, "blobs": {"cam1": [[Infinity, 1.0]]}}]}',
               headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    # none of the refused requests stored anything: frames 2-4 still go in
    r = c.post(url, json={"sets": good[2:]})
    assert r.status_code == 201 and r.json()["framesets"] == 5
    uploaded = c.post("/captures", files=capture_files_of(sim, app)).json()
    r = c.post(f"/captures/{uploaded['id']}/blobsets", json={"sets": good[:1]})
    assert r.status_code == 409 and "created by uploading rig.json alone" in r.json()["detail"]


def capture_files_of(sim, app):
    from wandcal.capture.folder import write_capture

    folder = app.state.wandcal.settings.data_dir.parent / "upload"
    write_capture(folder, sim.rig, sim.wand, None)
    return capture_files(folder)


def test_a_rig_streamed_as_blob_sets_over_http_calibrates(make_server):
    """A real server: 8 requests of 50 sets each, a job, and the rig's shape against the truth."""
    sim = simulate_capture(cameras=4, frames=400, noise_px=0.3, seed=11, static=False)
    server = make_server(workers=1).start()
    with server.client() as c:
        capture_id = stream_capture(c, sim)
        for batch in np.array_split(np.unique(sim.wand.frame), 8):
            r = c.post(f"/captures/{capture_id}/blobsets", json={"sets": blob_sets(sim, batch)})
            assert r.status_code == 201, r.text
        job = wait_job(c, c.post("/jobs", json={"capture_id": capture_id}).json()["id"])
        assert job["state"] == "done", job["error"]
    centers = np.array([cam["center"] for cam in job["result"]["cameras"]])
    truth = sim.truth.centers
    R, t, _ = kabsch(centers, truth)  # a wand-only result is in the wand volume's frame
    assert np.linalg.norm(centers @ R.T + t - truth, axis=1).max() < SHAPE_TOL_M
