"""File layout of the image level of a ``wandcal-capture/1`` folder (docs/capture-format.md).

The replay driver reads it and ``capture/`` writes it, so it lives here, below both; the names
of the files and folders are in :mod:`wandcal.drivers.capture_files`.

    rig.json
    sync.csv                      frame,trigger_count,trigger_us,<camera_id>_ts...
    frames/<camera_id>/<frame:06d>.png
    static/<camera_id>/<n:06d>.png
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

from wandcal.drivers.capture_files import FRAMES_DIR, SYNC_FILE

SYNC_FIXED = ("frame", "trigger_count", "trigger_us")
TS_SUFFIX = "_ts"
IMAGE_SUFFIX = ".png"


def image_path(folder: Path, phase: str, camera_id: str, index: int) -> Path:
    """Path of one image; ``phase`` is :data:`FRAMES_DIR` or :data:`STATIC_DIR`."""
    return Path(folder) / phase / camera_id / f"{index:06d}{IMAGE_SUFFIX}"


def sync_header(camera_ids: list[str]) -> list[str]:
    return [*SYNC_FIXED, *(f"{c}{TS_SUFFIX}" for c in camera_ids)]


@dataclass(frozen=True)
class SyncRow:
    """One frame set: pulse counter and time (None without a trigger) and each camera's
    timestamp in microseconds (None where that camera missed the pulse)."""

    frame: int
    trigger_count: int | None
    trigger_us: int | None
    camera_us: dict[str, int | None]


def read_sync(folder: Path) -> list[SyncRow] | None:
    """The rows of ``sync.csv``, or None when the folder has none. Errors name the line."""
    path = Path(folder) / SYNC_FILE
    if not path.is_file():
        return None
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (not UTF-8); sync.csv is written by 'wandcal capture'") from None
    if "\0" in text:
        raise ValueError(f"{path}: holds binary data (NUL bytes); sync.csv is written by 'wandcal capture'")
    reader = csv.reader(io.StringIO(text, newline=""))
    header = next(reader, None)
    if header is None or tuple(header[:3]) != SYNC_FIXED:
        raise ValueError(f"{path}: the header must start with {','.join(SYNC_FIXED)}")
    cams = [h[: -len(TS_SUFFIX)] for h in header[3:]]
    rows = []
    for line, cells in enumerate(reader, start=2):
        if not cells:
            continue
        try:
            values = [int(c) if c.strip() else None for c in cells]
        except ValueError:
            raise ValueError(f"{path} line {line}: {cells} holds a cell that is not a whole number") from None
        if len(values) > len(header) or values[0] is None or values[0] < 0:
            raise ValueError(f"{path} line {line}: {len(cells)} cells under {len(header)} columns, or no frame "
                             "number >= 0 in the first")
        values += [None] * (len(header) - len(values))
        rows.append(SyncRow(values[0], values[1], values[2], dict(zip(cams, values[3:]))))
    return rows


def listed_cameras(folder: Path, phase: str = FRAMES_DIR) -> list[str]:
    """Camera folders present under ``phase``, sorted."""
    root = Path(folder) / phase
    return sorted(p.name for p in root.iterdir() if p.is_dir()) if root.is_dir() else []


def listed_indices(folder: Path, phase: str, camera_id: str) -> list[int]:
    """Sorted image numbers present for one camera."""
    root = Path(folder) / phase / camera_id
    if not root.is_dir():
        return []
    return sorted(int(p.stem) for p in root.glob(f"*{IMAGE_SUFFIX}") if p.stem.isdigit())
