"""Retention (service/datafolder/retention.py): nothing is deleted unless a setting allows it; then exactly
the finished jobs and idle captures older than the setting, never a queued or running job's."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from fastapi.testclient import TestClient

from tests.service.conftest import capture_files
from wandcal.drivers.capture_files import TAKE_FILE
from wandcal.service.datafolder.retention import DAY_S, Pruner, Retention, prune
from wandcal.service.db import init_db
from wandcal.service.jobs.watch_job import LIVE_TAKE_PREFIX, TAKES_DIR
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


def test_watch_takes_go_with_their_job_and_capture_and_unnamed_ones_once_old(tmp_path, small_capture):
    """takes/ (issue 36): a watch job's take folder goes with the job, a live watch's with its capture,
    one that nothing names once older than the setting; a queued watch's take stays."""
    app, client, files = _service(tmp_path, small_capture)
    data, db = tmp_path / "data", tmp_path / "data" / "wandcal.sqlite3"
    take = "frame,camera,u,v\n" + "".join(f"{f},cam{c},{100 + f}.5,{200 + c}.5\n" for f in range(3) for c in (1, 2, 3))
    with client:
        capture_id = client.post("/captures", files=files).json()["id"]
        job_id = client.post("/jobs", json={"capture_id": capture_id, "method": "ba"}).json()["id"]
        app.state.wandcal.queue.drain()

        def watch() -> tuple[str, Path]:
            r = client.post("/watch", files={TAKE_FILE: (TAKE_FILE, take, "text/csv")}, data={"job_id": job_id})
            assert r.status_code == 202, r.text
            record = app.state.wandcal.queue.refresh(r.json()["id"])
            return record.id, Path(record.options["folder"])

        (done_watch, done_take), (queued_watch, queued_take) = watch(), watch()
        assert client.delete(f"/watch/{done_watch}").json()["state"] == "cancelled"  # finished: retention may take it
        live = data / TAKES_DIR / f"{LIVE_TAKE_PREFIX}{capture_id}"  # a live watch of this capture
        unnamed_live = data / TAKES_DIR / f"{LIVE_TAKE_PREFIX}{'f' * 32}"  # its recording was never stored
        unnamed_upload = data / TAKES_DIR / ("e" * 32)  # a crash between the folder and its job's row
        for folder in (live, unnamed_live, unnamed_upload):
            folder.mkdir(parents=True)
            (folder / "result.json").write_text("{}\n")
        assert done_take.parent == queued_take.parent == data / TAKES_DIR and done_take.is_dir()

        assert prune(data, db, Retention(), now=time.time() + 1e4 * DAY_S) == ([], [])  # the default keeps all
        assert all(f.is_dir() for f in (done_take, queued_take, live, unnamed_live, unnamed_upload))
        # results kept 30 days: the finished watch's take and the unnamed upload go; the queued one stays
        jobs, _ = prune(data, db, Retention(results_days=30), now=time.time() + 40 * DAY_S)
        assert done_watch in jobs and queued_watch not in jobs
        assert not done_take.exists() and not unnamed_upload.exists()
        assert queued_take.is_dir() and live.is_dir() and unnamed_live.is_dir()
        # not yet old: an unnamed live take stays
        prune(data, db, Retention(captures_days=30), now=time.time() + 29 * DAY_S)
        assert unnamed_live.is_dir() and live.is_dir()
        # captures kept 30 days: the capture with a queued watch stays, with both its takes; the unnamed live one goes
        _, captures = prune(data, db, Retention(captures_days=30), now=time.time() + 40 * DAY_S)
        assert captures == [] and queued_take.is_dir() and live.is_dir() and not unnamed_live.exists()
        client.delete(f"/watch/{queued_watch}")
        _, captures = prune(data, db, Retention(captures_days=30), now=time.time() + 40 * DAY_S)
        assert captures == [capture_id] and not queued_take.exists() and not live.exists()
        assert sorted(p.name for p in (data / TAKES_DIR).iterdir()) == []  # nothing left mid-delete either
