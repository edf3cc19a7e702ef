"""The live capture's take watched as it records (issue 36): each camera's health for the page,
updated every :data:`UPDATE_S`.

A thread reads the recording's ``blobs.csv`` (every blob of every set, flushed with each set:
capture/recording/centroids.py) as it grows and feeds whole batches of
:data:`~wandcal.calib.watch.stream.BATCH_FRAMES` sets to a :class:`~wandcal.calib.watch.stream.WatchStream`,
the same batches ``wandcal watch`` cuts: once the capture ends, the live report is the one
``wandcal watch RESULT`` gives on the recording. The re-solve of a moved camera is a watch job
(:mod:`wandcal.service.jobs.watch_job`) on the stored recording, started from the page.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.calib.watch.stream import BATCH_FRAMES, WatchStream
from wandcal.calib.watch.take import TakeBlobs
from wandcal.capture.watch_report import report_json

UPDATE_S = 0.5  # the page polls once a second: a batch of 100 sets at 100 fps lands within it
WAIT_FOR_FILE_S = 10.0  # the recording writes blobs.csv when its first set arrives


@dataclass
class _Rows:
    """Blob rows read so far and not yet fed to the watch."""

    frame: list[int] = field(default_factory=list)
    camera: list[int] = field(default_factory=list)
    uv: list[tuple[float, float]] = field(default_factory=list)

    def take(self, stop: int) -> tuple[TakeBlobs, np.ndarray]:
        """The rows of frames before ``stop`` as a take (sorted by frame), removed from here."""
        frame = np.array(self.frame, dtype=np.int64)
        keep = frame < stop
        order = np.argsort(frame[keep], kind="stable")
        blobs = TakeBlobs(frame[keep][order], np.array(self.camera, dtype=np.int64)[keep][order],
                          np.array(self.uv, dtype=float).reshape(-1, 2)[keep][order])
        rest = np.flatnonzero(~keep)
        self.frame = [self.frame[i] for i in rest]
        self.camera = [self.camera[i] for i in rest]
        self.uv = [self.uv[i] for i in rest]
        return blobs, np.arange(len(blobs))


class LiveWatch:
    """One live capture watched with a standing result (poses R (C, 3, 3), t (C, 3) in the order of
    ``rig``, the capture's). ``busy()``: whether the capture still records; :meth:`status` the page's document."""

    def __init__(self, capture_id: str, blobs_path: Path, rig: Rig, R: np.ndarray, t: np.ndarray, *,
                 standing: str, busy, folder: Path):
        self.capture_id, self.blobs_path, self.rig, self.R, self.t = capture_id, blobs_path, rig, R, t
        self.standing, self.busy, self.folder = standing, busy, folder  # folder: the standing result's copy
        self.ids = {cid: c for c, cid in enumerate(rig.ids)}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._doc: dict = {"state": "watching", "capture_id": capture_id, "standing": standing, "report": None,
                           "updated": time.time(), "error": None,
                           "batch_frames": BATCH_FRAMES}
        self._next = 0  # the first frame of the next batch
        self._begun = False  # the stream has its baseline
        self._baseline = TakeBlobs(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2)))  # not yet fed
        self._thread = threading.Thread(target=self._run, name=f"live-watch-{capture_id[:8]}", daemon=True)

    def start(self) -> LiveWatch:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def status(self) -> dict:
        with self._lock:
            return dict(self._doc)

    def _set(self, **fields) -> None:
        with self._lock:
            self._doc = self._doc | fields | {"updated": time.time()}

    def _run(self) -> None:
        try:
            self._watch()
        except Exception as exc:  # the thread's end: its status says why
            self._set(state="failed", error=f"{type(exc).__name__}: {exc}")

    def _watch(self) -> None:
        deadline = time.monotonic() + WAIT_FOR_FILE_S
        while not self.blobs_path.is_file():
            if self._stop.wait(0.05) or time.monotonic() > deadline:
                raise FileNotFoundError(f"the recording wrote no blobs within {WAIT_FOR_FILE_S:g} s")
        rows, stream, last = _Rows(), None, -1
        with open(self.blobs_path) as fh:
            partial = ""
            while True:
                ended = not self.busy()  # read before the file: every set of an ended capture is in it
                text = partial + fh.read()
                lines = text.split("\n")
                partial = lines.pop()
                self._parse(lines, rows)
                if rows.frame:
                    last = max(last, *rows.frame)
                    self._set(recorded_frame=last)  # how far the recording is: the page shows how far behind the watch is
                stream = self._feed(rows, stream, last, ended)
                if ended or self._stop.is_set():
                    break
                self._stop.wait(UPDATE_S)
        self._set(state="done" if not self._stop.is_set() else "stopped")

    def _parse(self, lines: list[str], rows: _Rows) -> None:
        for line in lines:
            if not line or line.startswith("frame,"):  # the header (the file may be read before it is written)
                continue
            frame, cid, u, v = line.split(",")
            rows.frame.append(int(frame))
            rows.camera.append(self.ids[cid])
            rows.uv.append((float(u), float(v)))

    def _feed(self, rows: _Rows, stream: WatchStream | None, last: int, ended: bool) -> WatchStream | None:
        """Feed every whole batch (all of them once the capture ended), the report published after each: a
        watch that trails the recording (a busy machine) still shows each batch as it is done."""
        if stream is None:
            if not rows.frame:
                return None
            stream = WatchStream(self.rig, self.R, self.t, min(rows.frame), keep_obs=False)
            self._next = stream.first
        if not self._begun:
            if last < stream.baseline_stop and not ended:
                return stream  # the test's baseline needs its first windows
            blobs, idx = rows.take(stream.baseline_stop)
            # begin() reads the baseline's blobs; they are fed again as batches below
            stream.begin(blobs, idx)
            self._baseline = blobs
            self._begun = True
        while self._next + BATCH_FRAMES <= last or (ended and self._next <= last):
            stop = self._next + BATCH_FRAMES
            blobs, idx = self._batch(rows, stop)
            self._next = stop
            if len(blobs):
                stream.add(blobs, idx)
                self._publish(stream, min(last, stop - 1))
        if ended:
            stream.close()  # the attribution's last look at a "one of" move, as ``wandcal watch`` takes it
            self._publish(stream, min(last, self._next - 1))
        return stream

    def _publish(self, stream: WatchStream, last: int) -> None:
        report = stream.report(last)
        doc = report_json(report)
        for entry, health in zip(doc["cameras"], report.cameras):
            entry["peak"] = round(health.peak, 1)  # the test's largest statistic so far, for the page's bar
        self._set(report=doc, frames=stream.frames)

    def _batch(self, rows: _Rows, stop: int) -> tuple[TakeBlobs, np.ndarray]:
        """The blobs of frames before ``stop``: the baseline's first, then the rows read."""
        base = self._baseline
        keep = base.frame < stop
        head = TakeBlobs(base.frame[keep], base.camera[keep], base.uv[keep])
        self._baseline = TakeBlobs(base.frame[~keep], base.camera[~keep], base.uv[~keep])
        tail, _ = rows.take(stop)
        blobs = TakeBlobs(np.concatenate([head.frame, tail.frame]), np.concatenate([head.camera, tail.camera]),
                          np.concatenate([head.uv, tail.uv]))
        return blobs, np.arange(len(blobs))
