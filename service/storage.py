"""Captures stored under the data directory: a points-level capture folder per capture, plus a row.

Layout: ``<data_dir>/captures/<id>/{rig.json, wand.csv, static.csv}`` (``docs/capture-format.md``).
Capture ids are made here (32 hex digits) and checked before any path is built from one, so no
request can point the store outside the data directory.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.rig import Rig, StaticObservations, WandObservations
from wandcal.capture.folder import (
    Capture,
    CaptureFormatError,
    check_wandless,
    parse_axis_csv,
    parse_drop_csv,
    parse_floor_csv,
    parse_points_csv,
    parse_static_csv,
    parse_wand_csv,
    read_capture,
    read_rig,
    save_capture,
)
from wandcal.capture.rig_file import load_json, rig_from_json
from wandcal.capture.world_references import reference_clash
from wandcal.drivers.capture_files import (
    AXIS_FILE,
    DROP_FILE,
    FLOOR_FILE,
    POINTS_FILE,
    RIG_FILE,
    STATIC_FILE,
    WAND_FILE,
)
from wandcal.service.db import connect, transaction

CAPTURE_ID = re.compile(r"^[0-9a-f]{32}$")
CAPTURE_FILES = (RIG_FILE, WAND_FILE, STATIC_FILE, POINTS_FILE, AXIS_FILE, FLOOR_FILE, DROP_FILE)  # what read_capture opens
WAND_PAIR = 2  # a camera image showing exactly the wand's two markers contributes a wand observation


class CaptureNotFound(LookupError):
    pass


class ReplayPathError(PermissionError):
    """A replay path that is not a folder under the configured replay root."""


class DuplicateFrameSet(ValueError):
    """A frame set that conflicts with what the capture already holds (HTTP 409)."""


@dataclass(frozen=True)
class CaptureRow:
    id: str
    created: float
    source: str
    name: str
    cameras: list[str]
    counts: dict[str, dict[str, int]]
    frames: int
    framesets: int
    has_static: bool
    static_solution: dict | None

    @classmethod
    def from_row(cls, row) -> CaptureRow:
        return cls(
            id=row["id"],
            created=row["created"],
            source=row["source"],
            name=row["name"],
            cameras=json.loads(row["cameras"]),
            counts=json.loads(row["counts"]),
            frames=row["frames"],
            framesets=row["framesets"],
            has_static=bool(row["has_static"]),
            static_solution=json.loads(row["static_solution"]) if row["static_solution"] else None,
        )

    def cameras_seeing_wand(self) -> list[str]:
        return [c for c in self.cameras if self.counts.get(c, {}).get("blobs", 0) > 0]


def wand_counts(rig: Rig, wand: WandObservations) -> tuple[dict[str, dict[str, int]], int]:
    """Per camera: blobs and frames with both wand markers; and the number of distinct frames."""
    counts = {}
    for i, cam in enumerate(rig.cameras):
        frames = wand.frame[wand.camera == i]
        _, per_frame = np.unique(frames, return_counts=True)
        counts[cam.id] = {"blobs": int(len(frames)), "pairs": int(np.sum(per_frame == WAND_PAIR))}
    return counts, int(len(np.unique(wand.frame)))


def _no_wand() -> WandObservations:
    """No wand blobs yet: a stream fills wand.csv later, or the capture has only points."""
    return WandObservations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)))


class CaptureStore:
    def __init__(self, data_dir: Path, db_path: Path, replay_root: Path | None):
        self.root = Path(data_dir).resolve() / "captures"
        self.db_path = db_path
        self.replay_root = Path(replay_root).resolve() if replay_root else None
        self._locks: dict[str, threading.Lock] = {}
        self._locks_guard = threading.Lock()
        self._rigs: dict[str, Rig] = {}

    def folder(self, capture_id: str) -> Path:
        if not CAPTURE_ID.match(capture_id):
            raise CaptureNotFound(capture_id)
        return self.root / capture_id

    # -- creating -----------------------------------------------------------------------------
    def create_from_texts(
        self, rig_text: str, wand_text: str | None, static_text: str | None, name: str = "upload",
        points_text: str | None = None, axis_text: str | None = None, vertical: tuple[str, str] | None = None,
    ) -> CaptureRow:
        """Validate uploaded rig.json / wand.csv / static.csv / points.csv / axis.csv texts and store them;
        ``vertical``: (file name, text) of floor.csv or drop.csv."""
        rig = rig_from_json(load_json(rig_text, RIG_FILE), allow_no_wand=points_text is not None)
        wand = parse_wand_csv(wand_text, rig) if wand_text is not None else _no_wand()
        points = parse_points_csv(points_text, rig) if points_text is not None else None
        axis = parse_axis_csv(axis_text, rig) if axis_text is not None else None
        if points is not None:  # a stream fills wand.csv later; an upload with points is whole now
            check_wandless(rig, wand, points)
        static = None
        if static_text is not None:
            static = parse_static_csv(static_text, rig)
            if rig.static_markers is None:
                raise CaptureFormatError(
                    "static.csv: static blobs are given but rig.json has no 'static_object.markers_m'; "
                    "add the static object's marker coordinates or leave static.csv out"
                )
        up = _vertical(rig, vertical, static, axis)
        return self._store(Capture(rig=rig, wand=wand, static=static, points=points, axis=axis, vertical=up),
                           "upload" if wand_text or points_text else "stream", name)

    def create_from_replay(self, path: str) -> CaptureRow:
        """Copy the capture folder ``path`` (relative to the replay root) into the store."""
        if self.replay_root is None:
            raise ReplayPathError("this server has no replay root, so it registers no 'path': start it with "
                                  "WANDCAL_REPLAY_ROOT=/folder/of/captures (or replay_root in its settings file) "
                                  "and give a folder under it, or upload the capture's files")
        if "\x00" in path:
            raise ReplayPathError("the replay path contains a NUL byte")
        folder = (self.replay_root / path).resolve()
        if not folder.is_relative_to(self.replay_root):
            raise ReplayPathError(
                f"replay path {path!r} leads outside the replay root; give a folder under the replay root"
            )
        if not folder.is_dir():
            raise CaptureFormatError(f"replay path {path!r}: no such folder under the replay root")
        for name in CAPTURE_FILES:  # a file may be a symlink planted to lead out of the root
            if (folder / name).exists() and not (folder / name).resolve().is_relative_to(self.replay_root):
                raise ReplayPathError(f"replay path {path!r}: {name} is a link leading outside the replay root; "
                                      "copy the file into the capture folder")
        capture = read_capture(folder)
        return self._store(capture, "replay", str(folder.relative_to(self.replay_root)))

    def _store(self, capture: Capture, source: str, name: str) -> CaptureRow:
        capture_id = uuid.uuid4().hex
        staging = self.root / f".{capture_id}.partial"  # a crash mid-write leaves no half capture behind
        try:
            save_capture(staging, capture)
        except BaseException:  # a full disk: nothing of this upload stays
            shutil.rmtree(staging, ignore_errors=True)
            raise
        return self.adopt(staging, capture_id, capture, source, name)

    def adopt(self, staging: Path, capture_id: str, capture: Capture, source: str, name: str,
              created: float | None = None) -> CaptureRow:
        """Make the complete folder ``staging`` (under the store) the capture ``capture_id``.

        The folder is renamed before its row is written: a crash in between leaves a folder
        without a row, which the next start registers (service/datafolder/recovery.py); a row that cannot
        be written (a full disk) puts the folder back to ``staging`` and raises."""
        folder = self.folder(capture_id)
        staging.rename(folder)
        counts, frames = wand_counts(capture.rig, capture.wand)
        try:
            with connect(self.db_path) as conn:
                conn.execute(
                    "INSERT INTO captures (id, created, source, name, cameras, counts, frames, has_static)"
                    " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        capture_id, created or time.time(), source, name[:200], json.dumps(capture.rig.ids),
                        json.dumps(counts), frames, int(capture.static is not None),
                    ),
                )
        except BaseException:
            folder.rename(staging)
            raise
        return self.get(capture_id)

    # -- reading ------------------------------------------------------------------------------
    def get(self, capture_id: str) -> CaptureRow:
        with connect(self.db_path) as conn:
            row = conn.execute("SELECT * FROM captures WHERE id = ?", (capture_id,)).fetchone()
        if row is None:
            raise CaptureNotFound(capture_id)
        return CaptureRow.from_row(row)

    def newest(self, limit: int = 100) -> list[CaptureRow]:
        """Up to ``limit`` captures, newest first."""
        with connect(self.db_path) as conn:
            rows = conn.execute("SELECT * FROM captures ORDER BY created DESC LIMIT ?", (limit,)).fetchall()
        return [CaptureRow.from_row(r) for r in rows]

    def load(self, capture_id: str) -> Capture:
        self.get(capture_id)
        return read_capture(self.folder(capture_id))

    def rig(self, capture_id: str) -> Rig:
        """The capture's rig (cached: a stored rig.json never changes)."""
        rig = self._rigs.get(capture_id)
        if rig is None:
            self.get(capture_id)
            rig = self._rigs[capture_id] = read_rig(self.folder(capture_id))
        return rig

    def frameset_coverage(self, capture_id: str) -> dict[str, dict[str, int]]:
        """Per camera, how many received frame sets showed 0, 1, 2 or more blobs."""
        with connect(self.db_path) as conn:
            rows = conn.execute("SELECT blobs FROM framesets WHERE capture_id = ?", (capture_id,)).fetchall()
        out: dict[str, dict[str, int]] = {}
        for row in rows:
            for cam, n in json.loads(row["blobs"]).items():
                key = str(n) if n <= WAND_PAIR else "more"
                slot = out.setdefault(cam, {"0": 0, "1": 0, "2": 0, "more": 0})
                slot[key] += 1
        return out

    # -- streaming ----------------------------------------------------------------------------
    def _lock(self, capture_id: str) -> threading.Lock:
        with self._locks_guard:
            return self._locks.setdefault(capture_id, threading.Lock())

    def append_frameset(
        self, capture_id: str, frame: int, trigger_count: int | None, blobs: dict[str, np.ndarray]
    ) -> CaptureRow:
        """Record one synchronised frame set: ``blobs`` maps camera id -> (K, 2) detected centres.

        Cameras that saw exactly the wand's two markers append two wand.csv rows.
        """
        return self.append_framesets(capture_id, [(frame, trigger_count, blobs)])

    def append_framesets(
        self, capture_id: str, sets: list[tuple[int, int | None, dict[str, np.ndarray]]]
    ) -> CaptureRow:
        """Record frame sets ``(frame, trigger_count, blobs)`` all together or, if any frame is
        already held (DuplicateFrameSet), none of them."""
        row = self.get(capture_id)
        if row.source != "stream":
            raise DuplicateFrameSet(
                f"capture {capture_id} was created from files ({row.source}); stream frame sets into a capture "
                "created by uploading rig.json alone"
            )
        path = self.folder(capture_id) / WAND_FILE
        with self._lock(capture_id):
            size = path.stat().st_size
            try:
                self._append(capture_id, sets, path)
            except BaseException:
                # the rows are appended before COMMIT: a failed commit (a full disk) or a failed
                # append rolls the rows back, and the file is cut back so no row or half row stays
                if path.stat().st_size != size:
                    os.truncate(path, size)
                raise
        return self.get(capture_id)

    def _append(self, capture_id: str, sets: list[tuple[int, int | None, dict[str, np.ndarray]]], path: Path) -> None:
        """The frame sets' rows and their wand.csv rows, in one transaction. The counts are read
        inside it: read before, two frame sets at once each added to the same old counts and one
        of them was lost (bench/bench_load.py found it)."""
        frames = [f for f, _, _ in sets]
        if len(set(frames)) != len(frames):
            raise DuplicateFrameSet(f"a frame is given twice among the {len(frames)} frame sets sent together")
        with transaction(self.db_path) as conn:
            held = {r[0] for r in conn.execute(
                "SELECT frame FROM framesets WHERE capture_id = ? AND frame BETWEEN ? AND ?",
                (capture_id, min(frames), max(frames)),
            )}
            again = sorted(held.intersection(frames))
            if again:
                listed = ", ".join(map(str, again[:5])) + (f" and {len(again) - 5} more" if len(again) > 5 else "")
                raise DuplicateFrameSet(f"frame {listed} of capture {capture_id} was already received")
            counts = json.loads(conn.execute("SELECT counts FROM captures WHERE id = ?", (capture_id,)).fetchone()[0])
            lines, rows, wand_frames, now = [], [], 0, time.time()
            for frame, trigger_count, blobs in sets:
                pairs = [(cam, uv) for cam, uv in blobs.items() if len(uv) == WAND_PAIR]
                for cam, uv in pairs:
                    lines += [f"{frame},{cam},{u:.4f},{v:.4f}\n" for u, v in uv]
                    counts[cam]["blobs"] += WAND_PAIR
                    counts[cam]["pairs"] += 1
                wand_frames += bool(pairs)
                rows.append((capture_id, frame, trigger_count, now, json.dumps({c: len(uv) for c, uv in blobs.items()})))
            conn.executemany(
                "INSERT INTO framesets (capture_id, frame, trigger_count, received, blobs) VALUES (?, ?, ?, ?, ?)", rows
            )
            conn.execute(
                "UPDATE captures SET counts = ?, frames = frames + ?, framesets = framesets + ? WHERE id = ?",
                (json.dumps(counts), wand_frames, len(sets), capture_id),  # frame sets are unique per frame
            )
            if lines:
                with open(path, "a") as fh:
                    fh.writelines(lines)

    def set_static(self, capture_id: str, static: StaticObservations, rig: Rig) -> None:
        """Replace the capture's static.csv with freshly detected static blobs."""
        folder = self.folder(capture_id)
        ids = rig.ids
        text = "camera,u,v\n" + "".join(f"{ids[c]},{u:.4f},{v:.4f}\n" for c, (u, v) in zip(static.camera, static.uv))
        tmp = folder / (STATIC_FILE + ".partial")
        try:
            tmp.write_text(text)
            tmp.replace(folder / STATIC_FILE)
        except BaseException:  # a full disk: the old static.csv stays whole
            tmp.unlink(missing_ok=True)
            raise
        with connect(self.db_path) as conn:
            conn.execute("UPDATE captures SET has_static = 1 WHERE id = ?", (capture_id,))

    def set_static_solution(self, capture_id: str, solution: dict) -> None:
        with connect(self.db_path) as conn:
            conn.execute(
                "UPDATE captures SET static_solution = ? WHERE id = ?", (json.dumps(solution), capture_id)
            )

    def captured_ids(self) -> list[str]:
        """Ids of the capture folders on disk (registered or not)."""
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and CAPTURE_ID.match(p.name))


def _vertical(rig, given: tuple[str, str] | None, static, axis):
    """An uploaded floor.csv or drop.csv, parsed; refused by the world-reference rule
    (:mod:`wandcal.capture.world_references`) beside static.csv or axis.csv with rows, as is
    axis.csv beside static.csv."""
    vertical = None
    if given is not None:
        name, text = given
        vertical = (parse_floor_csv if name == FLOOR_FILE else parse_drop_csv)(text, rig)
    held = ((STATIC_FILE, static), (AXIS_FILE, axis), (given[0] if given is not None else FLOOR_FILE, vertical))
    clash = reference_clash([name for name, rows in held if rows is not None and len(rows.camera)])
    if clash is not None:
        raise CaptureFormatError(f"{clash.at_fault}: {clash.message('this upload')}")
    return vertical
