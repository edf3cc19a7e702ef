"""Faults, and what survives each (docs/reliability.md): SIGKILL of the real server during an
upload and during a live recording, a full disk (a small tmpfs), a corrupt database at start,
the trigger vanishing during a live capture, and a camera that stalls. SIGKILL during a job is
tests/service/test_http.py::test_sigkill_mid_job_requeues_once_and_finishes."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import threading
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from tests.reliability.servers import poll
from tests.service.conftest import capture_files, simulated_capture
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.sim.render import render_blobs
from wandcal.capture.folder import read_capture, rig_to_json
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.datafolder.recovery import RECOVERED_SOURCE
from wandcal.service.db import connect
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

DISK_BYTES = 4 << 20  # a small tmpfs: the database, a few captures, then full
SMALL = (320, 240)  # streamed frame sets of small cameras keep the disk test's images small


@pytest.fixture(scope="module")
def capture_folder(tmp_path_factory):
    return simulated_capture(tmp_path_factory.mktemp("cap") / "c", cameras=3, frames=150, noise_px=0.3, seed=11)


# -- SIGKILL ----------------------------------------------------------------------------------
def test_sigkill_during_an_upload_leaves_no_trace_and_loses_nothing_stored(server, capture_folder):
    """Killed while a 3 MB upload streams in (spooled to data/tmp): after the restart the earlier
    capture is intact, no partial folder or spool file is left, and the upload succeeds when sent again."""
    folder, sim = capture_folder
    srv = server(workers=0)
    with srv.client() as c:
        kept = c.post("/captures", files=capture_files(folder)).json()
        parts = capture_files(folder)
        big = parts[WAND_FILE][1] + b"".join(f"{9000 + k},cam1,1.0,2.0\n".encode() for k in range(150_000))
        request = httpx.Request("POST", srv.url, files={RIG_FILE: parts[RIG_FILE], WAND_FILE: (WAND_FILE, big)})
        body, content_type = request.read(), request.headers["content-type"]
        release = threading.Event()

        def slow_body():
            yield body[: len(body) // 2]
            release.wait(30)
            yield body[len(body) // 2:]

        sender = threading.Thread(target=lambda: _send_ignoring_errors(srv, slow_body(), content_type), daemon=True)
        sender.start()
        spool = str(Path(srv.env["WANDCAL_DATA_DIR"]) / "tmp")
        poll(lambda: _open_files_under(srv.proc.pid, spool), "the server spooling the upload to data/tmp")
        srv.kill()
        release.set()
        sender.join(10)
    srv.start()
    with srv.client() as c:
        listed = c.get("/captures").json()["captures"]
        assert [x["id"] for x in listed] == [kept["id"]] and listed[0]["frames"] == kept["frames"]
        data = Path(srv.env["WANDCAL_DATA_DIR"])
        assert not list((data / "captures").glob(".*")) and not list((data / "tmp").iterdir())
        assert read_capture(data / "captures" / kept["id"]).wand.frame.tolist() == sim.wand.frame.tolist()
        assert c.post("/captures", files=capture_files(folder)).status_code == 201
    srv.stop()


def _open_files_under(pid: int, folder: str) -> list[str]:
    """Files process ``pid`` holds open under ``folder`` (Linux /proc; spooled uploads are
    unnamed O_TMPFILE files, seen only there)."""
    fds = Path(f"/proc/{pid}/fd")
    out = []
    for fd in fds.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith(folder):
            out.append(target)
    return out


def _send_ignoring_errors(srv, body, content_type: str) -> None:
    with contextlib.suppress(httpx.HTTPError):  # the server died under it: that is the test
        httpx.post(srv.url + "/api/v1/captures", content=body, headers={"content-type": content_type}, timeout=30)


def test_sigkill_during_a_live_recording_keeps_every_recorded_set(server):
    """Killed while recording: at the restart the recording is a capture holding every set whose
    row reached sync.csv, with its blobs (recorded live); only the images still queued for the
    PNG writer at the kill (its bound: capture/recording/session.py) are missing, and they are the newest."""
    from wandcal.capture.recording.session import BYTES_PER_PIXEL, WRITE_SECONDS, buffer_frames

    rate_hz, cameras = 50.0, 2
    srv = server(workers=0)
    with srv.client() as c:
        r = c.post("/capture/start", json={"cameras": [f"sim://?cameras={cameras}&seed=3&frames=3000"],
                                           "trigger": None, "frames": 3000, "rate_hz": rate_hz})
        assert r.status_code == 202, r.text
        capture_id = r.json()["capture_id"]
        poll(lambda: c.get("/capture").json()["frames_recorded"] >= 20, "20 recorded frame sets")
    srv.kill()
    data = Path(srv.env["WANDCAL_DATA_DIR"])
    staging = data / "captures" / f".{capture_id}.partial"
    rows_at_kill = (staging / "sync.csv").read_text().splitlines()[1:]
    assert len(rows_at_kill) >= 20
    srv.start()
    with srv.client() as c:
        listed = {x["id"]: x for x in c.get("/captures").json()["captures"]}
        assert listed[capture_id]["source"] == RECOVERED_SOURCE, listed
        assert c.post("/jobs", json={"capture_id": capture_id}).status_code == 202  # ready to calibrate
    srv.stop()
    kept = data / "captures" / capture_id
    assert not staging.exists()
    rows = (kept / "sync.csv").read_text().splitlines()[1:]
    assert rows[: len(rows_at_kill) - 1] == rows_at_kill[:-1]  # every whole row is still there
    capture = read_capture(kept)
    frames = [int(r.split(",")[0]) for r in rows]
    assert set(capture.wand.frame) <= set(frames) and len(np.unique(capture.wand.frame)) >= 0.9 * len(frames)
    missing = [f for f in frames if cv2.imread(str(kept / "frames" / "cam1" / f"{f:06d}.png")) is None]
    bound = buffer_frames(rate_hz, cameras, WRITE_SECONDS, 1280 * 1024 * BYTES_PER_PIXEL)
    assert len(missing) <= bound and all(f >= frames[-1] - bound for f in missing)


def test_a_half_drawn_report_is_cleared_at_start(tmp_path):
    """A kill while a report is drawn leaves its staging folder; the start removes it (the next
    request draws the report again) and leaves finished reports alone."""
    reports = tmp_path / "data" / "reports"
    half = reports / f".{'a' * 32}.{'b' * 32}.partial"
    done = reports / ("c" * 32)
    for folder in (half, done):
        folder.mkdir(parents=True)
        (folder / "rig.png").write_bytes(b"png")
    with TestClient(create_app(Settings(data_dir=tmp_path / "data", workers=0)), base_url="http://127.0.0.1/api/v1"):
        pass
    assert not half.exists() and (done / "rig.png").is_file()


def test_corrupt_database_at_start(server, capture_folder):
    """A database SQLite cannot read is moved aside (kept), a new one is made, and every capture
    is registered again from its folder: the captures survive, the job records stay in the moved file."""
    folder, _ = capture_folder
    srv = server(workers=0)
    with srv.client() as c:
        kept = c.post("/captures", files=capture_files(folder)).json()
    srv.stop()
    db = Path(srv.env["WANDCAL_DATA_DIR"]) / "wandcal.sqlite3"
    damaged = bytearray(db.read_bytes())
    damaged[:100] = os.urandom(100)  # the header: "file is not a database"
    db.write_bytes(bytes(damaged))
    srv.start()
    with srv.client() as c:
        (again,) = c.get("/captures").json()["captures"]
        assert again["id"] == kept["id"] and again["frames"] == kept["frames"]
        assert again["coverage"] == kept["coverage"]
        r = c.post("/jobs", json={"capture_id": kept["id"]})
        assert r.status_code == 202, r.text
    srv.stop()
    moved = list(db.parent.glob("wandcal.sqlite3.corrupt-*"))
    assert any(p.name.count("-") == 2 and p.read_bytes()[:100] == bytes(damaged[:100]) for p in moved)
    assert "is corrupt" in srv.log.read_text()


# -- a full disk ------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    mount = tmp_path / "disk"
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("a full disk is simulated with a small tmpfs, and mounting one needs root (CI runs as root)")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs", str(mount)],
                          capture_output=True, text=True, check=False)
    if done.returncode:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip()}); a container without CAP_SYS_ADMIN")
    yield mount
    subprocess.run(["umount", "-l", str(mount)], check=False)


def _small_rig() -> Rig:
    w, h = SMALL
    K = np.array([[300.0, 0, w / 2], [0, 300.0, h / 2], [0, 0, 1]])
    return Rig((Camera("a", w, h, K, np.zeros(5)), Camera("b", w, h, K, np.zeros(5))), 0.5)


def _frameset(frame: int) -> dict:
    w, h = SMALL
    uv = np.array([[60.0 + frame, 80.0], [200.0, 150.0 - frame]])
    png = cv2.imencode(".png", render_blobs((h, w), uv, sigma_px=1.5))[1].tobytes()
    return {"a": ("a.png", png, "image/png"), "b": ("b.png", png, "image/png")}


def _fill(path: Path) -> None:
    with open(path, "wb") as fh:
        try:
            while True:
                fh.write(b"\0" * 65536)
                fh.flush()
        except OSError:
            pass


def test_a_frame_set_killed_before_its_commit_is_not_doubled_by_its_retry(tmp_path):
    """A SIGKILL between a streamed frame set's wand.csv append and its COMMIT leaves its rows in
    the file and no frame-set row; the client, never answered, sends it again after the restart."""
    settings = Settings(data_dir=tmp_path / "data", workers=0, framesets_per_second=1e6)
    with TestClient(create_app(settings), base_url="http://127.0.0.1/api/v1") as c:
        stream = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(_small_rig())).encode())}).json()
        assert c.post(f"/captures/{stream['id']}/framesets", data={"frame": "0"}, files=_frameset(0)).status_code == 201
        wand = tmp_path / "data" / "captures" / stream["id"] / WAND_FILE
        before = wand.read_bytes()
        assert c.post(f"/captures/{stream['id']}/framesets", data={"frame": "1"}, files=_frameset(1)).status_code == 201
        frame_1 = wand.read_bytes()[len(before):]
    # the state the kill leaves: frame 1's rows appended, its transaction never committed
    with connect(settings.db_path) as conn:
        conn.execute("DELETE FROM framesets WHERE capture_id = ? AND frame = 1", (stream["id"],))
        conn.execute("UPDATE captures SET counts = ?, frames = 1, framesets = 1 WHERE id = ?",
                     (json.dumps({"a": {"blobs": 2, "pairs": 1}, "b": {"blobs": 2, "pairs": 1}}), stream["id"]))
    assert wand.read_bytes() == before + frame_1
    with TestClient(create_app(settings), base_url="http://127.0.0.1/api/v1") as c:  # the restart
        assert wand.read_bytes() == before
        assert c.post(f"/captures/{stream['id']}/framesets", data={"frame": "1"}, files=_frameset(1)).status_code == 201
        assert c.get(f"/captures/{stream['id']}").json()["frames"] == 2
    assert wand.read_bytes() == before + frame_1  # once, not twice
    assert np.bincount(read_capture(wand.parent).wand.frame).tolist() == [4, 4]


def test_a_full_disk_answers_507_and_loses_nothing(small_disk, capture_folder, caplog):
    folder, sim = capture_folder
    settings = Settings(data_dir=small_disk / "data", workers=0, framesets_per_second=1e6)
    app = create_app(settings)
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        upload = c.post("/captures", files=capture_files(folder)).json()
        stream = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(_small_rig())).encode())}).json()
        assert c.post(f"/captures/{stream['id']}/framesets", data={"frame": "0"}, files=_frameset(0)).status_code == 201
        job = c.post("/jobs", json={"capture_id": upload["id"]}).json()
        store = app.state.wandcal.queue.store
        claim = store.claim(os.getpid())  # the solve starts before the disk fills
        stream_folder = small_disk / "data" / "captures" / stream["id"]
        before = (stream_folder / WAND_FILE).read_bytes()

        _fill(small_disk / "filler")
        r = c.post("/captures", files=capture_files(folder))
        assert r.status_code == 507 and "disk is full" in r.json()["detail"]
        r = c.post(f"/captures/{stream['id']}/framesets", data={"frame": "1"}, files=_frameset(1))
        assert r.status_code == 507, r.text
        assert c.post("/jobs", json={"capture_id": upload["id"]}).status_code == 507
        # reads go on; nothing half-written is left
        assert [x["id"] for x in c.get("/captures").json()["captures"]] == [stream["id"], upload["id"]]
        assert (stream_folder / WAND_FILE).read_bytes() == before
        assert c.get(f"/captures/{stream['id']}").json()["framesets"] == 1
        assert not list((small_disk / "data" / "captures").glob(".*"))
        # the solve's outcome waits in memory until there is room
        from wandcal.service.jobs.worker import run_claim

        solver = threading.Thread(target=run_claim, args=(store, app.state.wandcal.captures.load, claim))
        solver.start()
        poll(lambda: "cannot record its outcome, the disk is full" in caplog.text, "the solve to end on a full disk")
        assert c.get(f"/jobs/{job['id']}").json()["state"] == "running"
        (small_disk / "filler").unlink()
        solver.join(30)
        done = c.get(f"/jobs/{job['id']}").json()
        assert done["state"] == "done" and done["result"]["format"] == "wandcal-result/1"
        # and everything works again
        assert c.post("/captures", files=capture_files(folder)).status_code == 201
        assert c.post(f"/captures/{stream['id']}/framesets", data={"frame": "1"}, files=_frameset(1)).status_code == 201
    kept = read_capture(small_disk / "data" / "captures" / upload["id"])
    assert kept.wand.frame.tolist() == sim.wand.frame.tolist() and np.allclose(kept.wand.uv, sim.wand.uv, atol=1e-4)


# -- devices ----------------------------------------------------------------------------------
def test_the_trigger_vanishing_during_a_live_capture_keeps_what_was_recorded(tmp_path, patient_stall_limit):
    from wandcal.drivers.trigger_emulator import EmulatorProcess

    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with EmulatorProcess("--vanish-after", "40") as emu, \
            TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        r = c.post("/capture/start", json={"cameras": ["sim://?cameras=2&seed=2&frames=400"], "trigger": emu.url,
                                           "frames": 400, "rate_hz": 200})
        assert r.status_code == 202, r.text
        status = poll(lambda: (s := c.get("/capture").json())["state"] in ("done", "failed") and s, "the capture's end")
        assert status["state"] == "failed" and "vanished" in status["error"]
        capture = c.get(f"/captures/{status['capture_id']}").json()
        assert capture["framesets"] == 0 and 0 < capture["frames"] <= 40  # streamed sets: none; recorded: its 40
        rows = (tmp_path / "data" / "captures" / status["capture_id"] / "sync.csv").read_text().splitlines()[1:]
        assert [int(r.split(",")[1]) for r in rows] == list(range(40))  # every pulse the board sent is a set


def test_a_live_recording_that_cannot_be_registered_keeps_its_sets(tmp_path, monkeypatch, patient_stall_limit):
    """The recording ends but cannot become a capture (here its registration fails as on a disk
    that just filled): its sets and images are moved to recovered/<id>, as a crash's are, and the
    status says where and what to run."""
    import errno

    from wandcal.drivers.trigger_emulator import EmulatorProcess

    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    store = app.state.wandcal.captures

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(store, "adopt", full)
    with EmulatorProcess() as emu, \
            TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as c:
        r = c.post("/capture/start", json={"cameras": ["sim://?cameras=2&seed=3&frames=30"], "trigger": emu.url,
                                           "frames": 30, "rate_hz": 100, "images": "all", "guidance": False})
        assert r.status_code == 202, r.text
        status = poll(lambda: (s := c.get("/capture").json())["state"] in ("done", "failed") and s, "the capture's end")
    kept = tmp_path / "data" / "recovered" / r.json()["capture_id"]
    assert status["state"] == "failed" and "No space left" in status["error"]
    assert str(kept) in status["error"] and "wandcal detect" in status["error"]
    assert status["capture_id"] is None  # nothing registered
    assert len((kept / "sync.csv").read_text().splitlines()) == 1 + 30
    assert len(list(kept.glob("frames/*/*.png"))) == 2 * 30  # every image the cameras sent
    assert read_capture(kept).wand.frame.size > 0  # and the centroids recorded as they came
    assert not list((tmp_path / "data" / "captures").glob(".*.partial"))


def test_a_stalled_camera_does_not_hold_the_capture(tmp_path):
    """cam2 stops delivering after frame 50 (a stalled USB camera): the capture goes on at the
    trigger's pace, keeps every set with cam2's slot empty, and says so."""
    from wandcal.capture.recording.session import record
    from wandcal.drivers.registry import open_cameras
    from wandcal.drivers.trigger import SerialTrigger
    from wandcal.drivers.trigger_emulator import EmulatorProcess

    cams = open_cameras("sim://?cameras=2&seed=6&frames=150&drop=cam2:50-149")
    with EmulatorProcess() as emu:
        result = record(cams, SerialTrigger(emu.url), tmp_path / "cap", cams[0].scene.rig, frames=150, rate_hz=100)
    assert result.error is None and result.frame_sets == 150
    assert result.per_camera["cam2"]["missed"] == 100 and result.per_camera["cam1"]["missed"] == 0
    rows = (tmp_path / "cap" / "sync.csv").read_text().splitlines()[1:]
    assert len(rows) == 150 and all(r.split(",")[4] == "" for r in rows[50:]) and all(r.split(",")[3] for r in rows)
    shutil.rmtree(tmp_path / "cap")
