"""Jobs on a distributed queue: Redis (started here, on a loopback port) and an rq worker process."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.service.conftest import REPO, capture_files, free_port, wait_job

pytest.importorskip("rq", reason="pip install 'wandcal[redis]' to test the Redis queue")
REDIS_SERVER = shutil.which("redis-server")
pytestmark = pytest.mark.skipif(REDIS_SERVER is None, reason="redis-server is not installed (apt-get install redis-server)")


@pytest.fixture
def redis_url(tmp_path):
    port = free_port()
    proc = subprocess.Popen(
        [REDIS_SERVER, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
         "--dir", str(tmp_path)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    from redis import Redis

    url = f"redis://127.0.0.1:{port}/0"
    deadline = time.monotonic() + 20
    while True:
        try:
            Redis.from_url(url).ping()
            break
        except Exception:
            if time.monotonic() > deadline or proc.poll() is not None:
                proc.kill()
                raise
            time.sleep(0.05)
    yield url
    proc.terminate()
    proc.wait(10)


def test_jobs_run_on_an_rq_worker(make_server, small_capture, redis_url, tmp_path):
    folder, sim = small_capture
    server = make_server(queue="redis", redis_url=redis_url, workers=0).start()
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        job_id = c.post("/jobs", json={"capture_id": capture_id, "method": "ba"}).json()["id"]
        queued = c.get(f"/jobs/{job_id}").json()
        assert queued["state"] == "queued"
        cancelled_id = c.post("/jobs", json={"capture_id": capture_id}).json()["id"]
        assert c.delete(f"/jobs/{cancelled_id}").json()["state"] == "cancelled"
        # the worker is another process that knows nothing of the server's data directory
        worker = subprocess.run(  # `rq worker --burst`: run what is queued, then exit
            [sys.executable, "-m", "rq.cli", "worker", "--burst", "--url", redis_url, "wandcal"],
            cwd=tmp_path, env=dict(server.env, PYTHONPATH=str(REPO)), capture_output=True, text=True, timeout=300,
        )
        assert worker.returncode == 0, worker.stderr
        job = wait_job(c, job_id, timeout_s=30)
        assert job["state"] == "done", job["error"]
        assert c.get(f"/jobs/{cancelled_id}").json()["state"] == "cancelled"
    centers = np.array([cam["center"] for cam in job["result"]["cameras"]])
    # same capture and solver as the SQLite path: the same 10 mm absolute bound (test_http.py)
    assert np.linalg.norm(centers - sim.truth.centers, axis=1).max() < 0.010

