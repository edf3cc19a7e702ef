"""Readers that agree (issue 20, class 8): the same capture files fed through every path that
reads them (the folder reader of ``wandcal calibrate`` and ``detect``, an HTTP upload, an HTTP
replay of the folder, an import) give the same outcome: accepted with the same rows, or refused.
(Before: a UTF-8 byte-order mark was refused by the CLI and accepted over HTTP; axis.csv was
ignored without a word when static.csv was present; an import exited 0 and wrote a capture that
calibrate refused.)"""

from __future__ import annotations

import shutil

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED, mutated_csv
from wandcal.calib.rig import AxisObservations
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import (
    CaptureFormatError,
    read_capture,
    write_capture,
)
from wandcal.capture.importers.summary import Imported
from wandcal.drivers.capture_files import AXIS_FILE, RIG_FILE, STATIC_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

UPLOADED = (RIG_FILE, WAND_FILE, STATIC_FILE)  # the parts POST /captures takes
BOM = b"\xef\xbb\xbf"
SIM = simulate_capture(cameras=3, frames=60, noise_px=0.3, seed=8)


@pytest.fixture(scope="module")
def valid(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("valid")
    write_capture(folder, SIM.rig, SIM.wand, SIM.static)
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    root = tmp_path_factory.mktemp("served")
    (root / "replay").mkdir()
    app = create_app(Settings(data_dir=root / "data", replay_root=root / "replay", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as client:
        yield client, root / "replay"


def _variant(valid: dict[str, bytes], bom: list[str], crlf: bool, mutated: tuple[str, bytes] | None) -> dict:
    files = dict(valid)
    if mutated is not None:
        files[mutated[0]] = mutated[1]
    if crlf:
        files = {n: d.replace(b"\r\n", b"\n").replace(b"\n", b"\r\n") for n, d in files.items()}
    return {n: (BOM + d if n in bom else d) for n, d in files.items()}


def _outcomes(files: dict[str, bytes], client, replay_root, k: int) -> dict[str, int | None]:
    """Rows read by each path, or None where it refused."""
    folder = replay_root / f"case{k}"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    for name, data in files.items():
        (folder / name).write_bytes(data)
    out: dict[str, int | None] = {}
    try:
        out["folder (CLI)"] = len(read_capture(folder).wand)
    except CaptureFormatError:
        out["folder (CLI)"] = None
    for label, response in (
        ("upload", client.post("/captures", files={n: (n, d) for n, d in files.items() if n in UPLOADED})),
        ("replay", client.post("/captures", data={"path": folder.name})),
    ):
        assert response.status_code in (201, 413, 422), response.text
        body = response.json()
        out[label] = sum(c["blobs"] for c in body["coverage"]) if response.status_code == 201 else None
    return out


def test_the_same_files_give_the_same_outcome_on_every_path(valid, served):
    client, replay_root = served
    names = [RIG_FILE, WAND_FILE, STATIC_FILE]
    k = iter(range(10**6))

    @settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
    @given(bom=st.lists(st.sampled_from(names), unique=True), crlf=st.booleans(),
           mutated=st.none() | st.sampled_from([WAND_FILE, STATIC_FILE]).flatmap(
               lambda n: mutated_csv(valid[n].decode()).map(lambda d: (n, d))))
    def fuzz(bom, crlf, mutated):
        TRIED["capture files through the CLI, upload and replay paths"] += 1
        outcomes = _outcomes(_variant(valid, bom, crlf, mutated), client, replay_root, next(k))
        assert len(set(outcomes.values())) == 1, outcomes

    fuzz()


def test_a_byte_order_mark_is_read_alike_everywhere(valid, served):
    client, replay_root = served
    outcomes = _outcomes(_variant(valid, [RIG_FILE, WAND_FILE, STATIC_FILE], False, None), client, replay_root, -1)
    assert set(outcomes.values()) == {len(SIM.wand)}, outcomes


def test_axis_points_beside_a_static_object_are_refused_not_ignored(valid, served):
    client, replay_root = served
    files = dict(valid) | {AXIS_FILE: b"role,camera,u,v\norigin,cam1,100,200\norigin,cam2,300,400\n"}
    outcomes = _outcomes(files, client, replay_root, -2)
    assert outcomes["folder (CLI)"] is None and outcomes["replay"] is None
    with pytest.raises(CaptureFormatError, match="axis.csv: the world frame is set by static.csv"):
        read_capture(replay_root / "case-2")


def test_an_import_whose_capture_calibrate_would_refuse_is_refused_before_writing(tmp_path):
    from wandcal.capture.folder import Capture

    axis = AxisObservations(role=["origin", "origin"], camera=[0, 1], uv=[[100.0, 200.0], [300.0, 400.0]])
    with pytest.raises(CaptureFormatError, match="session.mat: the capture's axis.csv.*nothing was written"):
        Imported(Capture(SIM.rig, SIM.wand, SIM.static, axis=axis), "session.mat")
    Imported(Capture(SIM.rig, SIM.wand, SIM.static), "session.mat")  # a sound one passes
