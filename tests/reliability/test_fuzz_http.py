"""The readers' fuzz cases sent as uploads: every answer is 201 or a 4xx that names the file or
field, never a 500. The app runs in-process (ASGI, as schemathesis drives it in
tests/service/test_fuzz.py); the real server over loopback is in test_load.py and test_faults.py."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import FUZZ, TRIED, garbage_bytes
from tests.reliability.test_fuzz_readers import GOOD_PNG, IMAGES, SIM, _bad_file, _kind
from wandcal.capture.folder import write_capture
from wandcal.drivers.capture_files import RIG_FILE, STATIC_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

UPLOAD_LIMIT = 1_000_000  # small, so the fuzzer's long files also meet the 413 path


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    root = tmp_path_factory.mktemp("http")
    (root / "replay").mkdir()
    write_capture(root / "replay" / "good", SIM.rig, SIM.wand, SIM.static)
    settings = Settings(data_dir=root / "data", replay_root=root / "replay", workers=0, max_upload_bytes=UPLOAD_LIMIT,
                        framesets_per_second=1e6)
    with TestClient(create_app(settings), base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        yield c


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, bytes]:
    folder = tmp_path_factory.mktemp("files")
    write_capture(folder, SIM.rig, SIM.wand, SIM.static)
    return {n: (folder / n).read_bytes() for n in (RIG_FILE, WAND_FILE, STATIC_FILE)}


def _answered(r, kind: str, names: tuple[str, ...]) -> None:
    TRIED[f"HTTP {kind}"] += 1
    assert r.status_code in (201, 400, 403, 404, 409, 413, 415, 422), (r.status_code, r.text)
    if r.status_code == 422:
        detail = r.json()["detail"]
        assert any(n in detail for n in names), detail


@pytest.mark.parametrize("name", [RIG_FILE, WAND_FILE, STATIC_FILE])
def test_uploaded_capture_files(client, files, name):
    @FUZZ
    @given(data=_bad_file(files[name]))
    def fuzz(data):
        upload = {n: (n, data if n == name else content) for n, content in files.items()}
        r = client.post("/captures", files=upload)
        _answered(r, f"POST /captures {name}: {_kind(data, files[name])}", (name,))

    fuzz()


def test_replay_paths(client):
    paths = st.one_of(st.text(max_size=80), st.sampled_from(["good", "../", "/etc", "good/../../x", "\0", "~", "."]))

    @FUZZ
    @given(path=paths)
    def fuzz(path):
        r = client.post("/captures", data={"path": path})
        _answered(r, "POST /captures path", ("path", "replay", "rig.json", "wand.csv", "folder"))

    fuzz()


def test_streamed_frame_sets(client, files):
    capture = client.post("/captures", files={RIG_FILE: (RIG_FILE, files[RIG_FILE])}).json()
    small = json.loads(files[RIG_FILE])
    fields = st.fixed_dictionaries({
        "frame": st.one_of(st.integers(-10, 10**25).map(str), st.text(max_size=30), st.just("99999999999999999999")),
    })

    @FUZZ
    @given(form=fields, image=st.one_of(IMAGES, garbage_bytes()), camera=st.sampled_from([c["id"] for c in small["cameras"]]
                                                                                       + ["nope", ""]))
    def fuzz(form, image, camera):
        r = client.post(f"/captures/{capture['id']}/framesets", data=form,
                        files={camera or "x": ("f.png", image, "image/png")})
        _answered(r, "POST /captures/{id}/framesets", ("frame", "camera", "image", "field"))

    fuzz()
    assert GOOD_PNG  # the good image is in IMAGES' truncations: some frame sets were whole PNGs
