"""The page's Check panel in headless Chromium, against the real server over HTTP: a capture judged
against the result the Rig panel shows (POST /captures/{id}/check), and the moved camera re-solved
from that result by one button (a job with from_job and solve_only), as `wandcal check` and
`wandcal calibrate --from RESULT --solve-only CAM` do on the command line."""

from __future__ import annotations

import numpy as np

from tests.service.browser import Browser
from tests.service.conftest import capture_files, wait_job
from tests.service.test_page import CHROMIUM, artefact, pytestmark  # noqa: F401 (skips where chromium is absent)
from wandcal.calib.sim.scenes import knocked_capture
from wandcal.capture.folder import write_capture

KNOCKED = 1  # cam2
KNOCK_DEG, KNOCK_M = 1.0, 0.03  # far past any camera's check limit at 0.3 px (tests/service/test_http_parity.py)


def _click(browser: Browser, selector: str) -> None:
    browser.wait_for(f"document.querySelector({selector!r}) && !document.querySelector({selector!r}).disabled")
    browser.js(f"document.querySelector({selector!r}).click()")


def _check_of(browser: Browser, capture_id: str, verdict: str) -> None:
    _click(browser, f'tr[data-capture-id="{capture_id}"] button.check')
    browser.wait_for(f"document.querySelector('#check-section')?.dataset.captureId === '{capture_id}' && "
                     f"document.querySelector('#check-body [data-verdict]')?.dataset.verdict === '{verdict}'")


def test_the_check_panel_names_the_knocked_camera_and_re_solves_it(make_server, small_capture, tmp_path):
    folder, sim = small_capture
    knocked = tmp_path / "knocked"
    wand, _, _ = knocked_capture(sim, KNOCKED, KNOCK_DEG, KNOCK_M, 300, 8)
    write_capture(knocked, sim.rig, wand, None)
    server = make_server(workers=1).start()
    with server.client() as c:
        base_capture = c.post("/captures", files=capture_files(folder)).json()["id"]
        base = wait_job(c, c.post("/jobs", json={"capture_id": base_capture}).json()["id"])
        assert base["state"] == "done", base["error"]
        fresh = c.post("/captures", files=capture_files(knocked)).json()["id"]
        with Browser(CHROMIUM, tmp_path / "profile") as browser:
            browser.open(server.url + "/")
            browser.wait_for(f"document.querySelector('#result-section')?.dataset.drawn === '{base['id']}'")

            _check_of(browser, fresh, "moved")
            states = browser.js("Object.fromEntries([...document.querySelectorAll('#check-cameras tbody tr')]"
                                ".map((r) => [r.dataset.camera, r.dataset.status]))")
            assert states == {cam.id: "moved" if i == KNOCKED else "agrees" for i, cam in enumerate(sim.rig.cameras)}
            api = c.post(f"/captures/{fresh}/check", json={"job_id": base["id"]}).json()
            assert browser.js("document.querySelector('#check-advice').textContent") == api["advice"]
            browser.screenshot(artefact(tmp_path, "page-check-moved.png"))

            _click(browser, "#check-resolve")
            resolve_id = browser.wait_for("document.querySelector('#check-section').dataset.resolveJob")
            job = wait_job(c, resolve_id)
            assert job["state"] == "done", job["error"]
            assert job["options"]["from_job"] == base["id"] and job["options"]["solve_only"] == ["cam2"]
            for i, (a, b) in enumerate(zip(base["result"]["cameras"], job["result"]["cameras"])):
                if i != KNOCKED:
                    assert a["R"] == b["R"] and a["t"] == b["t"]  # held where the standing result has them
            moved_by = np.linalg.norm(np.subtract(job["result"]["cameras"][KNOCKED]["t"], base["result"]["cameras"][KNOCKED]["t"]))
            assert moved_by > KNOCK_M / 3  # placed again, not held

            # the panel follows the re-solve; the same capture checked against it agrees
            browser.wait_for(f"document.querySelector('#result-section')?.dataset.drawn === '{resolve_id}'")
            _check_of(browser, fresh, "agrees")
            assert not browser.js("!!document.querySelector('#check-resolve')")
            browser.screenshot(artefact(tmp_path, "page-check-agrees.png"))
