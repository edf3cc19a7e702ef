"""What ``wandcal calibrate`` and ``wandcal check`` read beside the capture's blobs: its points level
(detected first from images), and a previous result's cameras in the capture's order. (The frame
rate and camera timestamps ``--sync auto`` reads are wandcal.capture.recording.stamps's: `check`
does not import them.)"""

from __future__ import annotations

from pathlib import Path

from wandcal.drivers.capture_files import WAND_FILE


def points_level(folder: Path, progress) -> Path:
    """Detect first when the capture is image level (:func:`wandcal.capture.images.ensure_points_level`)."""
    if not folder.is_dir() or (folder / WAND_FILE).is_file():
        return folder  # read_capture names what is missing
    from wandcal.capture.images import ensure_points_level

    return ensure_points_level(folder, progress=progress)


def result_for(result_path: Path, cap):
    """The result's cameras (calibrated intrinsics, poses and figures) in the capture's camera order:
    (the ResultFile, rig, R, t, [CameraFigures]) (:func:`wandcal.service.standing_result.in_capture_order`)."""
    from wandcal.capture.result_file import read_result
    from wandcal.service.standing_result import in_capture_order

    prev = read_result(result_path)
    return (prev, *in_capture_order(prev, cap.rig, str(result_path)))
