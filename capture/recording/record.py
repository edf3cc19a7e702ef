"""Write a ``wandcal-capture/1`` folder as frame sets arrive (docs/capture-format.md).

Centroids always (capture/recording/centroids.py: ``blobs.csv``, ``wand.csv``, ``static.csv``); images as an
:class:`ImagePolicy` says. Rows of ``sync.csv`` are flushed as their sets are handed to the
writer, and ``rig.json`` is written first, so a capture cut short (trigger unplugged, process
killed) keeps a readable folder with every set recorded until then.
"""

from __future__ import annotations

import csv
import json
import shutil
from dataclasses import dataclass
from pathlib import Path

from wandcal.calib.rig import Rig
from wandcal.capture.folder import rig_to_json
from wandcal.capture.recording.centroids import CentroidRecorder
from wandcal.capture.recording.framesets import DetectedFrame, FrameSet
from wandcal.capture.recording.writer import ImageWriter
from wandcal.drivers.camera import Frame
from wandcal.drivers.capture_files import (
    BLOBS_FILE,
    FRAMES_DIR,
    LOG_FILE,
    RIG_FILE,
    STATIC_DIR,
    STATIC_FILE,
    SYNC_FILE,
    WAND_FILE,
)
from wandcal.drivers.imagefolder import image_path, sync_header

LOG_FORMAT = "wandcal-capture-log/1"
HELD = (SYNC_FILE, FRAMES_DIR, WAND_FILE)  # any of these: the folder holds a capture, which a recording does not mix into
# what a recording writes, removed before recording again into its folder (masks/ and background/
# are the operator's detection inputs, and results are files of their own: they stay)
RECORDING = (RIG_FILE, WAND_FILE, STATIC_FILE, BLOBS_FILE, SYNC_FILE, LOG_FILE, "truth.json", FRAMES_DIR, STATIC_DIR)


@dataclass(frozen=True)
class HeldCapture:
    """What a folder already holds, before a recording into it.

    wand_sets: wand sets recorded (rows of ``sync.csv``; None when it has none, e.g. an import);
    partial: ``capture.json`` says the recording stopped early (Ctrl-C, a fault).
    """

    wand_sets: int | None
    partial: bool

    @property
    def replaceable(self) -> bool:
        """An interrupted recording with no wand sets: nothing in it can be calibrated, so the
        same ``--out`` records again into it without being asked."""
        return self.partial and self.wand_sets == 0

    def describe(self) -> str:
        state = "partial" if self.partial else "complete"
        return f"a {state} capture" + ("" if self.wand_sets is None else f" of {self.wand_sets} wand sets")


def held_capture(folder: Path) -> HeldCapture | None:
    """What ``folder`` holds (None: no capture, a recording may go there)."""
    folder = Path(folder)
    if not any((folder / name).exists() for name in HELD):
        return None
    wand_sets = None
    if (folder / SYNC_FILE).is_file():
        with open(folder / SYNC_FILE, newline="") as fh:
            wand_sets = max(sum(1 for row in csv.reader(fh) if row) - 1, 0)  # less the header
    try:
        log = json.loads((folder / LOG_FILE).read_text())
        partial = log.get("state") == "partial" or bool(log.get("error"))
    except (OSError, ValueError, AttributeError):
        partial = (folder / SYNC_FILE).is_file() and not (folder / LOG_FILE).exists()  # killed: no log written
    return HeldCapture(wand_sets, partial)


def clear_recording(folder: Path) -> None:
    """Remove the files a recording writes from ``folder`` (:data:`RECORDING`), to record again."""
    for name in RECORDING:
        path = Path(folder) / name
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()


@dataclass(frozen=True)
class ImagePolicy:
    """Which images a capture writes beside its centroids.

    Args:
        every: write the images of every ``every``-th wand set (1: all, 0: none).
        static: write the static recording's images.
    """

    every: int = 1
    static: bool = True

    @classmethod
    def parse(cls, text: str) -> ImagePolicy:
        """``all``, ``none``, ``static`` (the static recording only) or a whole number N (every
        N-th wand set, and the static recording)."""
        word = str(text).strip().lower()
        named = {"all": cls(1, True), "none": cls(0, False), "static": cls(0, True)}
        if word in named:
            return named[word]
        if word.isdigit() and int(word) >= 1:
            return cls(int(word), True)
        raise ValueError(f"images {text!r}: give all, none, static, or a whole number N >= 1 (every N-th wand set)")

    def __str__(self) -> str:
        if self.every == 1 and self.static:
            return "all"
        if self.every == 0:
            return "static" if self.static else "none"
        return f"every {self.every}" + ("" if self.static else ", no static")

    def keeps(self, sequence: int, static_frames: int) -> bool:
        """Whether a reader thread keeps the image of frame ``sequence`` for the recorder (which
        then writes it or not by its set index); the others are dropped at once."""
        return self.static if sequence < static_frames else self.every > 0

    def writes(self, wand_set: int) -> bool:
        return self.every > 0 and wand_set % self.every == 0


class Recorder:
    """Writes frame sets into ``folder``.

    Args:
        folder: the capture folder (created; must not already hold a capture).
        rig: cameras (ids in slot order) with intrinsics, wand length and static object.
        writer: the bounded image writer.
        triggered: False without a trigger; sync.csv then leaves trigger_count empty.
        images: which images to write (centroids are always written); None: all.
        listener: told of every live wand pair and of the static markers (the live guidance;
            see :class:`wandcal.capture.recording.centroids.CentroidRecorder`).

    Frames must carry their blobs (``uv`` (K, 2)) and, where an image is to be written, ``image``
    (:class:`wandcal.capture.recording.framesets.DetectedFrame`).
    """

    def __init__(self, folder: Path, rig: Rig, writer: ImageWriter, triggered: bool = True,
                 images: ImagePolicy | None = None, listener=None):
        self.folder = Path(folder)
        if any((self.folder / name).exists() for name in HELD):
            writer.close()
            raise FileExistsError(f"{self.folder} already holds a capture; choose a new --out folder")
        self.folder.mkdir(parents=True, exist_ok=True)
        self.ids = rig.ids
        self.writer = writer
        self.triggered = triggered
        self.images = images or ImagePolicy()
        (self.folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
        self.points = CentroidRecorder(self.folder, rig, listener)
        self._sync = open(self.folder / SYNC_FILE, "w", newline="")  # noqa: SIM115 - open for the recording's life; close() closes it
        self._csv = csv.writer(self._sync)
        self._csv.writerow(sync_header(self.ids))
        self._sync.flush()
        self.static_sets = 0
        self.frame_sets = 0

    def add_static(self, fs: FrameSet) -> None:
        """One set of the static-object recording: blobs and images (its timing is of no use)."""
        for c, (cid, frame) in enumerate(zip(self.ids, fs.frames)):
            if frame is not None:
                self.points.add_static(c, _detected(frame).uv)
                if self.images.static and frame.image is not None:
                    self.writer.put(image_path(self.folder, STATIC_DIR, cid, self.static_sets), frame.image)
        self.static_sets += 1

    def add_frames(self, fs: FrameSet) -> None:
        """One wand frame set: its blobs, its images and its sync.csv row (empty cells for
        missing frames)."""
        n = self.frame_sets
        write = self.images.writes(n)
        for c, (cid, frame) in enumerate(zip(self.ids, fs.frames)):
            if frame is not None:
                self.points.add_wand(n, c, _detected(frame).uv)
                if write and frame.image is not None:
                    self.writer.put(image_path(self.folder, FRAMES_DIR, cid, n), frame.image)
        self.points.flush()
        cells = [n, fs.counter if self.triggered else "", "" if fs.trigger_us is None else fs.trigger_us]
        cells += ["" if f is None else f.timestamp_us for f in fs.frames]
        self._csv.writerow(cells)
        self._sync.flush()
        self.frame_sets += 1

    def close(self, log: dict) -> None:
        """Finish writing images, close sync.csv, finish the points level and write the capture
        log (with the detection counts per camera under ``detection``)."""
        try:
            self.writer.close()
        finally:
            self._sync.close()
            try:
                log = log | {"images": str(self.images), "detection": self.points.close()}
            finally:
                (self.folder / LOG_FILE).write_text(json.dumps({"format": LOG_FORMAT, **log}, indent=2) + "\n")


def _detected(frame: Frame | DetectedFrame) -> DetectedFrame:
    """A recorded frame set's frame: detected in the capture loop, so it carries its blobs."""
    if not isinstance(frame, DetectedFrame):
        raise TypeError(f"camera {frame.camera_id}: the recorder takes frames after detection (DetectedFrame), not "
                        "the driver's raw Frame")
    return frame
