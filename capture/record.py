"""Write the image level of a ``wandcal-capture/1`` folder (docs/capture-format.md).

Rows of ``sync.csv`` are flushed as their sets are handed to the writer, and ``rig.json`` is
written first, so a capture cut short (trigger unplugged, process killed) keeps a readable
folder with every set recorded until then.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from calib.rig import Rig
from capture.folder import RIG_FILE, rig_to_json
from capture.sync import FrameSet
from capture.writer import ImageWriter
from drivers.imagefolder import FRAMES_DIR, STATIC_DIR, SYNC_FILE, image_path, sync_header

LOG_FILE = "capture.json"
LOG_FORMAT = "wandcal-capture-log/1"


class Recorder:
    """Writes frame sets into ``folder``.

    Args:
        folder: the capture folder (created; must not already hold a capture).
        rig: cameras (ids in slot order) with intrinsics, wand length and static object.
        writer: the bounded image writer.
        triggered: False without a trigger; sync.csv then leaves trigger_count empty.
    """

    def __init__(self, folder: Path, rig: Rig, writer: ImageWriter, triggered: bool = True):
        self.folder = Path(folder)
        if (self.folder / SYNC_FILE).exists() or (self.folder / FRAMES_DIR).exists():
            writer.close()
            raise FileExistsError(f"{self.folder} already holds a capture; choose a new --out folder")
        self.folder.mkdir(parents=True, exist_ok=True)
        self.ids = rig.ids
        self.writer = writer
        self.triggered = triggered
        (self.folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
        self._sync = open(self.folder / SYNC_FILE, "w", newline="")
        self._csv = csv.writer(self._sync)
        self._csv.writerow(sync_header(self.ids))
        self._sync.flush()
        self.static_sets = 0
        self.frame_sets = 0

    def add_static(self, fs: FrameSet) -> None:
        """One set of the static-object recording: images only (its timing is of no use)."""
        for cid, frame in zip(self.ids, fs.frames):
            if frame is not None:
                self.writer.put(image_path(self.folder, STATIC_DIR, cid, self.static_sets), frame.image)
        self.static_sets += 1

    def add_frames(self, fs: FrameSet) -> None:
        """One wand frame set: its images and its sync.csv row (empty cells for missing frames)."""
        n = self.frame_sets
        for cid, frame in zip(self.ids, fs.frames):
            if frame is not None:
                self.writer.put(image_path(self.folder, FRAMES_DIR, cid, n), frame.image)
        cells = [n, fs.counter if self.triggered else "", "" if fs.trigger_us is None else fs.trigger_us]
        cells += ["" if f is None else f.timestamp_us for f in fs.frames]
        self._csv.writerow(cells)
        self._sync.flush()
        self.frame_sets += 1

    def close(self, log: dict) -> None:
        """Finish writing images, close sync.csv and write the capture log."""
        try:
            self.writer.close()
        finally:
            self._sync.close()
            (self.folder / LOG_FILE).write_text(json.dumps({"format": LOG_FORMAT, **log}, indent=2) + "\n")
