"""Read any camera format ``wandcal export`` writes back as a rig (``wandcal import cameras``).

The readers live beside their writers (:mod:`wandcal.capture.formats.export`'s table); this
module picks one by name or by the file's extension, and turns what it read into ``rig.json``
(the intrinsics, and the wand when given) and ``poses.json`` (a ``wandcal-result/1`` document
with every camera's pose, which ``wandcal export`` converts onward). docs/import.md.
"""

from __future__ import annotations

import json
from pathlib import Path

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Rig
from wandcal.capture.csv_tables import MAX_CSV_BYTES
from wandcal.capture.folder import CaptureFormatError, rig_to_json
from wandcal.capture.formats import dlt, qualisys_vicon
from wandcal.capture.formats.anipose_opencv import read_anipose_toml, read_opencv_yaml
from wandcal.capture.formats.cameras import BOTTOM_LEFT, PosedCameras
from wandcal.drivers.capture_files import RIG_FILE

POSES_FILE = "poses.json"
CAMERA_FORMATS = ("anipose-toml", "opencv-yaml", "dlt-csv", "qca", "xcp")
BY_SUFFIX = {".toml": "anipose-toml", ".yaml": "opencv-yaml", ".yml": "opencv-yaml", ".csv": "dlt-csv",
             ".qca": "qca", ".txt": "qca", ".xcp": "xcp"}  # Qualisys names its files *.qca.txt


def guess_format(path: Path) -> str | None:
    """The camera format a file's extension names, or None."""
    return BY_SUFFIX.get(Path(path).suffix.lower())


# Every imported file (a camera file here, a session's files in capture/importers/) is read whole:
# past this size it is refused before it is read. The capture CSVs' own bound (about 2 million
# rows); a camera file or a keypoint table larger is not one.
MAX_IMPORT_BYTES = MAX_CSV_BYTES


def check_size(path: Path, what: str) -> None:
    """Refuse ``path`` before it is read when it is larger than :data:`MAX_IMPORT_BYTES` (a read
    of any size would allocate as much). A file that cannot be examined is left to its read."""
    try:
        size = path.stat().st_size
    except OSError:
        return
    if size > MAX_IMPORT_BYTES:
        raise CaptureFormatError(f"{path}: {size} bytes, more than the {MAX_IMPORT_BYTES} an imported {what} may "
                                 "hold; give a shorter recording, or keep every n-th frame")


def read_camera_file(path: str | Path, fmt: str | None = None, unit: str | None = None, origin: str = BOTTOM_LEFT,
                     sizes: list[tuple[int, int]] | None = None, ids: list[str] | None = None) -> PosedCameras:
    """The cameras and poses of an exported camera file.

    Args:
        fmt: one of :data:`CAMERA_FORMATS`; None: from the extension.
        unit: the file's length unit where the format does not say (anipose-toml, dlt-csv;
            ``m`` by default); OpenCV YAML names its own, qca and xcp are in mm.
        origin: dlt-csv's pixel origin (``bottom-left``, DLTdv's, or ``top-left``).
        sizes: dlt-csv only: (width, height) pixels per camera, or one for every camera.
        ids: dlt-csv only: camera names (default ``cam1``...).
    """
    path = Path(path)
    fmt = fmt or guess_format(path)
    if fmt not in CAMERA_FORMATS:
        raise CaptureFormatError(f"{path}: cannot tell its format from the extension; give --format, one of "
                                 f"{', '.join(CAMERA_FORMATS)}")
    check_size(path, "camera file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureFormatError(f"{path}: cannot read it as text ({exc})") from None
    try:
        if fmt == "anipose-toml":
            return read_anipose_toml(text, unit or "m", str(path))
        if fmt == "opencv-yaml":
            return read_opencv_yaml(text, str(path))
        if fmt == "qca":
            return qualisys_vicon.read_qca(text, str(path))
        if fmt == "xcp":
            return qualisys_vicon.read_xcp(text, str(path))
        return dlt.read_dlt_csv(text, _dlt_sizes(text, sizes, path), origin, unit or "m", ids, str(path))
    except CaptureFormatError:
        raise
    except CalibrationError as exc:
        raise CaptureFormatError(str(exc)) from None


def _dlt_sizes(text: str, sizes: list[tuple[int, int]] | None, path: Path) -> list[tuple[int, int]]:
    """Every camera's image size: DLT coefficients do not hold them."""
    first = next((line for line in text.splitlines() if line.strip()), "")
    n = len(first.split(","))
    if not sizes:
        raise CaptureFormatError(f"{path}: DLT coefficients hold no image size; give --size WIDTHxHEIGHT (once for "
                                 f"every camera, or once per camera: {n} columns here)")
    if len(sizes) == 1:
        return sizes * n
    if len(sizes) != n:
        raise CaptureFormatError(f"{path}: {n} cameras (columns) but {len(sizes)} --size values; give one per camera "
                                 "or one for all")
    return list(sizes)


def rig_of(posed: PosedCameras, wand_length: float | None = None) -> Rig:
    """The cameras as a :class:`Rig` (no static object)."""
    return Rig(tuple(posed.cameras), wand_length)


def poses_document(posed: PosedCameras, source: str) -> dict:
    """The cameras and their poses as a ``wandcal-result/1`` document (``R`` (3, 3) and ``t``
    (3,) world->camera, metres; ``center`` (3,) metres), which ``wandcal export`` reads."""
    return {
        "format": "wandcal-result/1",
        "source": source,
        "cameras": [
            {"id": c.id, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist(),
             "model": c.model, "R": posed.R[i].tolist(), "t": posed.t[i].tolist(), "center": posed.centers[i].tolist()}
            for i, c in enumerate(posed.cameras)
        ],
    }


def write_cameras(folder: Path, posed: PosedCameras, source: str, wand_length: float | None = None) -> Rig:
    """Write ``rig.json`` and ``poses.json`` into ``folder`` (new or empty); the rig."""
    try:
        rig = rig_of(posed, wand_length)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
    write_poses(folder, posed, source)
    return rig


def write_poses(folder: Path, posed: PosedCameras, source: str) -> None:
    """Write :func:`poses_document` to ``folder``/:data:`POSES_FILE`."""
    (Path(folder) / POSES_FILE).write_text(json.dumps(poses_document(posed, source), indent=2) + "\n")
