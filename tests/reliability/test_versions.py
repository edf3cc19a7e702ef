"""Versions that outlive the release: the capture format, the result format and the service's
database written by this release are read by it (fixtures in tests/fixtures, made by
tests/fixtures/make_fixtures.py), a database from before versioning is migrated, and a capture, a
result or a database from a newer wandcal is refused by name: exit 2 on the command line, 4xx over HTTP."""

from __future__ import annotations

import json
import shutil
import sqlite3
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from wandcal.capture.folder import read_capture
from wandcal.capture.result_file import read_result
from wandcal.capture.rig_file import CAPTURE_FORMAT, CaptureFormatError, NewerFormatError
from wandcal.service.cli import main
from wandcal.service.db import SCHEMA_VERSION, NewerDatabaseError, init_db, schema_version
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
CAPTURE_1 = FIXTURES / "captures" / "wandcal-capture-1"
DATABASES = sorted((FIXTURES / "db").glob("schema-*.sqlite3"))
NEWER = "written by a newer wandcal"
CAMERAS = ["cam1", "cam2", "cam3", "cam4"]  # the fixture's rig (make_fixtures.py)


def _client(data_dir: Path) -> TestClient:
    app = create_app(Settings(data_dir=data_dir, workers=0))
    return TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False)


def _data_dir(tmp_path: Path, fixture: Path) -> Path:
    """A data directory with the fixture database and the capture folder its rows name."""
    data = tmp_path / "data"
    (data / "captures").mkdir(parents=True)
    shutil.copyfile(fixture, data / "wandcal.sqlite3")
    with sqlite3.connect(fixture) as conn:
        (capture_id,) = conn.execute("SELECT id FROM captures").fetchone()
    shutil.copytree(CAPTURE_1, data / "captures" / capture_id)
    return data


def _bumped(folder: Path, tmp_path: Path) -> Path:
    """A copy of ``folder`` whose rig.json says it is wandcal-capture/2."""
    out = shutil.copytree(folder, tmp_path / "newer")
    doc = json.loads((out / "rig.json").read_text())
    (out / "rig.json").write_text(json.dumps(doc | {"format": "wandcal-capture/2"}))
    return out


def test_there_is_a_fixture_of_each_schema_version():
    assert [p.name for p in DATABASES] == [f"schema-{v}.sqlite3" for v in range(SCHEMA_VERSION + 1)]


def test_this_release_reads_its_capture_fixture_and_solves_it(tmp_path, capsys):
    capture = read_capture(CAPTURE_1)
    assert [c.id for c in capture.rig.cameras] == CAMERAS
    assert main(["calibrate", str(CAPTURE_1), "--out", str(tmp_path / "result.json"), "--quiet"]) == 0
    result = read_result(tmp_path / "result.json")
    assert result.doc["format"] == "wandcal-result/1" and len(result.rig.cameras) == 4


@pytest.mark.parametrize("fixture", DATABASES, ids=lambda p: p.stem)
def test_this_release_reads_its_databases(fixture, tmp_path):
    data = _data_dir(tmp_path, fixture)
    with sqlite3.connect(fixture) as conn:
        conn.row_factory = sqlite3.Row
        stored = dict(conn.execute("SELECT * FROM jobs").fetchone())
    with _client(data) as client:
        (listed,) = client.get("/jobs").json()["jobs"]
        job = client.get(f"/jobs/{listed['id']}").json()
        capture = client.get(f"/captures/{stored['capture_id']}").json()
        exported = client.get(f"/jobs/{job['id']}/result", params={"format": "opencv-yaml"})
    assert job["id"] == stored["id"] and job["state"] == "done"
    assert job["result"] == json.loads(stored["result"])  # the record as written, to the last digit
    assert capture["cameras"] == CAMERAS
    assert exported.status_code == 200 and "camera_matrix" in exported.text.lower()
    with sqlite3.connect(data / "wandcal.sqlite3") as conn:
        assert schema_version(conn) == SCHEMA_VERSION


def test_a_database_from_before_versioning_is_migrated_once(tmp_path, caplog):
    data = _data_dir(tmp_path, FIXTURES / "db" / "schema-0.sqlite3")
    with caplog.at_level("INFO", logger="wandcal.service"):
        init_db(data / "wandcal.sqlite3")
    assert "database schema migrated to version 1" in caplog.text
    caplog.clear()
    with caplog.at_level("INFO", logger="wandcal.service"):
        init_db(data / "wandcal.sqlite3")  # at the current version: nothing to do, nothing said
    assert "migrated" not in caplog.text


def test_a_database_from_a_newer_wandcal_is_refused_by_name_and_left_alone(tmp_path, capsys):
    data = _data_dir(tmp_path, FIXTURES / "db" / f"schema-{SCHEMA_VERSION}.sqlite3")
    db = data / "wandcal.sqlite3"
    with sqlite3.connect(db) as conn:
        conn.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    before = db.read_bytes()
    with pytest.raises(NewerDatabaseError, match=f"{NEWER}: database schema version {SCHEMA_VERSION + 1}; upgrade"):
        init_db(db)
    assert main(["serve", "--data-dir", str(data), "--port", "1"]) == 2
    err = capsys.readouterr().err
    assert f"{NEWER}: database schema version {SCHEMA_VERSION + 1}; upgrade wandcal" in err and str(db) in err
    assert db.read_bytes() == before


def test_a_capture_from_a_newer_wandcal_is_refused_by_name(tmp_path, capsys):
    newer = _bumped(CAPTURE_1, tmp_path)
    with pytest.raises(NewerFormatError, match=f"{NEWER}: format wandcal-capture/2; upgrade wandcal"):
        read_capture(newer)
    assert main(["calibrate", str(newer), "--out", str(tmp_path / "result.json"), "--quiet"]) == 2
    assert f"{NEWER}: format wandcal-capture/2; upgrade wandcal" in capsys.readouterr().err
    assert not (tmp_path / "result.json").exists()
    files = {p.name: (p.name, p.read_bytes()) for p in sorted(newer.iterdir())}
    with _client(tmp_path / "data") as client:
        answer = client.post("/captures", files=files)
        assert answer.status_code == 422 and f"{NEWER}: format wandcal-capture/2" in answer.json()["detail"]
        assert client.get("/captures").json()["captures"] == []


def test_a_result_from_a_newer_wandcal_is_refused_by_name(tmp_path, capsys):
    assert main(["calibrate", str(CAPTURE_1), "--out", str(tmp_path / "result.json"), "--quiet"]) == 0
    doc = json.loads((tmp_path / "result.json").read_text())
    newer = tmp_path / "newer.json"
    newer.write_text(json.dumps(doc | {"format": "wandcal-result/2"}))
    with pytest.raises(NewerFormatError, match=f"{NEWER}: format wandcal-result/2; upgrade wandcal"):
        read_result(newer)
    assert main(["export", str(newer), "--format", "opencv-yaml"]) == 2
    assert f"{NEWER}: format wandcal-result/2; upgrade wandcal" in capsys.readouterr().err


@pytest.mark.parametrize("value", ["wandcal-capture/0", "wandcal-capture/1.5", "wandcal-capture/99999999999999",
                                   "wandcal-capture/٢", "wandcal-result/2", "", None, 2])
def test_other_formats_are_not_taken_for_newer_versions(value):
    doc = json.loads((CAPTURE_1 / "rig.json").read_text()) | {"format": value}
    from wandcal.capture.rig_file import rig_from_json

    with pytest.raises(CaptureFormatError, match=f"'format' must be '{CAPTURE_FORMAT}'") as raised:
        rig_from_json(doc)
    assert not isinstance(raised.value, NewerFormatError)
