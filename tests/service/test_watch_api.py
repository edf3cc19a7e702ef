"""Watch over HTTP (issue 36): a take uploaded to a capture with its standing result, watched as a
job, gives the figures ``wandcal watch`` gives on the same files; bad input is a 4xx naming the part."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from tests.service.conftest import REPO, capture_files, free_port, wandcal
from wandcal.drivers.capture_files import RIG_FILE, TAKE_FILE

WATCH_TIMEOUT_S = 300.0  # a 600-frame take of 6 cameras is seconds of CPU; the machine is shared


@pytest.fixture(scope="module")
def root(tmp_path_factory, watch_standing, watch_knock_take):
    """wand: the capture ``standing.json`` was calibrated from; knock: cam2 knocked at 300 (both
    tests/service/conftest.py, shared with the other watch tests); other: a take of another rig."""
    root = tmp_path_factory.mktemp("watch_api")
    shutil.copytree(watch_standing.parent / "wand", root / "wand")
    shutil.copyfile(watch_standing, root / "standing.json")
    shutil.copytree(watch_knock_take, root / "knock")
    r = wandcal("simulate", str(root / "other"), "--take", "--cameras", "6", "--frames", "200", "--seed", "8")
    assert r.returncode == 0, r.stderr
    return root


def wait_watch(c, watch_id: str) -> dict:
    deadline = time.monotonic() + WATCH_TIMEOUT_S
    while time.monotonic() < deadline:
        watch = c.get(f"/watch/{watch_id}").json()
        if watch["state"] in ("done", "failed", "cancelled"):
            return watch
        time.sleep(0.1)
    raise AssertionError(f"watch {watch_id} still {watch['state']} after {WATCH_TIMEOUT_S} s")


def take_part(folder, text: str | None = None) -> dict:
    return {TAKE_FILE: (TAKE_FILE, text if text is not None else (folder / TAKE_FILE).read_bytes(), "text/csv")}


@pytest.mark.long
def test_watch_over_http_gives_the_cli_figures(make_server, root, tmp_path):
    server = make_server(workers=1).start()
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(root / "wand")).json()["id"]
        job_id = c.post("/jobs", json={"capture_id": capture_id, "method": "ba"}).json()["id"]
        deadline = time.monotonic() + WATCH_TIMEOUT_S
        while c.get(f"/jobs/{job_id}").json()["state"] not in ("done", "failed") and time.monotonic() < deadline:
            time.sleep(0.1)
        standing = c.get(f"/jobs/{job_id}/result").json()
        (tmp_path / "standing.json").write_text(json.dumps(standing, indent=2) + "\n")
        r = c.post("/watch", files=take_part(root / "knock"), data={"job_id": job_id, "write": "true"})
        assert r.status_code == 202, r.text
        watch = wait_watch(c, r.json()["id"])
        assert watch["state"] == "done", watch["error"]
        assert c.get(f"/jobs/{watch['id']}").status_code == 404  # a watch is not a calibration job
        updated = c.get(f"/watch/{watch['id']}/result").json()
    cli = wandcal("watch", str(tmp_path / "standing.json"), str(root / "knock"), "--json",
                  "--write", str(tmp_path / "updated.json"))
    assert cli.returncode == 1, cli.stderr  # a camera moved
    printed, _ = json.JSONDecoder().raw_decode(cli.stdout)  # --write's "wrote ..." line follows the JSON
    assert watch["report"] == printed  # every figure, to the digits the CLI prints
    assert watch["report"]["moved"] == ["cam2"]
    mine = {c["id"]: c for c in updated["cameras"]}
    for entry in json.loads((tmp_path / "updated.json").read_text())["cameras"]:
        assert np.array_equal(mine[entry["id"]]["R"], entry["R"]) and np.array_equal(mine[entry["id"]]["t"], entry["t"])
    assert updated["watch"]["resolved"] == ["cam2"] and updated["watch"]["standing"] == f"job {job_id}'s result"
    assert updated["watch"]["take"].startswith("takes/") and updated["watch"]["standing_sha256"]


def test_bad_input_is_a_4xx_naming_the_part(make_server, root, tmp_path):
    server = make_server(workers=1).start()
    standing = root / "standing.json"  # `wandcal calibrate` of the wand capture (tests/service/conftest.py)
    result = {"result.json": ("result.json", standing.read_bytes(), "application/json")}
    lines = (root / "knock" / TAKE_FILE).read_text().splitlines()
    with server.client() as c:
        capture_id = c.post("/captures", files=capture_files(root / "wand")).json()["id"]
        ok = {"capture_id": capture_id}
        r = c.post("/watch", files=take_part(root, "frame,camera,u,v\n") | result, data=ok)
        assert r.status_code == 422 and TAKE_FILE in r.json()["detail"] and "no blobs" in r.json()["detail"], r.text
        one = "\n".join([lines[0], *[x for x in lines[1:] if ",cam1," in x]]) + "\n"
        r = c.post("/watch", files=take_part(root, one) | result, data=ok)
        assert r.status_code == 422 and "blobs in only 1 camera(s) (cam1)" in r.json()["detail"], r.text
        renamed = standing.read_text().replace('"cam6"', '"cam9"')  # a result of another rig
        r = c.post("/watch", files=take_part(root / "knock") | {"result.json": ("result.json", renamed, "application/json")},
                   data=ok)
        assert r.status_code == 422 and "result.json" in r.json()["detail"] and "cam9" in r.json()["detail"], r.text
        r = c.post("/watch", files=take_part(root / "knock"), data=ok)
        assert r.status_code == 422 and "job_id" in r.json()["detail"], r.text
        r = c.post("/watch", files=take_part(root / "knock") | result, data={"capture_id": "nope"})
        assert r.status_code == 404 and "capture_id" in r.json()["detail"], r.text
        r = c.post("/watch", files=take_part(root / "knock") | result, data=ok | {"write": "maybe"})
        assert r.status_code == 422 and "write" in r.json()["detail"], r.text
        # cameras of the same ids and lenses placed elsewhere: the watch runs and fails with the CLI's words
        other = take_part(root / "other") | {RIG_FILE: (RIG_FILE, (root / "other" / RIG_FILE).read_bytes(), "application/json")}
        r = c.post("/watch", files=other | result, data=ok)
        assert r.status_code == 202, r.text
        watch = wait_watch(c, r.json()["id"])
        assert watch["state"] == "failed" and "does not fit" in watch["error"], watch
        assert c.get(f"/watch/{watch['id']}/result").status_code == 409
    assert len(list((tmp_path / "data" / "takes").iterdir())) == 1  # a refused take leaves nothing behind


@pytest.mark.long
def test_watch_on_an_rq_worker(make_server, root, tmp_path, watch_knock):
    """The same take watched by an rq worker that never sees the data folder: the report
    ``wandcal watch --json`` printed of the same result and take (tests/service/conftest.py)."""
    pytest.importorskip("rq", reason="pip install 'wandcal[redis]' to test the Redis queue")
    from tests.service.test_redis import REDIS_SERVER, _wait_for_redis

    if REDIS_SERVER is None:
        pytest.skip("redis-server is not installed")
    standing = root / "standing.json"
    port = free_port()
    redis = subprocess.Popen([REDIS_SERVER, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
                              "--dir", str(tmp_path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"redis://127.0.0.1:{port}/0"
    try:
        _wait_for_redis(url, redis)
        server = make_server(queue="redis", redis_url=url, workers=0).start()
        with server.client() as c:
            capture_id = c.post("/captures", files=capture_files(root / "wand")).json()["id"]
            r = c.post("/watch", files=take_part(root / "knock")
                       | {"result.json": ("result.json", standing.read_bytes(), "application/json")},
                       data={"capture_id": capture_id})
            assert r.status_code == 202, r.text
            worker = subprocess.run([sys.executable, "-m", "rq.cli", "worker", "--burst", "--url", url, "wandcal"],
                                    cwd=tmp_path, env=dict(server.env, PYTHONPATH=str(REPO)), capture_output=True,
                                    text=True, timeout=600, check=False)
            assert worker.returncode == 0, worker.stderr
            watch = wait_watch(c, r.json()["id"])
    finally:
        redis.terminate()
        redis.wait(10)
    assert watch["state"] == "done", watch["error"]
    cli = watch_knock[1]
    assert cli.returncode == 1, cli.stderr
    assert watch["report"] == json.loads(cli.stdout)
