"""The rig page in headless Chromium (Debian's ``chromium``), against the real server."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from tests.service.conftest import capture_files, wait_job

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium)")
# time the page's scripts may run in virtual time: a few 1-second polls
VIRTUAL_TIME_BUDGET_MS = 5000


def chromium(url: str, profile, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={profile}", f"--virtual-time-budget={VIRTUAL_TIME_BUDGET_MS}", *args, url],
        capture_output=True, text=True, timeout=120,
    )


def test_page_shows_captures_jobs_and_the_solved_rig(make_server, small_capture, tmp_path):
    folder, sim = small_capture
    server = make_server(workers=1).start()
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(folder)).json()["id"]
        job_id = c.post("/jobs", json={"capture_id": capture_id}).json()["id"]
        job = wait_job(c, job_id)
    assert job["state"] == "done", job["error"]

    dom = chromium(server.url + "/", tmp_path / "profile", "--dump-dom")
    assert dom.returncode == 0, dom.stderr
    html = dom.stdout
    assert f'data-capture-id="{capture_id}"' in html
    assert f'data-job-id="{job_id}" data-state="done"' in html
    for cam in job["result"]["cameras"]:
        assert f'data-camera="{cam["id"]}"' in html  # coverage and residual rows
        assert f'{cam["reprojection_rms_px"]:.3f}' in html
    assert 'id="result-section" hidden' not in html

    shot = tmp_path / "page.png"
    run = chromium(server.url + "/", tmp_path / "profile2", f"--screenshot={shot}", "--window-size=1280,1100")
    assert run.returncode == 0 and shot.stat().st_size > 10_000, run.stderr
