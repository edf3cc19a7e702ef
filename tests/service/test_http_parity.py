"""The service does what the command line does (issue 32): ``check``, ``--solve-only`` and guidance
over HTTP give the command line's answers on the same capture, for every input kind: a two-marker
wand with an L-frame, a 3-marker wand (``markers_m``), a planar wand, a wand with point tracks,
points only, and a sparse hand-digitised session with point tracks and axis points (Brown 1 of
../shared/data, skipped where absent). The command line runs as a user runs it (a subprocess); the API in-process
(``TestClient``, ``drain()`` runs the queue), as tests/service/test_api.py does.

Small rigs (4 cameras, 300 frames, 0.3 px) keep it fast."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import long_except
from tests.service.conftest import wandcal
from tests.service.test_api import app_client  # noqa: F401 (a fixture)
from wandcal.calib.rig import WandObservations
from wandcal.calib.sim.scenes import knocked_capture, pairwise_points
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import write_capture
from wandcal.drivers.capture_files import AXIS_FILE, POINTS_FILE, RIG_FILE, STATIC_FILE, WAND_FILE

CW500_M = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]])  # 3 collinear markers
T_WAND_M = np.array([[0.0, 0.0, 0.0], [0.18, 0.0, 0.0], [0.42, 0.0, 0.0], [0.18, 0.12, 0.0], [0.18, 0.30, 0.0]])
KINDS = ("lframe", "three_marker", "planar", "wand_points", "points_only", "sparse_digitised")
# guidance fields that say when and how long, not what: they differ between any two runs
TIMING = {"seconds", "updated", "live"}



def _write_kind(name: str, folder: Path) -> bool:
    """One input kind's capture folder, and for a simulated wand ``folder``-knocked: the same rig with
    cam2 knocked by 1 degree. False when the kind's data are absent (the sparse session's)."""
    if name == "sparse_digitised":  # Brown 1 of ../shared/data: 2-8 wand frames a camera, point tracks, axis
        from bench.real_sessions import BROWN, BROWN_MAT, SHARED_DATA
        from wandcal.capture.importers.easywand import read_easywand_mat

        mat = SHARED_DATA / BROWN / "calibration1" / BROWN_MAT
        if not mat.is_file():
            return False
        cap = read_easywand_mat(mat).capture
        write_capture(folder, cap.rig, cap.wand, None, cap.points, cap.axis)
        return True
    markers = {"three_marker": CW500_M, "planar": T_WAND_M}.get(name)
    sim = simulate_capture(4, 300, 0.3, 0.0, name == "lframe", 1, wand_markers=markers)
    points = None
    if name in ("wand_points", "points_only"):
        points = pairwise_points(sim, 400, np.random.default_rng(5), third=0.8)
    if name == "points_only":
        no_wand = WandObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))
        write_capture(folder, dataclasses.replace(sim.rig, wand_length=None), no_wand, None, points)
        return True
    write_capture(folder, sim.rig, sim.wand, sim.static, points)
    wand, _, _ = knocked_capture(sim, 1, 1.0, 0.03, 300, 8)
    write_capture(folder.with_name(folder.name + "-knocked"), sim.rig, wand, None)
    return True


@pytest.fixture(scope="module")
def kinds(tmp_path_factory) -> dict[str, Path]:
    """{kind: its capture folder, with the CLI's result.json}; a kind whose data are absent is left out."""
    root = tmp_path_factory.mktemp("kinds")
    folders = {}
    for name in KINDS:
        if not _write_kind(name, root / name):
            continue
        r = wandcal("calibrate", root / name, "--quiet")
        assert r.returncode == 0, r.stderr
        folders[name] = root / name
    return folders


def _folder(kinds: dict[str, Path], kind: str) -> Path:
    if kind not in kinds:
        pytest.skip(f"the {kind} capture's data are absent (../shared/data)")
    return kinds[kind]


def upload(client, folder: Path) -> str:
    names = [n for n in (RIG_FILE, WAND_FILE, STATIC_FILE, POINTS_FILE, AXIS_FILE) if (folder / n).is_file()]  # what a kind has
    r = client.post("/captures", files={n: (n, (folder / n).read_bytes(), "application/octet-stream") for n in names})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def solved(app, client, capture_id: str, options: dict | None = None) -> dict:
    """A job of the capture run to its end: its record, done."""
    r = client.post("/jobs", json={"capture_id": capture_id, "options": options or {}})
    assert r.status_code == 202, r.text
    app.state.wandcal.queue.drain()
    job = client.get(f"/jobs/{r.json()['id']}").json()
    assert job["state"] == "done", job["error"]
    return job


def cli_check(result: Path, capture: Path) -> tuple[int, dict]:
    r = wandcal("check", result, capture, "--json")
    assert r.returncode in (0, 1, 3), r.stderr
    return r.returncode, json.loads(r.stdout)


@pytest.mark.parametrize("kind", long_except(KINDS, {"lframe", "three_marker"}))
def test_check_over_http_answers_as_the_command_line(kind, kinds, app_client):  # noqa: F811 (the fixture)
    folder = _folder(kinds, kind)
    app, c = app_client()
    capture_id = upload(c, folder)
    code, cli = cli_check(folder / "result.json", folder)
    r = c.post(f"/captures/{capture_id}/check", json={"result": json.loads((folder / "result.json").read_text())})
    assert r.status_code == 200, r.text
    http = r.json()
    assert code == 0 and http["exit_code"] == 0 and http["verdict"] == "agrees", (cli, http)
    assert {k: http[k] for k in cli} == cli  # every figure, to the last digit
    # the job's own result, by its id: the server's calibration agrees with its capture as the CLI's does
    job = solved(app, c, capture_id)
    np.testing.assert_allclose([cam["t"] for cam in job["result"]["cameras"]],
                               [cam["t"] for cam in json.loads((folder / "result.json").read_text())["cameras"]],
                               atol=1e-9)  # the same solve in another process: rounding only
    again = c.post(f"/captures/{capture_id}/check", json={"job_id": job["id"]}).json()
    assert again["exit_code"] == 0 and again["job_id"] == job["id"]
    # and its export is the command line's export of the same result
    standing = folder.parent / f"{kind}-job.json"
    standing.write_text(json.dumps(job["result"]))
    r = wandcal("export", standing, "--format", "anipose-toml")
    assert r.returncode == 0, r.stderr
    exported = c.get(f"/jobs/{job['id']}/result", params={"format": "anipose-toml"})
    assert exported.status_code == 200 and exported.text == r.stdout, exported.text


@pytest.mark.parametrize("kind", long_except(["lframe", "three_marker", "planar"], {"three_marker"}))
def test_a_knock_is_named_and_re_solved_over_http_as_on_the_command_line(kind, kinds, app_client, tmp_path):  # noqa: F811
    folder, knocked = kinds[kind], kinds[kind].with_name(kind + "-knocked")
    app, c = app_client()
    base = solved(app, c, upload(c, folder))
    standing = tmp_path / "standing.json"  # the job's result, for the command line's --from
    standing.write_text(json.dumps(base["result"]))
    fresh = upload(c, knocked)

    code, cli = cli_check(standing, knocked)
    http = c.post(f"/captures/{fresh}/check", json={"job_id": base["id"]}).json()
    assert code == 1 and cli["moved"] == ["cam2"], cli
    assert http["exit_code"] == 1 and http["verdict"] == "moved"
    assert {k: http[k] for k in cli} == cli
    assert '"solve_only": ["cam2"]' in http["advice"] and base["id"] in http["advice"]

    out = tmp_path / "resolved.json"
    r = wandcal("calibrate", knocked, "--from", standing, "--solve-only", "cam2", "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    job = solved(app, c, fresh, {"from_job": base["id"], "solve_only": ["cam2"]})
    cli_doc, http_doc = json.loads(out.read_text()), job["result"]
    for a, b in zip(cli_doc["cameras"], http_doc["cameras"]):
        np.testing.assert_allclose(b["R"], a["R"], atol=1e-9)  # the same solve in another process: rounding only
        np.testing.assert_allclose(b["t"], a["t"], atol=1e-9)
    assert http_doc["world"] == cli_doc["world"]
    for a, b in zip(base["result"]["cameras"], http_doc["cameras"]):
        if a["id"] != "cam2":
            assert a["R"] == b["R"] and a["t"] == b["t"]  # held exactly, through JSON
    after = c.post(f"/captures/{fresh}/check", json={"job_id": job["id"]}).json()
    assert after["exit_code"] == 0, after


@pytest.mark.parametrize("kind", long_except(["wand_points", "points_only", "sparse_digitised"], {"points_only"}))
def test_a_re_solve_from_point_tracks_over_http_is_the_command_lines(kind, kinds, app_client, tmp_path):  # noqa: F811
    """--solve-only with the capture's point tracks (and no wand at all for points only), against the
    capture the standing result came from: the HTTP job gives the command line's result."""
    folder = _folder(kinds, kind)
    app, c = app_client()
    capture_id = upload(c, folder)
    base = solved(app, c, capture_id)
    standing = tmp_path / "standing.json"
    standing.write_text(json.dumps(base["result"]))
    camera = base["result"]["cameras"][1]["id"]
    out = tmp_path / "resolved.json"
    r = wandcal("calibrate", folder, "--from", standing, "--solve-only", camera, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    job = solved(app, c, capture_id, {"from_job": base["id"], "solve_only": [camera]})
    for a, b in zip(json.loads(out.read_text())["cameras"], job["result"]["cameras"]):
        np.testing.assert_allclose(b["R"], a["R"], atol=1e-9)  # the same solve in another process: rounding only
        np.testing.assert_allclose(b["t"], a["t"], atol=1e-9)


@pytest.mark.parametrize("kind", KINDS)
def test_guidance_over_http_is_the_command_lines(kind, kinds, app_client):  # noqa: F811 (the fixture)
    folder = _folder(kinds, kind)
    app, c = app_client()
    capture_id = upload(c, folder)
    r = wandcal("guidance", folder, "--json")
    assert r.returncode == 0, r.stderr
    cli = json.loads(r.stdout)
    http = c.get(f"/captures/{capture_id}/guidance").json()
    assert http["cameras"] == cli["cameras"] and http["advice"] == cli["advice"] and http["enough"] == cli["enough"]
    # the HTTP document's schema gives every field (null, or false, where the command line's leaves it out)
    assert {k: v for k, v in http["solve"].items() if k not in TIMING and v not in (None, False)} == {
        k: v for k, v in cli["solve"].items() if k not in TIMING and v not in (None, False)}
    assert http["solve"]["ok"] and http["solve"].get("points_only", False) == cli["solve"].get("points_only", False)


def test_bad_check_and_solve_only_requests_are_4xx_naming_the_field(kinds, app_client, tmp_path):  # noqa: F811
    app, c = app_client()
    capture_id = upload(c, kinds["lframe"])
    sim = simulate_capture(3, 60, 0.3, 0.0, False, 2)  # another rig: other camera ids
    rig = dataclasses.replace(sim.rig, cameras=tuple(dataclasses.replace(cam, id=f"wall{k}")
                                                     for k, cam in enumerate(sim.rig.cameras)))
    write_capture(tmp_path / "other", rig, sim.wand, None)
    other = upload(c, tmp_path / "other")
    base = solved(app, c, capture_id)
    cases = [
        (c.post(f"/captures/{capture_id}/check", json={}), 422, "give one of job_id"),
        (c.post(f"/captures/{capture_id}/check", json={"job_id": base["id"], "result": {}}), 422, "give one of job_id"),
        (c.post(f"/captures/{capture_id}/check", json={"job_id": "nope"}), 404, "job_id: no job with id 'nope'"),
        (c.post(f"/captures/{capture_id}/check", json={"result": {"format": "x"}}), 422, "the posted result"),
        (c.post(f"/captures/{'0' * 32}/check", json={"job_id": base["id"]}), 404, "no capture with id"),
        (c.post(f"/captures/{other}/check", json={"job_id": base["id"]}), 422, "not of this result's rig"),
        (c.post("/jobs", json={"capture_id": capture_id, "options": {"solve_only": ["cam2"]}}), 422,
         "from_job and solve_only go together"),
        (c.post("/jobs", json={"capture_id": capture_id, "method": "lp",
                               "options": {"from_job": base["id"], "solve_only": ["cam2"]}}), 422, "method ba only"),
        (c.post("/jobs", json={"capture_id": capture_id, "options": {"from_job": "nope", "solve_only": ["cam2"]}}),
         422, "options.from_job: no job with id 'nope'"),
        (c.post("/jobs", json={"capture_id": capture_id, "options": {"from_job": base["id"], "solve_only": ["cam9"]}}),
         422, "options.solve_only: unknown camera id 'cam9'"),
        (c.post("/jobs", json={"capture_id": other, "options": {"from_job": base["id"], "solve_only": ["cam2"]}}),
         422, "not of this result's rig"),
    ]
    queued = c.post("/jobs", json={"capture_id": capture_id}).json()  # not drained: still queued
    cases.append((c.post(f"/captures/{capture_id}/check", json={"job_id": queued["id"]}), 409, "it has no result"))
    cases.append((c.post("/jobs", json={"capture_id": capture_id, "options": {"from_job": queued["id"],
                                                                                "solve_only": ["cam2"]}}), 409, "queued"))
    for r, status, words in cases:
        assert r.status_code == status and words in r.json()["detail"], (status, words, r.status_code, r.text)
