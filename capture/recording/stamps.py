"""What a recording without a trigger leaves for ``--sync auto``: the cameras' timestamps in
``sync.csv`` and the frame rate in ``capture.json`` (docs/sync.md), read and checked.

sync.csv is parsed by its one reader, :func:`wandcal.drivers.imagefolder.read_sync`; this module
turns its rows into each camera's (frame, timestamp) pairs and the whole-frame offsets
:func:`wandcal.calib.start.offsets.timestamps.timestamp_offsets` finds from them. Errors name the file,
and the line or field (before: numpy's ``genfromtxt`` read sync.csv, and a missing column, a
cell of text or a duplicated frame ended ``wandcal calibrate --sync auto`` in a traceback).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from wandcal.calib.rig import Rig
from wandcal.capture.folder import CaptureFormatError
from wandcal.drivers.capture_files import LOG_FILE, SYNC_FILE
from wandcal.drivers.imagefolder import read_sync

MAX_RATE_HZ = 1e6  # no camera records a million frames a second; past it the number is a typo
MAX_STAMP_US = 2**53  # ~285 years of microseconds: exact as a float, so no offset overflows


def capture_rate(folder: Path) -> float | None:
    """The frame rate in ``capture.json`` (``rate_hz``), for offsets in seconds; None without a
    log or a rate in it (an import, an older recording). A rate that is not a positive number up to
    :data:`MAX_RATE_HZ` is refused naming the field."""
    path = Path(folder) / LOG_FILE
    try:
        rate = json.loads(path.read_bytes())["rate_hz"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    if isinstance(rate, bool) or not isinstance(rate, (int, float)):
        raise CaptureFormatError(f"{path}: rate_hz must be a number of frames a second, got {str(rate)[:40]!r}")
    try:
        rate = float(rate)
    except OverflowError:
        rate = math.inf
    if not 0 < rate <= MAX_RATE_HZ:
        raise CaptureFormatError(f"{path}: rate_hz {rate:g} is not a frame rate (0 to {MAX_RATE_HZ:g} Hz); fix it or "
                                 "remove the capture log's rate_hz")
    return rate


def camera_stamps(folder: Path, rig: Rig) -> tuple[list[np.ndarray], list[np.ndarray]] | None:
    """Each rig camera's frames (K_c,) int and timestamps (K_c,) microseconds from ``sync.csv``;
    None without a sync.csv, without rows, or when a trigger stamped the frames (its times rule)."""
    path = Path(folder) / SYNC_FILE
    try:
        rows = read_sync(folder)
    except ValueError as exc:
        raise CaptureFormatError(str(exc)) from None
    if not rows or any(r.trigger_us is not None for r in rows):
        return None
    seen: dict[int, int] = {}
    for line, row in enumerate(rows, start=2):
        if row.frame in seen:
            raise CaptureFormatError(f"{path}: frame {row.frame} on two rows; each frame set has one row")
        seen[row.frame] = line
        bad = [c for c, us in row.camera_us.items() if us is not None and not 0 <= us <= MAX_STAMP_US]
        if bad or row.frame > MAX_STAMP_US:
            raise CaptureFormatError(f"{path}: frame {row.frame}: {'a timestamp' if bad else 'the frame number'} "
                                     f"out of range (0 to {MAX_STAMP_US} microseconds){' for ' + bad[0] if bad else ''}")
    frames, stamps = [], []
    for cam in rig.cameras:
        had = [(r.frame, r.camera_us.get(cam.id)) for r in rows if r.camera_us.get(cam.id) is not None]
        frames.append(np.array([f for f, _ in had], dtype=np.int64))
        stamps.append(np.array([us for _, us in had], dtype=float))
    return frames, stamps


def timestamp_start(folder: Path, rig: Rig, rate_hz: float | None) -> np.ndarray | None:
    """Whole-frame offsets (N,) from sync.csv's camera timestamps when no trigger stamped it
    (docs/sync.md), else None; a contradiction in them is refused naming sync.csv."""
    from wandcal.calib.errors import CalibrationError
    from wandcal.calib.start.offsets.timestamps import timestamp_offsets

    stamps = camera_stamps(folder, rig)
    if stamps is None:
        return None
    try:
        return timestamp_offsets(rig.ids, *stamps, rate_hz)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{Path(folder) / SYNC_FILE}: {exc}") from None
