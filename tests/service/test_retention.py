"""Retention (service/jobs/retention.py): nothing is deleted unless a setting allows it; then exactly
the finished jobs and idle captures older than the setting, never a queued or running job's."""

from __future__ import annotations

import threading
import time

from fastapi.testclient import TestClient

from tests.service.conftest import capture_files
from wandcal.service.db import init_db
from wandcal.service.jobs.retention import DAY_S, Pruner, Retention, prune
from wandcal.service.main import create_app
from wandcal.service.report.store import report_folder
from wandcal.service.settings import Settings


def _service(tmp_path, small_capture, **settings):
    folder, _ = small_capture
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0, **settings))
    client = TestClient(app, base_url="http://127.0.0.1/api/v1")
    return app, client, capture_files(folder)


def test_by_default_nothing_is_deleted_and_no_pruner_runs(tmp_path, small_capture):
    app, client, files = _service(tmp_path, small_capture)
    with client:
        capture_id = client.post("/captures", files=files).json()["id"]
        client.post("/jobs", json={"capture_id": capture_id, "method": "ba"})
        app.state.wandcal.queue.drain()
        assert not any(t.name == "wandcal-retention" for t in threading.enumerate())
        data = tmp_path / "data"
        assert prune(data, data / "wandcal.sqlite3", Retention(), now=time.time() + 1e4 * DAY_S) == ([], [])
        assert len(client.get("/jobs").json()["jobs"]) == 1 and (data / "captures" / capture_id).is_dir()


def test_old_results_and_idle_captures_go_and_nothing_else(tmp_path, small_capture):
    app, client, files = _service(tmp_path, small_capture)
    data = tmp_path / "data"
    with client:
        old_capture = client.post("/captures", files=files).json()["id"]
        busy_capture = client.post("/captures", files=files).json()["id"]
        old_job = client.post("/jobs", json={"capture_id": old_capture, "method": "ba"}).json()["id"]
        app.state.wandcal.queue.drain()
        assert client.get(f"/jobs/{old_job}/report").status_code == 200  # drawn into reports/<job id>
        assert report_folder(data, old_job).is_dir()
        queued = client.post("/jobs", json={"capture_id": busy_capture, "method": "ba"}).json()["id"]
        later = time.time() + 40 * DAY_S
        # results kept 30 days: the finished job goes with its report, the queued one stays
        jobs, captures = prune(data, data / "wandcal.sqlite3", Retention(results_days=30), now=later)
        assert jobs == [old_job] and captures == []
        assert not report_folder(data, old_job).exists()
        assert client.get(f"/jobs/{old_job}").status_code == 404
        assert client.get(f"/jobs/{queued}").json()["state"] == "queued"
        # captures kept 30 days: the idle one goes with its folder, the one with a queued job stays
        jobs, captures = prune(data, data / "wandcal.sqlite3", Retention(captures_days=30), now=later)
        assert captures == [old_capture] and jobs == []
        assert not (data / "captures" / old_capture).exists() and (data / "captures" / busy_capture).is_dir()
        assert client.get(f"/captures/{old_capture}").status_code == 404
        assert client.get(f"/captures/{busy_capture}").status_code == 200
        # not yet old: nothing more
        assert prune(data, data / "wandcal.sqlite3", Retention(30, 30), now=time.time() + 29 * DAY_S) == ([], [])
        assert list((data / "captures").glob(".*.deleting")) == []


def test_a_folder_left_mid_delete_by_a_crash_is_removed_at_the_next_prune(tmp_path):
    data = tmp_path / "data"
    init_db(data / "wandcal.sqlite3")
    left = data / "captures" / ".0123456789abcdef0123456789abcdef.deleting"
    (left / "frames").mkdir(parents=True)
    (left / "wand.csv").write_text("frame\n")
    prune(data, data / "wandcal.sqlite3", Retention(results_days=1))
    assert not left.exists()


def test_the_setting_starts_a_pruner_that_stops_with_the_app(tmp_path):
    data = tmp_path / "data"
    init_db(data / "wandcal.sqlite3")
    pruner = Pruner(data, data / "wandcal.sqlite3", Retention(results_days=7), every_s=3600)
    pruner.start()
    assert pruner._thread is not None and pruner._thread.is_alive()
    pruner.stop()
    assert not pruner._thread.is_alive()
