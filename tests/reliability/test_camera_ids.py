"""Camera ids that round-trip (issue 20, class 5): an id is checked where it enters (rig.json,
imports, the API); any accepted id survives write -> crash -> restart -> read with every
acknowledged row, and a refused one is refused naming the camera. (Before: an id with a comma,
a newline, a carriage return or leading whitespace was stored, written unquoted and read back as
another id; recovery counted lines differently from the writer and cut acknowledged rows.)"""

from __future__ import annotations

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import CAMERA_ID, Camera
from wandcal.capture.folder import CaptureFormatError, read_capture, write_capture
from wandcal.capture.rig_file import rig_from_json
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

K = [[1000.0, 0, 640], [0, 1000.0, 512], [0, 0, 1]]
SAFE = st.from_regex(CAMERA_ID, fullmatch=True)
# what a hand-written rig.json or an import may hold: separators, quotes, line ends of every kind,
# whitespace, control and non-ASCII characters, and the safe ids
ANY = st.one_of(SAFE, st.text(max_size=12), st.sampled_from(["a,b", "a\nb", "a\rb", " cam1", "cam1 ", '"q"', "a\x1cb",
                                                             "a\u2028b", "a\x85b", "", "ü", "cam\t1", "-x"]))


def _rig_doc(ids: list[str]) -> dict:
    return {"format": "wandcal-capture/1", "wand": {"length_m": 0.5},
            "cameras": [{"id": i, "width": 1280, "height": 1024, "K": K, "dist": [0, 0, 0, 0, 0]} for i in ids]}


def _accepted(cid: str) -> bool:
    try:
        Camera(cid, 1280, 1024, np.array(K), np.zeros(5))
        return True
    except CalibrationError:
        return False


@settings(max_examples=300, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(ids=st.lists(ANY, min_size=2, max_size=4, unique=True))
def test_an_id_is_accepted_only_if_it_round_trips_through_the_folder(ids, tmp_path_factory):
    TRIED["camera ids of any characters"] += 1
    try:
        rig = rig_from_json(_rig_doc(ids))
    except CaptureFormatError as exc:
        bad = next(i for i in ids if not _accepted(i))
        assert "camera id" in str(exc) and "rig.json" in str(exc), str(exc)
        assert repr(bad[:80]) in str(exc)
        return
    assert all(CAMERA_ID.fullmatch(i) for i in ids)
    folder = tmp_path_factory.mktemp("ids")
    n = len(ids)
    frame = np.repeat(np.arange(6), 2 * n)
    camera = np.tile(np.repeat(np.arange(n), 2), 6)
    uv = np.random.default_rng(len(ids)).uniform(0, 1000, (len(frame), 2)).round(4)
    from wandcal.calib.rig import WandObservations

    write_capture(folder, rig, WandObservations(frame, camera, uv), None)
    back = read_capture(folder)
    assert back.rig.ids == ids
    np.testing.assert_array_equal(back.wand.camera, camera)
    np.testing.assert_allclose(back.wand.uv, uv, atol=1e-4)


@pytest.fixture
def data_dir(tmp_path):
    (tmp_path / "replay").mkdir()
    return tmp_path


def _client(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0))
    return TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False)


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(ids=st.lists(ANY, min_size=2, max_size=3, unique=True), sets=st.integers(1, 6), cut=st.integers(1, 20))
def test_any_accepted_id_survives_streaming_a_crash_and_a_restart(ids, sets, cut, tmp_path_factory):
    TRIED["camera ids streamed through a crash and a restart"] += 1
    root = tmp_path_factory.mktemp("restart")
    (root / "replay").mkdir()
    with _client(root) as client:
        r = client.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(_rig_doc(ids)).encode())})
        if not all(_accepted(i) for i in ids):
            assert r.status_code == 422 and "camera id" in r.json()["detail"], r.text
            return
        assert r.status_code == 201, r.text
        capture_id = r.json()["id"]
        body = {"sets": [{"frame": f, "blobs": {i: [[10.0 + f, 20.0], [30.0, 40.0 + f]] for i in ids}}
                         for f in range(sets)]}
        assert client.post(f"/captures/{capture_id}/blobsets", json=body).status_code == 201
        wand = root / "data" / "captures" / capture_id / WAND_FILE
    # a crash mid-append of a set that was never answered: part of a row at the file's end
    with open(wand, "ab") as fh:
        fh.write(f"{sets},{ids[0]},1.0000,2.0000\n".encode()[:cut])
    with _client(root) as client:  # the restart: recovery runs
        row = client.get(f"/captures/{capture_id}").json()
        assert row["cameras"] == ids
        capture = read_capture(wand.parent)
    assert capture.rig.ids == ids
    assert len(capture.wand) == 2 * len(ids) * sets  # every acknowledged row, nothing of the cut one
    assert sorted(set(capture.wand.frame.tolist())) == list(range(sets))
