"""The points level of a capture, written as its frame sets arrive (centroid recording).

Every frame is detected in the capture loop (capture/recording/session.py), so a capture writes what
commercial mocap cameras send, centroids, whether or not it keeps images:

- ``blobs.csv``: every blob of every wand frame, ``frame,camera,u,v`` (flushed with each set);
- ``static.csv``: the static recording's markers, averaged, written when the wand run begins;
- ``wand.csv``: as it goes, the camera-frames that show exactly two blobs once still markers are
  taken out: the static recording's markers, and blobs that stayed put through half of the last
  :data:`STILL_WINDOW_SETS` sets (an L-frame left on the floor, a lamp). When the capture ends it
  is rewritten from ``blobs.csv`` by the rule of ``wandcal detect`` over the whole recording
  (:func:`wandcal.calib.detect.wand_frames`), so both give the same points level.

A capture killed midway keeps a valid ``wand.csv`` up to its last flushed set.
"""

from __future__ import annotations

import os
from array import array
from collections import deque
from pathlib import Path

import numpy as np

from wandcal.calib.detect import WAND_MARKERS, WAND_STILL_PRESENCE, static_markers_from_frames, wand_frames
from wandcal.calib.rig import Rig, StaticObservations
from wandcal.capture.folder import STATIC_COLUMNS, WAND_COLUMNS, parse_wand_csv
from wandcal.drivers.capture_files import BLOBS_FILE, STATIC_FILE, WAND_FILE

# Sets in the window that finds still markers during the wand run: 2 s at 100 fps, long enough
# that the moving wand never holds half of them at one spot, short enough that a lamp switched
# on mid-capture stops spoiling the live pairs within seconds.
STILL_WINDOW_SETS = 200


def _csv_line(cells) -> str:
    return ",".join(map(str, cells)) + "\n"


def _uv_lines(prefix: str, uv: np.ndarray) -> list[str]:
    return [f"{prefix}{u:.4f},{v:.4f}\n" for u, v in uv]


class CentroidRecorder:
    """Writes ``blobs.csv``, ``wand.csv`` and ``static.csv`` into ``folder`` as sets arrive.

    Args:
        folder: the capture folder (exists).
        rig: the cameras, in slot order, and the static object.
        listener: optional object with ``add_pair(frame, camera, uv (2, 2))`` and
            ``set_static(StaticObservations)``, told of every live wand pair (the live guidance).
    """

    def __init__(self, folder: Path, rig: Rig, listener=None):
        self.folder = Path(folder)
        self.rig = rig
        self.ids = rig.ids
        self.listener = listener
        # open for the recorder's life (rows are appended as sets arrive); close() closes them
        self._blobs = open(self.folder / BLOBS_FILE, "w")  # noqa: SIM115
        self._wand = open(self.folder / WAND_FILE, "w")  # noqa: SIM115
        self._blobs.write(_csv_line(WAND_COLUMNS))
        self._wand.write(_csv_line(WAND_COLUMNS))
        n = len(self.ids)
        self._static_uv: list[list[np.ndarray]] = [[] for _ in range(n)]
        self._static_markers: list[np.ndarray] = [np.zeros((0, 2))] * n
        self._still: list[np.ndarray] = [np.zeros((0, 2))] * n
        self._recent: list[deque] = [deque(maxlen=STILL_WINDOW_SETS) for _ in range(n)]
        self._delivered = [array("q") for _ in range(n)]  # the wand sets each camera delivered a frame to
        self._static_ended = False
        self.live_pairs = np.zeros(n, dtype=np.int64)

    def add_static(self, camera: int, uv: np.ndarray) -> None:
        """The blobs (K, 2) of one static-recording frame of camera ``camera``."""
        self._static_uv[camera].append(uv)

    def end_static(self) -> StaticObservations | None:
        """Average the static recording into markers (once); write static.csv when the rig has a
        static object. Returns its observations, or None."""
        if self._static_ended:
            return None
        self._static_ended = True
        if not any(self._static_uv):
            return None
        self._static_markers = [static_markers_from_frames(frames) for frames in self._static_uv]
        self._still = list(self._static_markers)
        self._static_uv = [[] for _ in self.ids]
        if self.rig.static_markers is None:
            return None
        camera = np.concatenate([np.full(len(m), c) for c, m in enumerate(self._static_markers)])
        static = StaticObservations(camera=camera, uv=np.concatenate(self._static_markers).reshape(-1, 2))
        with open(self.folder / STATIC_FILE, "w") as fh:
            fh.write(_csv_line(STATIC_COLUMNS))
            fh.writelines(f"{self.ids[c]},{u:.4f},{v:.4f}\n" for c, (u, v) in zip(static.camera, static.uv))
        if self.listener is not None:
            self.listener.set_static(static)
        return static

    def add_wand(self, frame: int, camera: int, uv: np.ndarray) -> None:
        """The blobs (K, 2) camera ``camera`` saw in wand set ``frame``."""
        self.end_static()
        self._delivered[camera].append(frame)
        cid = self.ids[camera]
        self._blobs.writelines(_uv_lines(f"{frame},{cid},", uv))
        recent = self._recent[camera]
        recent.append(uv)
        if len(recent) == STILL_WINDOW_SETS and frame % STILL_WINDOW_SETS == 0:
            found = static_markers_from_frames(list(recent), min_presence=WAND_STILL_PRESENCE)
            self._still[camera] = np.concatenate([self._static_markers[camera], found])
        still = self._still[camera]
        if len(still):
            kept = wand_frames([uv], static_uv=still)
            pair = kept.uv[0] if len(kept) else None
        else:  # the rule without still markers, at a tenth of its cost (this runs 800 times a second)
            pair = uv if len(uv) == WAND_MARKERS else None
        if pair is not None:
            self._wand.writelines(_uv_lines(f"{frame},{cid},", pair))
            self.live_pairs[camera] += 1
            if self.listener is not None:
                self.listener.add_pair(frame, camera, pair)

    def flush(self) -> None:
        self._blobs.flush()
        self._wand.flush()

    def close(self) -> dict[str, dict]:
        """Close the files and rewrite wand.csv by ``wandcal detect``'s rule over the whole
        recording. Returns per camera ``{"wand_frames", "too_few", "too_many", "still_markers"}``."""
        self.end_static()
        self._blobs.close()
        self._wand.close()
        blobs = parse_wand_csv((self.folder / BLOBS_FILE).read_text(), self.rig, str(self.folder / BLOBS_FILE))
        lines, report = [_csv_line(WAND_COLUMNS)], {}
        for c, cid in enumerate(self.ids):
            rows = blobs.camera == c
            frame, uv = blobs.frame[rows], blobs.uv[rows]
            delivered = np.frombuffer(self._delivered[c], dtype=np.int64) if len(self._delivered[c]) else np.zeros(0, np.int64)
            lo, hi = np.searchsorted(frame, delivered, "left"), np.searchsorted(frame, delivered, "right")
            kept = wand_frames([uv[a:b] for a, b in zip(lo, hi)])
            for f, pair in zip(delivered[kept.frame], kept.uv):
                lines += _uv_lines(f"{f},{cid},", pair)
            report[cid] = {"wand_frames": len(kept), "too_few": kept.too_few, "too_many": kept.too_many,
                           "still_markers": len(kept.still_uv)}
        partial = self.folder / (WAND_FILE + ".partial")
        partial.write_text("".join(lines))
        os.replace(partial, self.folder / WAND_FILE)
        return report
