"""What ``wandcal calibrate`` and ``wandcal check`` read beside the capture's blobs: its frame rate and
camera timestamps (for ``--sync auto``), its points level (detected first from images), and a
previous result's cameras in the capture's order."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.drivers.capture_files import LOG_FILE, SYNC_FILE, WAND_FILE


def capture_rate(folder: Path) -> float | None:
    """The capture log's frame rate (capture.json ``rate_hz``), for offsets in seconds; None without one."""
    try:
        return float(json.loads((folder / LOG_FILE).read_text())["rate_hz"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def timestamp_start(folder: Path, rig, rate_hz: float | None):
    """Whole-frame offsets from sync.csv's camera timestamps when no trigger stamped it (docs/sync.md), else None."""
    from wandcal.calib.start.timestamps import timestamp_offsets

    path = folder / SYNC_FILE
    table = np.genfromtxt(path, delimiter=",", names=True) if path.is_file() else None
    if table is None or not table.size or np.isfinite(np.atleast_1d(table["trigger_us"])).any():
        return None
    table = np.atleast_1d(table)
    cols = [table[f"{cam.id}_ts"] if f"{cam.id}_ts" in table.dtype.names else np.full(len(table), np.nan) for cam in rig.cameras]
    frames = [table["frame"][np.isfinite(c)].astype(np.int64) for c in cols]
    return timestamp_offsets(rig.ids, frames, [c[np.isfinite(c)] for c in cols], rate_hz)


def points_level(folder: Path, progress) -> Path:
    """Detect first when the capture is image level (wandcal.capture.images provides it)."""
    if not folder.is_dir() or (folder / WAND_FILE).is_file():
        return folder  # read_capture names what is missing
    try:
        from wandcal.capture.images import ensure_points_level
    except ImportError:
        return folder
    return ensure_points_level(folder, progress=progress)


def result_for(result_path: Path, cap):
    """The result's cameras (calibrated intrinsics and poses) in the capture's camera order."""
    from wandcal.calib.judge.evaluate import rig_mismatches
    from wandcal.capture.results import read_result

    prev = read_result(result_path)
    mismatch = rig_mismatches(prev.rig, cap.rig)
    if mismatch:
        raise CalibrationError(f"{result_path}: the capture is not of this result's rig: {'; '.join(mismatch[:3])}; check "
                               "that the capture and the result are of one rig, or calibrate the capture afresh")
    order = [prev.rig.index(cid) for cid in cap.rig.ids]
    rig = replace(cap.rig, cameras=tuple(prev.rig.cameras[k] for k in order))
    entries = [prev.doc["cameras"][k] for k in order]
    return prev, rig, prev.R[order], prev.t[order], entries
