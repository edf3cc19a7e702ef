"""Security: the token compared in constant time and never shown; paths that cannot leave the
data and replay roots (planted symlinks included); upload and image-size limits, a
decompression bomb refused before decoding; CORS off by default."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given
from hypothesis import strategies as st

from tests.reliability.fuzzing import FUZZ, TRIED
from tests.reliability.test_fuzz_readers import SIM
from tests.service.conftest import REPO, free_port, server_env
from wandcal.capture.folder import write_capture
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

TOKEN = "wandcal-Secret-7f3a9c"  # distinctive, so a leak anywhere is found by a plain search
SECRET = "root:x:0:0:the-secret-outside-the-roots"


@pytest.fixture
def roots(tmp_path):
    """A replay root with a good capture and planted links out of it, and a secret beside it."""
    replay = tmp_path / "replay"
    write_capture(replay / "good", SIM.rig, SIM.wand, SIM.static)
    outside = tmp_path / "outside"
    write_capture(outside / "capture", SIM.rig, SIM.wand, SIM.static)
    (outside / "secret.csv").write_text(f"frame,camera,u,v\n0,{SECRET},1,2\n")
    (outside / "secret.json").write_text(json.dumps({"format": SECRET}))
    (replay / "link-to-outside").symlink_to(outside / "capture")  # a folder link
    planted = replay / "planted"
    write_capture(planted, SIM.rig, SIM.wand, SIM.static)
    (planted / WAND_FILE).unlink()
    (planted / WAND_FILE).symlink_to(outside / "secret.csv")  # a file link inside a capture
    rig_link = replay / "rig-link"
    write_capture(rig_link, SIM.rig, SIM.wand, SIM.static)
    (rig_link / RIG_FILE).unlink()
    (rig_link / RIG_FILE).symlink_to(outside / "secret.json")
    (replay / "inside-link").symlink_to(replay / "good")  # a link that stays inside is fine
    return tmp_path


@pytest.fixture
def client(roots):
    settings = Settings(data_dir=roots / "data", replay_root=roots / "replay", workers=0, token=TOKEN,
                        max_upload_bytes=200_000)
    with TestClient(create_app(settings), base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False,
                    headers={"Authorization": f"Bearer {TOKEN}"}) as c:
        yield c


def test_the_token_is_compared_in_constant_time(client, monkeypatch):
    from wandcal.service.api import deps

    calls = []
    real = deps.secrets.compare_digest
    monkeypatch.setattr(deps.secrets, "compare_digest", lambda a, b: calls.append((a, b)) or real(a, b))
    assert client.get("/captures", headers={"Authorization": "Bearer wandcal-Secret-7f3a9d"}).status_code == 401
    assert client.get("/captures").status_code == 200
    assert calls == [(b"wandcal-Secret-7f3a9d", TOKEN.encode()), (TOKEN.encode(), TOKEN.encode())]


@pytest.mark.parametrize("path, status", [
    ("good", 201), ("inside-link", 201), ("../outside/capture", 403), ("/etc", 403), ("good/../../outside/capture", 403),
    ("link-to-outside", 403), ("planted", 403), ("rig-link", 403), ("good/\0", 403),
])
def test_replay_paths_cannot_leave_the_replay_root(client, path, status):
    r = client.post("/captures", data={"path": path})
    assert r.status_code == status, r.text
    assert SECRET not in r.text
    if status == 403:
        assert "replay root" in r.json()["detail"] or "NUL" in r.json()["detail"]


def test_random_paths_and_planted_links_never_read_outside(roots, client):
    """Any path, with links planted anywhere under the root: a capture is made only from files
    whose real location is inside the replay root, and no answer shows the secret."""
    replay = (roots / "replay").resolve()
    names = ["good", "planted", "rig-link", "link-to-outside", "inside-link", "..", ".", "outside", "capture", "x"]
    paths = st.lists(st.sampled_from(names), min_size=1, max_size=4).map("/".join)

    @FUZZ
    @given(path=st.one_of(paths, paths.map(lambda p: "/" + p), st.text(max_size=30)))
    def fuzz(path):
        TRIED["replay path with planted links"] += 1
        r = client.post("/captures", data={"path": path})
        assert r.status_code in (201, 403, 422), r.text
        assert SECRET not in r.text
        if r.status_code == 201:
            read = (replay / path.lstrip("/")).resolve()
            assert read.is_relative_to(replay)
            assert all((read / n).resolve().is_relative_to(replay) for n in (RIG_FILE, WAND_FILE))

    fuzz()


def test_capture_ids_cannot_name_paths(client):
    for bad in ("..", "../../etc", "%2e%2e%2f%2e%2e%2fetc", "0" * 31 + "/", "0" * 33, "A" * 32):
        r = client.get(f"/captures/{bad}")
        assert r.status_code == 404, (bad, r.status_code)


def test_a_live_replay_whose_sync_csv_leads_outside_is_refused(roots, client):
    folder = roots / "replay" / "images"
    (folder / "frames" / "cam1").mkdir(parents=True)
    (folder / "sync.csv").symlink_to(roots / "outside" / "secret.csv")
    r = client.post("/capture/start", json={"cameras": [f"replay://{folder}"], "trigger": None, "frames": 5,
                                            "rate_hz": 50, "rig": json.loads((roots / "replay" / "good" / RIG_FILE)
                                                                               .read_text())})
    assert r.status_code == 422 and "leading outside" in r.json()["detail"], r.text
    assert SECRET not in r.text


def _png_header(width: int, height: int, idat: bytes) -> bytes:
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def test_image_bombs_are_refused_before_decoding(client, monkeypatch):
    """A 40 kB PNG that inflates to 10 GB, and a 200-byte JPEG claiming 30000 x 30000 (which made
    OpenCV allocate 1.7 GB), are refused without being decoded."""
    from wandcal.service import ingest

    decoded = []
    monkeypatch.setattr(ingest.cv2, "imdecode", lambda *a: decoded.append(a) or cv2.imdecode(*a))
    rig = (Path(client.app.state.wandcal.settings.replay_root) / "good" / RIG_FILE).read_bytes()
    capture = client.post("/captures", files={RIG_FILE: (RIG_FILE, rig)}).json()
    bomb = zlib.compressobj(9)
    idat = bomb.compress(b"\0" * (10 << 20)) + bomb.flush()  # the first 10 MB of a 100000^2 image
    jpeg = bytearray(cv2.imencode(".jpg", np.zeros((16, 16), np.uint8))[1].tobytes())
    sof = jpeg.find(b"\xff\xc0")
    jpeg[sof + 5: sof + 9] = struct.pack(">HH", 30000, 30000)
    for name, data in (("png", _png_header(100_000, 100_000, idat)), ("jpeg", bytes(jpeg))):
        r = client.post(f"/captures/{capture['id']}/framesets", data={"frame": "0"},
                        files={"cam1": (f"bomb.{name}", data, "application/octet-stream")})
        assert r.status_code == 422, r.text
        assert "100000x100000 but rig.json says 1280x1024" in r.text if name == "png" else "not a PNG" in r.text
    assert decoded == []


def test_uploads_over_the_limit_are_refused_before_parsing(client):
    big = b"0" * 300_000
    r = client.post("/captures", files={RIG_FILE: (RIG_FILE, b"{}"), WAND_FILE: (WAND_FILE, big)})
    assert r.status_code == 413 and "limit of 200000 bytes" in r.json()["detail"]
    r = client.post("/captures", content=b"x" * 300_000, headers={"content-type": "multipart/form-data; boundary=x",
                                                                   "transfer-encoding": "chunked"})
    assert r.status_code == 413


def test_cors_is_off_by_default(client):
    origin = {"Origin": "https://elsewhere.example", "Access-Control-Request-Method": "POST"}
    for r in (client.options("/captures", headers=origin), client.get("/captures", headers=origin)):
        assert not any(k.lower().startswith("access-control-") for k in r.headers), r.headers


def test_the_token_never_reaches_a_log_or_an_answer(tmp_path):
    """A real server at log level debug: requests with the right token, a near miss, bad input,
    unknown ids; neither its log nor any answer holds the token."""
    (tmp_path / "replay").mkdir()
    env = server_env(tmp_path, token=TOKEN, workers=0)
    port, log = free_port(), tmp_path / "server.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "wandcal.service.cli", "serve", "--port", str(port), "--log-level",
                                 "debug"], cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}/api/v1"
    try:
        from tests.reliability.servers import poll

        poll(lambda: _up(url), "the server to answer")
        good, near = {"Authorization": f"Bearer {TOKEN}"}, {"Authorization": f"Bearer {TOKEN[:-1]}x"}
        answers = [
            httpx.get(f"{url}/captures", headers=good), httpx.get(f"{url}/captures", headers=near),
            httpx.get(f"{url}/captures"), httpx.get(f"{url}/health", headers=good),
            httpx.post(f"{url}/captures", headers=good, files={RIG_FILE: (RIG_FILE, b"{not json")}),
            httpx.post(f"{url}/jobs", headers=good, json={"capture_id": "0" * 32}),
            httpx.get(f"{url}/jobs/nope", headers=good), httpx.get(f"http://127.0.0.1:{port}/", headers=good),
            httpx.get(f"{url}/captures", headers={"Authorization": f"Basic {TOKEN}"}),
        ]
    finally:
        proc.send_signal(2)
        proc.wait(20)
    statuses = [a.status_code for a in answers]
    assert statuses[:3] == [200, 401, 401] and statuses[-1] == 401, statuses
    assert not any(TOKEN in a.text or TOKEN[:-1] in a.text for a in answers)
    text = log.read_text()
    assert "GET /api/v1/captures" in text or "HTTP" in text  # the debug log did record requests
    assert TOKEN not in text and TOKEN[:-1] not in text


def _up(url: str) -> bool:
    try:
        return httpx.get(f"{url}/health", timeout=1.0).status_code == 200
    except httpx.TransportError:
        return False


def test_the_settings_never_show_the_token():
    settings = Settings(data_dir=Path("x"), token=TOKEN)
    assert TOKEN not in repr(settings) and TOKEN not in str(settings)
    assert os.environ.get("WANDCAL_TOKEN") != TOKEN
