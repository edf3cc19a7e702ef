"""Load over loopback, bounded in count: concurrent uploads and jobs, and frame sets of 8 cameras
at 1280x1024 streamed with several requests in flight. Nothing acknowledged may be lost. The
throughput and latency figures are bench/bench_load.py's (docs/benchmarks.md, "Load"); here they
are only printed, never asserted."""

from __future__ import annotations

import json

import numpy as np

from bench import load
from tests.service.conftest import capture_files, simulated_capture
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import rig_to_json
from wandcal.drivers.capture_files import RIG_FILE

UPLOADS, UPLOAD_CONCURRENCY = 16, 8
JOBS, JOB_CONCURRENCY = 6, 3
FRAMESETS, FRAMESET_CONCURRENCY, POOL = 12, 4, 4
BLOB_SETS, BLOB_BATCH, BLOB_CONCURRENCY = 2000, 10, 4
JOB_TIMEOUT_S = 120.0


def test_concurrent_uploads_and_jobs_lose_nothing(server, tmp_path):
    folder, _ = simulated_capture(tmp_path / "capture", cameras=4, frames=300, noise_px=0.3, seed=11)
    srv = server(workers=1)
    with srv.client() as c:
        c.timeout = load.REQUEST_TIMEOUT_S
        uploads, made = load.concurrent_uploads(c, capture_files(folder), UPLOADS, UPLOAD_CONCURRENCY)
        assert uploads.statuses == {201: UPLOADS} and uploads.lost == 0
        assert len({m["id"] for m in made}) == UPLOADS
        jobs, done = load.concurrent_jobs(c, [m["id"] for m in made], JOBS, JOB_CONCURRENCY, JOB_TIMEOUT_S)
        assert jobs.lost == 0, [j["error"] for j in done if j["state"] != "done"]
        assert all(j["attempts"] == 1 for j in done)
    print(f"\n{uploads.row('uploads')}\n{jobs.row('jobs')}\nserver peak RSS {load.peak_rss_mb(srv.proc.pid):.0f} MB")


def test_streamed_frame_sets_lose_nothing(server):
    sim = simulate_capture(cameras=8, frames=POOL, noise_px=0.3, seed=1)
    pool = load.frameset_pool(sim, POOL)
    srv = server(workers=0, framesets_per_second=1000)
    with srv.client() as c:
        c.timeout = load.REQUEST_TIMEOUT_S
        capture = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())}).json()
        run = load.stream_framesets(c, capture["id"], pool, FRAMESETS, FRAMESET_CONCURRENCY)
        assert run.statuses == {201: FRAMESETS} and run.lost == 0
        stored = c.get(f"/captures/{capture['id']}").json()
    # each camera's pairs are those of the pool's sets it saw both ends in, cycled
    expected = {cid: sum(len(pool[f % POOL][1][cid]) == 2 for f in range(FRAMESETS)) for cid in sim.rig.ids}
    assert {cov["id"]: cov["pairs"] for cov in stored["coverage"]} == expected
    print(f"\n{run.row('frame sets')}\nserver peak RSS {load.peak_rss_mb(srv.proc.pid):.0f} MB")


def test_streamed_blob_sets_lose_nothing(server):
    """2,000 frame sets of 8 cameras as centroids, 10 a request, 4 requests in flight."""
    sim = simulate_capture(cameras=8, frames=200, noise_px=0.3, seed=1)
    batches = load.blob_set_batches(sim, BLOB_SETS, BLOB_BATCH)
    srv = server(workers=0)
    with srv.client() as c:
        c.timeout = load.REQUEST_TIMEOUT_S
        capture = c.post("/captures", files={RIG_FILE: (RIG_FILE, json.dumps(rig_to_json(sim.rig)).encode())}).json()
        run = load.stream_blobsets(c, capture["id"], batches, BLOB_CONCURRENCY)
        assert run.statuses == {201: len(batches)} and run.lost == 0
        stored = c.get(f"/captures/{capture['id']}").json()
    # each camera's pairs: the simulated frames it saw both ends in, cycled
    _, per = np.unique(sim.wand.frame * 8 + sim.wand.camera, return_counts=True)
    assert stored["framesets"] == BLOB_SETS
    assert sum(cov["pairs"] for cov in stored["coverage"]) == BLOB_SETS // 200 * int((per == 2).sum())
    print(f"\n{run.row('frame sets')}")


def test_concurrent_frame_sets_keep_every_count(tmp_path):
    """Frame sets appended from many threads at once (detection done beforehand, so they meet at
    the database): every wand row and every count is kept. Before the counts were read inside the
    transaction, two sets at once lost one's counts (found by bench/bench_load.py)."""
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    from wandcal.capture.folder import read_capture
    from wandcal.service.db import init_db
    from wandcal.service.storage import CaptureStore

    sim = simulate_capture(cameras=3, frames=2, seed=1)
    init_db(tmp_path / "db.sqlite3")
    store = CaptureStore(tmp_path / "data", tmp_path / "db.sqlite3", None)
    store.root.mkdir(parents=True)
    capture = store.create_from_texts(json.dumps(rig_to_json(sim.rig)), None, None)
    pair = np.array([[100.0, 200.0], [300.0, 400.0]])
    sets = 200

    def append(f: int) -> None:
        store.append_frameset(capture.id, f, f, {"cam1": pair, "cam2": pair[:1], "cam3": pair if f % 2 else pair[:0]})

    with ThreadPoolExecutor(8) as pool:
        list(pool.map(append, range(sets)))
    row = store.get(capture.id)
    assert row.framesets == sets and row.frames == sets
    assert row.counts == {"cam1": {"blobs": 2 * sets, "pairs": sets}, "cam2": {"blobs": 0, "pairs": 0},
                          "cam3": {"blobs": sets, "pairs": sets // 2}}
    stored = read_capture(store.folder(capture.id)).wand
    assert len(stored) == 3 * sets and sorted(set(stored.frame.tolist())) == list(range(sets))
