"""The rig page in headless Chromium (Debian's ``chromium``), against the real server."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import pytest

from tests.service.conftest import capture_files, wait_job
from tests.service.test_live_capture import (
    LOOSE_GUIDANCE,
    STATIC_SETS,
    WAND_SETS,
    start_guided,
    start_paused,
    wait_capture,
    watch_guidance,
)
from wandcal.drivers.trigger_emulator import EmulatorProcess
from wandcal.service.settings import DEFAULT_CONTINUE_TIMEOUT_S

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium)")
# time the page's scripts may run in virtual time: a few 1-second polls
VIRTUAL_TIME_BUDGET_MS = 5000
# the page trusts its own clock within 2 s of the server's (CLOCK_SLACK_S in app.js; virtual time lags
# while fetches wait), and the Date header it compares with has whole seconds
PAGE_CLOCK_SLACK_S = 2 + 1


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
        assert f'{cam["center_std_mm"]:.2f}' in html  # the predicted uncertainty
        assert f'class="verdict-{cam["verdict"]["level"]}"' in html
    assert f'verdict: {job["result"]["verdict"]["level"]}' in html
    assert 'id="result-section" hidden' not in html

    shot = tmp_path / "page.png"
    run = chromium(server.url + "/", tmp_path / "profile2", f"--screenshot={shot}", "--window-size=1280,1100")
    assert run.returncode == 0 and shot.stat().st_size > 10_000, run.stderr


def live_panel(html: str) -> str:
    """The live-capture section of a dumped DOM."""
    start = html.index('<section id="live"')
    return html[start:html.index("</section>", start)]


def test_page_shows_a_live_capture_waiting_for_the_wand_until_continue(make_server, tmp_path):
    server = make_server(workers=0).start()
    with EmulatorProcess() as emu, server.client() as c:
        started, waiting = start_paused(c, emu)

        panel = live_panel(chromium(server.url + "/", tmp_path / "profile", "--dump-dom").stdout)
        assert 'data-state="waiting_for_wand"' in panel
        assert '<div id="live-wait" class="prompt">' in panel  # shown, not hidden
        assert "remove the L-frame" in panel
        assert f"{STATIC_SETS} / {STATIC_SETS + WAND_SETS} frame sets" in panel
        left = int(re.search(r'id="live-left" data-seconds="(\d+)"', panel).group(1))
        assert 0 < left <= DEFAULT_CONTINUE_TIMEOUT_S + PAGE_CLOCK_SLACK_S
        assert '<button id="live-continue" class="primary">' in panel
        assert '<button id="live-stop">' in panel
        for cam in waiting["cameras"]:
            assert f'<tr data-camera="{cam}"><td>{cam}</td><td class="">0</td></tr>' in panel

        assert c.post("/capture/continue").status_code == 202
        status = wait_capture(c)
        assert status["state"] == "done", status["error"]

        html = chromium(server.url + "/", tmp_path / "profile2", "--dump-dom").stdout
    panel = live_panel(html)
    assert 'data-state="done"' in panel
    assert f"{STATIC_SETS + WAND_SETS} / {STATIC_SETS + WAND_SETS} frame sets" in panel
    assert '<div id="live-wait" class="prompt" hidden="">' in panel
    assert '<button id="live-continue" class="primary" hidden="">' in panel
    assert '<button id="live-stop" hidden="">' in panel
    assert f'data-capture-id="{started["capture_id"]}"' in html  # the stored capture, ready to calibrate


def test_page_shows_the_guidance_filling_in_and_when_it_is_enough(make_server, tmp_path):
    server = make_server(workers=0, guidance=json.dumps(LOOSE_GUIDANCE)).start()
    with EmulatorProcess() as emu, server.client() as c:
        started = start_guided(c, emu)
        watch_guidance(c, started["capture_id"], updates=1)
        panel = live_panel(chromium(server.url + "/", tmp_path / "profile", "--dump-dom").stdout)
        assert '<div id="live-guidance" data-enough=' in panel  # shown, not hidden
        for cam in started["cameras"]:
            assert f'data-guidance-camera="{cam}"' in panel
        assert panel.count('class="covgrid"') == len(started["cameras"]) and 'class="hit"' in panel
        assert "Enough when every camera's centre σ is below 1 mm" in panel

        assert c.patch("/capture", json={"stop_when_enough": True}).status_code == 200
        status = wait_capture(c)
        assert status["state"] == "done" and status["enough"], status["error"]
        html = chromium(server.url + "/", tmp_path / "profile2", "--dump-dom").stdout
        shot = tmp_path / "guidance.png"
        run = chromium(server.url + "/", tmp_path / "profile3", f"--screenshot={shot}", "--window-size=1280,1400")
    panel = live_panel(html)
    assert '<div id="live-guidance" data-enough="true">' in panel
    assert '<p id="live-enough" class="enough">Enough: you can stop waving.</p>' in panel
    assert panel.count("✓") == len(started["cameras"])  # no camera needs anything
    assert run.returncode == 0 and shot.stat().st_size > 10_000, run.stderr
