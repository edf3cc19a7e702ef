"""No request changes process-wide state (issue 20, class 2): the report, export, upload, blob-set
and guidance routes run at once from many threads, and afterwards every global is as it was:
warnings filters, numpy's error state, BLAS threads, the working directory, the environment and
the locale. (Before: a reader set the warnings filter to "error" inside worker threads and left
it there, and every later report answered 500.)"""

from __future__ import annotations

import json
import locale
import os
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from fastapi.testclient import TestClient
from threadpoolctl import threadpool_info

from tests.service.conftest import capture_files
from wandcal.capture.folder import rig_to_json
from wandcal.drivers.capture_files import RIG_FILE, WAND_FILE
from wandcal.service.main import create_app
from wandcal.service.settings import Settings

FORMATS = ("json", "anipose-toml", "opencv-yaml", "dlt-csv", "qca", "xcp")
ROUNDS = 4  # each route this many times per thread pool run: enough for the threads to interleave
THREADS = 8


def snapshot() -> dict:
    return {
        "warnings": list(warnings.filters),
        "errstate": np.geterr(),
        "blas": sorted((i["internal_api"], i["num_threads"]) for i in threadpool_info()),
        "cwd": os.getcwd(),
        "environ": dict(os.environ),
        "locale": locale.setlocale(locale.LC_ALL, None),
    }


@pytest.fixture
def served(tmp_path, small_capture):
    (tmp_path / "replay").mkdir()
    app = create_app(Settings(data_dir=tmp_path / "data", replay_root=tmp_path / "replay", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1", raise_server_exceptions=False) as client:
        folder, sim = small_capture
        capture = client.post("/captures", files=capture_files(folder)).json()
        job = client.post("/jobs", json={"capture_id": capture["id"]}).json()
        app.state.wandcal.queue.drain()
        assert client.get(f"/jobs/{job['id']}").json()["state"] == "done"
        yield client, folder, sim, capture["id"], job["id"]


def test_routes_run_concurrently_leave_every_global_as_it_was(served):
    pytest.importorskip("matplotlib")
    client, folder, sim, capture_id, job_id = served
    rig = json.dumps(rig_to_json(sim.rig)).encode()
    empty = {RIG_FILE: (RIG_FILE, rig), WAND_FILE: (WAND_FILE, b"frame,camera,u,v\n")}  # the reader's empty table
    stream_id = client.post("/captures", files={RIG_FILE: (RIG_FILE, rig)}).json()["id"]
    before = snapshot()

    def blobsets(k: int):
        sets = [{"frame": 1000 * k + i, "blobs": {cid: [[100.0 + i, 200.0], [150.0, 260.0 + i]] for cid in sim.rig.ids}}
                for i in range(5)]
        return client.post(f"/captures/{stream_id}/blobsets", json={"sets": sets})

    calls = [
        *(lambda f=f: client.get(f"/jobs/{job_id}/result", params={"format": f}) for f in FORMATS),
        lambda: client.get(f"/jobs/{job_id}/report", follow_redirects=True),
        lambda: client.post("/captures", files=capture_files(folder)),
        lambda: client.post("/captures", files=empty),
        lambda: client.get(f"/captures/{capture_id}/guidance"),
        lambda: client.get(f"/captures/{stream_id}/guidance"),
    ]
    work = [call for _ in range(ROUNDS) for call in calls] + [lambda k=k: blobsets(k) for k in range(ROUNDS * 2)]
    with ThreadPoolExecutor(THREADS) as pool:
        answers = list(pool.map(lambda call: call(), work))
    assert all(a.status_code < 500 for a in answers), [a.text for a in answers if a.status_code >= 500]
    assert snapshot() == before
    # and the routes still answer as before once the burst is over
    assert client.get(f"/jobs/{job_id}/report/").status_code == 200
    assert client.get(f"/jobs/{job_id}/result", params={"format": "dlt-csv"}).status_code == 200


def test_readers_in_many_threads_leave_the_warnings_filter_alone(small_capture):
    """The reader whose empty-table check once turned warnings into errors, from many threads
    switching as often as the interpreter allows (that interleaving left the filter at "error")."""
    import sys

    from wandcal.capture.folder import CaptureFormatError, parse_wand_csv

    _, sim = small_capture
    before, interval = list(warnings.filters), sys.getswitchinterval()

    def read(k: int):
        text = "frame,camera,u,v\n" + ("" if k % 2 else f"{k},{sim.rig.ids[0]},1.5,2.5\n")
        try:
            return len(parse_wand_csv(text, sim.rig))
        except CaptureFormatError:
            return -1

    sys.setswitchinterval(1e-6)
    try:
        with ThreadPoolExecutor(THREADS) as pool:
            counts = list(pool.map(read, range(2000)))
    finally:
        sys.setswitchinterval(interval)
    assert counts == [0 if k % 2 else 1 for k in range(2000)]
    assert warnings.filters == before


# Calls that change what every thread of the process sees. The product code may make them only at
# a process's start (the server's, a worker's), never on a request's path; each allowed place is
# listed with its reason.
GLOBAL_CALLS = ("warnings.simplefilter", "warnings.filterwarnings", "warnings.catch_warnings", "os.chdir",
                "os.environ[", "os.putenv", "locale.setlocale", "np.seterr(", "numpy.seterr(", "setNumThreads",
                "threadpool_limits(", "mallopt(", "_set_madvise_hugepage(")
ALLOWED = {
    # at the app's start, restored at its stop: one BLAS thread while the server serves (see its comment)
    ("service/main.py", "threadpool_limits("),
    # around a `wandcal calibrate` command, which serves no requests, restored after it (see its comment)
    ("service/cli/calibrate.py", "threadpool_limits("),
    # the solvers pin BLAS to one thread for their own run; in the server that is a no-op, as the
    # server set one thread at its start, so concurrent solves cannot leave the count changed
    ("calib/solve/ba/adjust.py", "threadpool_limits("),
    ("calib/solve/lp/refine.py", "threadpool_limits("),
    ("calib/solve/paper.py", "threadpool_limits("),
    # the memory policy of a command that computes once and exits, taken by the CLI's own process
    # only (service/cli/__init__.py: never by the server, a worker or an in-process caller)
    ("service/cli/support/batch_memory.py", "mallopt("),
    ("service/cli/support/batch_memory.py", "_set_madvise_hugepage("),
}


def test_no_product_code_changes_process_wide_state_on_a_request_path():
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    found = []
    for package in ("calib", "capture", "drivers", "service"):
        for path in sorted((repo / package).rglob("*.py")):
            text = path.read_text()
            rel = path.relative_to(repo).as_posix()
            found += [(rel, call) for call in GLOBAL_CALLS if call in text and (rel, call) not in ALLOWED]
    assert not found, f"process-wide state changed in product code: {found}"


def test_an_app_holds_blas_to_one_thread_while_it_serves_and_gives_it_back(tmp_path):
    """The server's one BLAS thread is the app's while it runs, not the process's for ever: a
    calibration in the same process after an app stopped (a test) uses BLAS as it found it."""
    def blas() -> list:
        return sorted((i["internal_api"], i["num_threads"]) for i in threadpool_info() if i["user_api"] == "blas")

    before = blas()
    app = create_app(Settings(data_dir=tmp_path / "data", workers=0))
    with TestClient(app, base_url="http://127.0.0.1/api/v1") as client:
        assert client.get("/health").status_code == 200
        assert all(threads == 1 for _, threads in blas())
    assert blas() == before
