"""The live watch (service/live_watch.py) on a recording's ``blobs.csv``: the report is published after
each batch, so a watch that trails the recording shows every batch as it is done, and it ends on the
report ``wandcal watch`` gives on the same blobs."""

from __future__ import annotations

import numpy as np

from wandcal.calib.sim.takes import CameraMove, simulate_take
from wandcal.calib.watch.stream import BATCH_FRAMES, watch_take
from wandcal.calib.watch.take import TakeBlobs
from wandcal.capture.watch_report import report_json
from wandcal.service.live_watch import LiveWatch

FRAMES = 400  # the test's 200-frame baseline, then two batches past it
KNOCK = CameraMove(2, 250, 0.5, 0.0, seed=3)  # a turn far past what the test needs: named in the second batch


def test_a_trailing_watch_publishes_each_batch_and_ends_on_the_clis_report(tmp_path):
    sim = simulate_take(6, FRAMES, markers=20, noise_px=0.3, moves=(KNOCK,), seed=3)
    ids = sim.rig.ids
    path = tmp_path / "blobs.csv"
    # the whole recording is on disk before the watch starts: the watch trails it by every batch
    path.write_text("frame,camera,u,v\n" + "".join(
        f"{f},{ids[c]},{u:.4f},{v:.4f}\n" for f, c, (u, v) in zip(sim.blobs.frame, sim.blobs.camera, sim.blobs.uv)))
    watch = LiveWatch("c1", path, sim.rig, sim.truth.R, sim.truth.t, standing="truth", busy=lambda: False,
                      folder=tmp_path)
    shown = []
    publish = watch._set

    def spy(**fields):
        publish(**fields)
        if "report" in fields:
            shown.append(fields["report"])

    watch._set = spy
    watch._run()

    status = watch.status()
    assert status["state"] == "done" and status["error"] is None, status
    assert status["recorded_frame"] == int(sim.blobs.frame.max()) and status["batch_frames"] == BATCH_FRAMES
    last_frames = [doc["last_frame"] for doc in shown]
    # one report a batch (the baseline's two, then the rest), each further on, then the take's end once more
    assert last_frames[:-1] == [BATCH_FRAMES * (k + 1) - 1 for k in range(FRAMES // BATCH_FRAMES)], last_frames
    assert last_frames[-1] == FRAMES - 1
    knocked = ids[KNOCK.camera]
    before = [doc for doc in shown if doc["last_frame"] < KNOCK.frame]
    assert before and all(knocked not in doc["moved"] for doc in before)
    # the last report is the CLI's on the same blobs as written (without the re-solve)
    written = TakeBlobs(sim.blobs.frame, sim.blobs.camera, np.round(sim.blobs.uv, 4))
    cli = report_json(watch_take(sim.rig, sim.truth.R, sim.truth.t, written, resolve=False))
    final = shown[-1]
    for mine in final["cameras"]:
        mine.pop("peak")
    assert final == cli
    assert final["moved"] == [knocked]
    assert np.isclose(next(c for c in final["cameras"] if c["id"] == knocked)["moved_at_frame"], KNOCK.frame, atol=10)
