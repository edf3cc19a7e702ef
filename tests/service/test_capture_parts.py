"""``POST /captures`` keeps every part it takes (points.csv with labelled points, axis.csv, floor.csv or drop.csv) and
refuses any other part with 422, storing nothing: an imported session uploaded to the service
loses nothing."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.capture.importers.test_import_anipose import _session
from wandcal.calib.geometry import project_pixels
from wandcal.capture.folder import read_capture, save_capture
from wandcal.capture.importers.anipose import read_anipose
from wandcal.drivers.capture_files import AXIS_FILE, POINTS_FILE, RIG_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

AXIS_M = {"origin": [0.0, 0.0, 1.0], "+x": [0.5, 0.0, 1.0]}  # inside the simulated volume


@pytest.fixture
def client(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        yield app, c


@pytest.fixture
def imported(tmp_path):
    """An anipose import (labelled keypoints, no wand) with axis points, as a capture folder."""
    cams, R, t, X, uv, toml, files = _session(tmp_path)
    cap = read_anipose(toml, list(map(str, files)), unit="mm")[0].capture
    folder = tmp_path / "cap"
    save_capture(folder, cap)
    rows = ["role,camera,u,v"]
    for role, x in AXIS_M.items():
        for c, cam in enumerate(cams):
            u, v = project_pixels(cam, R[c], t[c], np.array([x]))[0]
            rows.append(f"{role},{cam.id},{u:.4f},{v:.4f}")
    (folder / AXIS_FILE).write_text("\n".join(rows) + "\n")
    return folder


def _files(folder, *names, extra=None):
    files = {n: (n, (folder / n).read_bytes(), "text/csv") for n in names}
    return files | (extra or {})


def test_points_and_axis_parts_are_stored(client, imported):
    app, c = client
    r = c.post("/captures", files=_files(imported, RIG_FILE, POINTS_FILE, AXIS_FILE))
    assert r.status_code == 201, r.text
    stored = read_capture(app.state.wandcal.captures.folder(r.json()["id"]))
    sent = read_capture(imported)
    assert np.array_equal(stored.points.point, sent.points.point)
    assert np.array_equal(stored.points.frame, sent.points.frame)
    assert np.allclose(stored.points.uv, sent.points.uv)
    assert stored.axis.role.tolist() == sent.axis.role.tolist()
    assert read_capture(app.state.wandcal.captures.folder(r.json()["id"])).rig.wand_length is None


def test_unknown_and_bad_parts_are_refused_and_nothing_is_stored(client, imported):
    app, c = client
    extra = {"notes.csv": ("notes.csv", b"a,b\n", "text/csv")}
    r = c.post("/captures", files=_files(imported, RIG_FILE, POINTS_FILE, extra=extra))
    assert r.status_code == 422 and "unknown part 'notes.csv'" in r.text and "points.csv" in r.text
    mixed = {POINTS_FILE: (POINTS_FILE, b"frame,camera,u,v,point\n0,cam1,1,2,nose\n0,cam2,3,4,\n", "text/csv")}
    r = c.post("/captures", files=_files(imported, RIG_FILE, extra=mixed))
    assert r.status_code == 422 and "points.csv line 3, column 'point'" in r.text
    # a rig.json without a wand needs its points
    r = c.post("/captures", files=_files(imported, RIG_FILE))
    assert r.status_code == 422 and "wand.length_m" in r.text
    assert c.get("/captures").json()["captures"] == []


def test_a_multi_marker_wand_layout_is_taken_and_a_bad_one_refused(client, tmp_path):
    import json

    from wandcal.calib.sim.simulate import simulate_capture
    from wandcal.capture.folder import write_capture
    from wandcal.drivers.capture_files import WAND_FILE

    app, c = client
    layout = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0]]
    sim = simulate_capture(3, 20, seed=0, static=False, wand_markers=np.array(layout))
    write_capture(tmp_path / "w", sim.rig, sim.wand, None)
    r = c.post("/captures", files=_files(tmp_path / "w", RIG_FILE, WAND_FILE))
    assert r.status_code == 201, r.text
    assert np.allclose(read_capture(app.state.wandcal.captures.folder(r.json()["id"])).rig.wand_markers, layout)
    doc = json.loads((tmp_path / "w" / RIG_FILE).read_text())
    doc["wand"] = {"markers_m": [[0, 0, 0], [0.2, 0, 0], [0.2, 0, 0]]}
    bad = {RIG_FILE: (RIG_FILE, json.dumps(doc).encode(), "application/json")}
    r = c.post("/captures", files=bad)
    assert r.status_code == 422 and "wand.markers_m: markers 1 and 2 coincide" in r.text


def test_the_service_takes_a_drop_and_refuses_it_beside_a_floor(tmp_path):
    from tests.calib.start.test_vertical import _scene
    from wandcal.capture.folder import write_capture
    from wandcal.drivers.capture_files import DROP_FILE, FLOOR_FILE, WAND_FILE

    sim, drop = _scene(5, "drop", 20)
    folder = tmp_path / "cap"
    write_capture(folder, sim.rig, sim.wand, None, vertical=drop)
    files = {n: (n, (folder / n).read_bytes(), "text/csv") for n in (RIG_FILE, WAND_FILE, DROP_FILE)}
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        r = c.post("/captures", files=files)
        assert r.status_code == 201, r.text
        stored = read_capture(app.state.wandcal.captures.folder(r.json()["id"]))
        assert stored.vertical is not None and stored.vertical.kind == "drop"
        both = files | {FLOOR_FILE: (FLOOR_FILE, b"point,camera,u,v\n", "text/csv")}
        r = c.post("/captures", files=both)
        assert r.status_code == 422 and "drop.csv: the world's vertical is set by floor.csv" in r.text, r.text
