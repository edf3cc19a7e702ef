"""The default no-token server and a browser on the same machine (issue 20, class 9): DNS
rebinding (any Host name), cross-site state-changing requests, and absolute paths in answers."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import TRIED
from tests.service.conftest import capture_files
from wandcal.capture.folder import rig_to_json
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.api.security import relative_paths
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
LABEL = st.from_regex(r"[a-z][a-z0-9-]{0,14}", fullmatch=True)
NAMES = st.lists(LABEL, min_size=1, max_size=4).map(".".join)
PORTS = st.one_of(st.just(""), st.integers(1, 65535).map(lambda p: f":{p}"))
WRITES = [("post", "/jobs"), ("post", "/captures"), ("delete", "/jobs/0123"), ("patch", "/capture"),
          ("post", "/capture/start"), ("post", "/capture/stop")]


@pytest.fixture
def make_client(tmp_path):
    clients = []

    def make(**overrides):
        (tmp_path / "replay").mkdir(exist_ok=True)
        app = create_app(Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0, **overrides))
        client = TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False)
        client.__enter__()
        clients.append(client)
        return client

    yield make
    for c in clients:
        c.__exit__(None, None, None)


def test_a_host_name_not_the_servers_own_is_refused(make_client):
    client = make_client(allowed_hosts=["rigpc.lab.example"])

    @FUZZ
    @given(name=NAMES, port=PORTS)
    def fuzz(name, port):
        TRIED["Host headers naming another host (DNS rebinding)"] += 1
        allowed = name in ("localhost", "rigpc.lab.example")
        r = client.get("/health", headers={"host": name + port})
        assert r.status_code == (200 if allowed else 421), (name, r.text)
        r = client.post("/capture/start", json={"cameras": ["sim://?cameras=2"]}, headers={"host": name + port})
        assert (r.status_code == 421) != allowed, (name, r.text)

    fuzz()
    for host in ("127.0.0.1", "127.0.0.1:8750", "[::1]:8750", "localhost:8750", "LOCALHOST", "rigpc.lab.example:1",
                 "10.1.2.3"):
        assert client.get("/health", headers={"host": host}).status_code == 200, host
    assert make_client(allowed_hosts=["*"]).get("/health", headers={"host": "any.example"}).status_code == 200


@pytest.mark.parametrize("headers", [{"sec-fetch-site": "cross-site"}, {"sec-fetch-site": "same-site"},
                                     {"origin": "http://evil.example"}, {"origin": "http://127.0.0.1:9999"},
                                     {"origin": "null"}, {"origin": "http://localhost", "sec-fetch-site": "cross-site"}])
def test_cross_site_writes_are_refused_and_store_nothing(make_client, small_capture, headers):
    folder, _ = small_capture
    client = make_client()
    for method, path in WRITES:
        for extra in ({}, {"authorization": "Bearer anything"}):  # a server without a token has none to carry
            r = client.request(method.upper(), path, headers=headers | extra, json={})
            assert r.status_code == 403 and "cross-site" in r.json()["detail"], (method, path, r.text)
    r = client.post("/captures", files=capture_files(folder), headers=headers)
    assert r.status_code == 403
    assert client.get("/captures").json()["captures"] == []
    # reads stay open (CORS, off, keeps another site from reading the answer)
    assert client.get("/captures", headers=headers).status_code == 200


def test_same_origin_and_token_bearing_writes_pass(make_client, small_capture):
    folder, _ = small_capture
    client = make_client()
    for headers in ({"origin": "http://127.0.0.1", "sec-fetch-site": "same-origin"}, {"sec-fetch-site": "none"}, {}):
        assert client.post("/captures", files=capture_files(folder), headers=headers).status_code == 201, headers
    guarded = make_client(token="s3cret")
    cross = {"origin": "http://evil.example", "sec-fetch-site": "cross-site"}
    ok = guarded.post("/captures", files=capture_files(folder), headers=cross | {"authorization": "Bearer s3cret"})
    assert ok.status_code == 201
    wrong = guarded.post("/captures", files=capture_files(folder), headers=cross | {"authorization": "Bearer nope"})
    assert wrong.status_code == 401


def test_error_bodies_show_no_absolute_path(make_client, small_capture, tmp_path):
    _, sim = small_capture
    client = make_client()
    data_dir = str((tmp_path / "data").resolve())
    rig = json.dumps(rig_to_json(sim.rig)).encode()
    stream = client.post("/captures", files={RIG_FILE: (RIG_FILE, rig)}).json()["id"]
    answers = [
        client.post("/captures", files={RIG_FILE: (RIG_FILE, rig), WAND_FILE: (WAND_FILE, b"frame,camera,u,v\n1,x,2,3\n")}),
        client.post("/captures", data={"path": str(tmp_path / "replay" / "missing")}),
        client.post("/captures", data={"path": "/etc"}),
        client.post(f"/captures/{stream}/static"),
    ]
    for r in answers:
        assert 400 <= r.status_code < 500, r.text
        assert data_dir not in r.text and str(tmp_path) not in r.text, r.text


@FUZZ
@given(root=st.from_regex(r"(/[a-z0-9_-]{1,8}){1,4}", fullmatch=True),
       rest=st.lists(st.from_regex(r"[a-z0-9_-]{1,8}", fullmatch=True), min_size=1, max_size=3))
def test_relative_paths_cut_every_root_and_nothing_else(root, rest):
    relative = "/".join(rest)
    text = f"{root}/{relative}: bad; see {root} and {relative}{root} and '{root}2'"
    assert relative_paths(text, [root]) == f"{relative}: bad; see . and {relative}{root} and '{root}2'"
