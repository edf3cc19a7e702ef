"""One owner per data folder (service/folder_lock.py, issue 34): a second ``wandcal serve`` on a
folder in use refuses at once and changes nothing; a killed owner's lock goes with it, and the
next start recovers."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.reliability.servers import poll
from tests.service.conftest import REPO, capture_files, free_port
from wandcal.service.folder_lock import LOCK_FILE, DataFolderInUse, Owner, hold_data_folder
from wandcal.service.jobs.records import JobState, JobStore
from wandcal.service.settings import Settings

REFUSAL_TIMEOUT_S = 120.0  # a refused start imports the service and exits; minutes only on a wedged box


def _tree(data_dir: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder of the data folder but the database (the live server writes it) and its
    lock file: path -> (size, mtime in ns)."""
    return {str(p.relative_to(data_dir)): (p.stat().st_size, p.stat().st_mtime_ns)
            for p in sorted(data_dir.rglob("*")) if not p.name.startswith("wandcal.sqlite3")}


def _second_serve(env: dict) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "wandcal.service.cli", "serve", "--port", str(free_port()),
                           "--workers", "0"], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=REFUSAL_TIMEOUT_S, check=False)


def test_a_second_serve_refuses_changes_nothing_and_a_killed_owner_is_recovered(make_server, small_capture, tmp_path):
    folder, _ = small_capture
    owner = make_server(workers=0).start()
    with owner.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        job_id = c.post("/jobs", json={"capture_id": capture_id}).json()["id"]
    data_dir = tmp_path / "data"
    store = JobStore(data_dir / "wandcal.sqlite3")
    claim = store.claim(os.getpid(), job_id)  # this test is the job's worker: it runs until the test says
    assert claim is not None
    running = store.get(job_id)
    lock_before = (data_dir / LOCK_FILE).read_bytes()
    tree_before = _tree(data_dir)

    second = _second_serve(owner.env)
    assert second.returncode == 2, second.stderr
    assert "Traceback" not in second.stderr
    message = second.stderr
    assert str(data_dir) in message and f"pid {owner.proc.pid}" in message, message
    assert f":{owner.port}" in message and "since" in message and "--data-dir" in message, message
    # it changed nothing: the running job is still this claim's, the folder and the lock's record as they were
    assert store.get(job_id) == running and running.state is JobState.running and running.attempts == 1
    assert _tree(data_dir) == tree_before
    assert (data_dir / LOCK_FILE).read_bytes() == lock_before
    with owner.client() as c:
        assert c.get(f"/jobs/{job_id}").json()["state"] == "running"

    owner.kill()  # SIGKILL: the kernel lets the lock go with the process
    restarted = make_server(workers=0)
    restarted.env = owner.env
    restarted.start()
    with restarted.client() as c:
        job = poll(lambda: (j := c.get(f"/jobs/{job_id}").json())["state"] == "queued" and j, "the re-queue")
    assert job["attempts"] == 1
    assert store.finish(job_id, claim.token, JobState.done, result={}) is False  # the old claim lost the job
    held = Owner.parse((data_dir / LOCK_FILE).read_text())
    assert held is not None and held.pid == restarted.proc.pid and held.port == restarted.port
    restarted.stop()
    log = (tmp_path / "server.log").read_text()
    assert f"job {job_id} was running when the server stopped: now queued" in log, log


def test_a_folder_held_by_a_process_that_wrote_no_record_is_refused_naming_the_lock(tmp_path):
    data_dir = tmp_path / "data"
    data_dir.mkdir()
    (data_dir / LOCK_FILE).write_text("not a record")
    with open(data_dir / LOCK_FILE, "rb") as other:  # another open file: flock conflicts even within a process
        fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(DataFolderInUse, match="another process") as refused:
            hold_data_folder(Settings(data_dir=data_dir, workers=0))
    assert str(data_dir) in str(refused.value)
    assert not (data_dir / "wandcal.sqlite3").exists()
    lock = hold_data_folder(Settings(data_dir=data_dir, workers=0))  # free again once the other closed it
    assert json.loads((data_dir / LOCK_FILE).read_text())["pid"] == os.getpid()
    assert hold_data_folder(Settings(data_dir=data_dir, workers=0)) is lock  # shared within the process


def test_a_lock_file_that_is_a_link_or_a_folder_is_refused_naming_it(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.write_text("keep me")
    for kind in ("link", "folder"):
        data_dir = tmp_path / kind
        data_dir.mkdir()
        if kind == "link":
            (data_dir / LOCK_FILE).symlink_to(elsewhere)
        else:
            (data_dir / LOCK_FILE).mkdir()
        with pytest.raises(ValueError, match="lock file cannot be opened") as refused:
            hold_data_folder(Settings(data_dir=data_dir, workers=0))
        assert str(data_dir / LOCK_FILE) in str(refused.value)
    assert elsewhere.read_text() == "keep me"
