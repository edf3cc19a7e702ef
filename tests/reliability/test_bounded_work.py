"""Bounded work (issue 20, class 3): every size a request or a file can have is checked before the
work starts: a JSON body over its route's limit is a 413 before it is parsed, a capture CSV over
MAX_CSV_BYTES is refused (exit 2) before it is read. The peak memory of the largest allowed
ones is measured by bench/bench_memory.py and published in docs/reliability.md."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from wandcal.capture.csv_tables import MAX_CSV_BYTES
from wandcal.capture.folder import rig_to_json, write_capture
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.request_limits import (
    MAX_BLOBSETS_BODY_BYTES,
    MAX_CHECK_BODY_BYTES,
    MAX_JSON_BODY_BYTES,
    body_limit,
)
from wandcal.service.settings import Settings

ROUTES = ["/api/v1/captures/0123/blobsets", "/api/v1/jobs", "/api/v1/capture/start", "/api/v1/capture",
          "/api/v1/captures", "/api/v1/captures/0123/framesets", "/api/v1/captures/0123/static",
          "/api/v1/captures/0123/check"]


@settings(max_examples=100, deadline=None, derandomize=True)
@given(path=st.sampled_from(ROUTES), upload=st.integers(1, 1 << 40))
def test_every_route_has_a_limit_no_larger_than_the_upload_limit(path, upload):
    limit, what = body_limit(path, upload)
    assert 0 < limit <= upload and what
    if "blobsets" in path:
        assert limit == min(upload, MAX_BLOBSETS_BODY_BYTES)
    elif path.endswith(("/jobs", "/capture/start", "/capture")):
        assert limit == min(upload, MAX_JSON_BODY_BYTES)
    elif path.endswith("/check"):
        assert limit == min(upload, MAX_CHECK_BODY_BYTES)


@pytest.fixture
def client(tmp_path):
    (tmp_path / "replay").mkdir()
    app = create_app(Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        yield c


def test_json_bodies_over_their_limit_are_refused_before_parsing(client, small_capture):
    _, sim = small_capture
    capture_id = client.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)))}).json()["id"]

    @settings(max_examples=10, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(extra=st.integers(1, 4096), chunked=st.booleans())
    def fuzz(extra, chunked):
        TRIED["JSON bodies over their route's limit"] += 1
        body = b'{"sets": [' + b" " * (MAX_BLOBSETS_BODY_BYTES + extra) + b"]}"
        content = iter([body[i:i + (1 << 20)] for i in range(0, len(body), 1 << 20)]) if chunked else body
        r = client.post(f"/captures/{capture_id}/blobsets", content=content, headers={"content-type": "application/json"})
        assert r.status_code == 413 and "blob-set limit" in r.json()["detail"], r.text
        r = client.post("/jobs", content=b" " * (MAX_JSON_BODY_BYTES + extra), headers={"content-type": "application/json"})
        assert r.status_code == 413

    fuzz()
    assert client.get(f"/captures/{capture_id}").json()["framesets"] == 0


def test_a_capture_file_over_the_limit_exits_2_before_it_is_read(small_capture, tmp_path, capsys):
    from wandcal.service.cli import main

    _, sim = small_capture
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    with open(tmp_path / WAND_FILE, "ab") as fh:  # a sparse file: the size is checked, never the content
        fh.truncate(MAX_CSV_BYTES + 1)
    code = main(["calibrate", str(tmp_path), "--out", str(tmp_path / "result.json")])
    err = capsys.readouterr().err
    assert code == 2 and f"{tmp_path / WAND_FILE}: {MAX_CSV_BYTES + 1} bytes, more than" in err, err


# Issue 34: every option and input size that scales work has a limit and a clear error past it
# (the table in docs/reliability.md, "Bounded work").


def test_a_rig_past_the_camera_limit_is_refused_naming_the_count(small_capture, tmp_path, capsys):
    from wandcal.capture.rig_file import MAX_CAMERAS, CaptureFormatError, rig_from_json
    from wandcal.service.cli import main

    _, sim = small_capture
    doc = rig_to_json(sim.rig)
    cams = doc["cameras"]
    many = doc | {"cameras": [cams[i % len(cams)] | {"id": f"c{i}"} for i in range(MAX_CAMERAS + 1)]}
    at_limit = many | {"cameras": many["cameras"][:MAX_CAMERAS]}
    assert len(rig_from_json(at_limit).cameras) == MAX_CAMERAS
    with pytest.raises(CaptureFormatError, match=f"{MAX_CAMERAS + 1} cameras, more than the {MAX_CAMERAS}"):
        rig_from_json(many)
    write_capture(tmp_path, sim.rig, sim.wand, sim.static)
    (tmp_path / RIG_FILE).write_text(json.dumps(many))
    assert main(["calibrate", str(tmp_path), "--out", str(tmp_path / "result.json")]) == 2
    assert f"{MAX_CAMERAS + 1} cameras, more than the {MAX_CAMERAS}" in capsys.readouterr().err


def test_a_rig_past_the_camera_limit_is_a_422(client, small_capture):
    from wandcal.capture.rig_file import MAX_CAMERAS

    _, sim = small_capture
    doc = rig_to_json(sim.rig)
    doc["cameras"] = [doc["cameras"][0] | {"id": f"c{i}"} for i in range(MAX_CAMERAS + 1)]
    r = client.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(doc))})
    assert r.status_code == 422 and f"more than the {MAX_CAMERAS}" in r.json()["detail"]


def test_sync_max_offset_past_its_limit_exits_2_and_is_a_422(client, small_capture, tmp_path, capsys):
    from wandcal.calib.run.options import MAX_SYNC_OFFSET
    from wandcal.service.cli import main

    folder, _ = small_capture
    with pytest.raises(SystemExit) as exited:  # argparse's own refusal: exit 2, naming the option
        main(["calibrate", str(folder), "--sync", "auto", "--sync-max-offset", str(MAX_SYNC_OFFSET + 1)])
    assert exited.value.code == 2 and "--sync-max-offset" in capsys.readouterr().err
    capture_id = client.post("/captures", files={n: (n, (folder / n).read_bytes()) for n in (RIG_FILE, WAND_FILE)}).json()["id"]
    r = client.post("/jobs", json={"capture_id": capture_id, "options": {"sync": "auto",
                                                                         "sync_max_offset": MAX_SYNC_OFFSET + 1}})
    assert r.status_code == 422 and "sync_max_offset" in r.json()["detail"]


def test_guidance_frames_past_their_limit_are_a_settings_error(tmp_path):
    from wandcal.service.settings import MAX_GUIDANCE_FRAMES, Settings, SettingsError

    assert Settings.load(data_dir=tmp_path, guidance={"frames_per_camera": MAX_GUIDANCE_FRAMES})
    with pytest.raises(SettingsError, match="guidance.frames_per_camera"):
        Settings.load(data_dir=tmp_path, guidance={"frames_per_camera": MAX_GUIDANCE_FRAMES + 1})


def _oversized(path):
    with open(path, "ab") as fh:  # sparse: the size is checked, never the content
        fh.truncate(MAX_CSV_BYTES + 1)
    return path


@pytest.mark.parametrize("name", ["cam1DLC.csv", "points.npy", "calibration.toml", "cameras.yaml", "profile.txt"])
def test_an_imported_file_over_the_limit_is_refused_before_it_is_read(tmp_path, name):
    """Issue 34: the importers read a file whole, so a file of any size was an allocation of any
    size; each is now refused from its size, naming the file, as the capture CSVs are."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.capture.formats.cameras_in import MAX_IMPORT_BYTES, read_camera_file
    from wandcal.capture.importers.anipose import read_anipose
    from wandcal.capture.importers.deeplabcut import read_dlc_csv, read_points_npy
    from wandcal.capture.importers.dltdv import read_text

    path = _oversized(tmp_path / name)
    read = {"cam1DLC.csv": lambda: read_dlc_csv(path), "points.npy": lambda: read_points_npy(path, 3, "calibration.toml"),
            "calibration.toml": lambda: read_anipose(path, [str(path.with_name("cam1DLC.csv"))]),
            "cameras.yaml": lambda: read_camera_file(path), "profile.txt": lambda: read_text(path, "camera profile")}
    with pytest.raises(CalibrationError, match="more than the") as refused:
        read[name]()
    assert f"{path}: {MAX_CSV_BYTES + 1} bytes, more than the {MAX_IMPORT_BYTES}" in str(refused.value)
