"""What ``wandcal calibrate`` and ``wandcal check`` read beside the capture's blobs: its frame rate and
camera timestamps (for ``--sync auto``), its points level (detected first from images), and a
previous result's cameras in the capture's order."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from wandcal.calib.errors import CalibrationError
from wandcal.capture.recording.stamps import capture_rate, timestamp_start  # noqa: F401  (read here before)
from wandcal.drivers.capture_files import WAND_FILE


def points_level(folder: Path, progress) -> Path:
    """Detect first when the capture is image level (:func:`wandcal.capture.images.ensure_points_level`)."""
    if not folder.is_dir() or (folder / WAND_FILE).is_file():
        return folder  # read_capture names what is missing
    from wandcal.capture.images import ensure_points_level

    return ensure_points_level(folder, progress=progress)


def result_for(result_path: Path, cap):
    """The result's cameras (calibrated intrinsics, poses and figures) in the capture's camera order."""
    from wandcal.calib.judge.evaluate import rig_mismatches
    from wandcal.capture.result_file import read_result

    prev = read_result(result_path)
    mismatch = rig_mismatches(prev.rig, cap.rig)
    if mismatch:
        raise CalibrationError(f"{result_path}: the capture is not of this result's rig: {'; '.join(mismatch[:3])}; check "
                               "that the capture and the result are of one rig, or calibrate the capture afresh")
    order = [prev.rig.index(cid) for cid in cap.rig.ids]
    rig = replace(cap.rig, cameras=tuple(prev.rig.cameras[k] for k in order))
    entries = [prev.result.cameras[k] for k in order]
    return prev, rig, prev.R[order], prev.t[order], entries
