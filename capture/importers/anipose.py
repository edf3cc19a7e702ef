"""anipose / aniposelib / Pose2Sim sessions as captures: ``calibration.toml`` and 2D keypoints.

The cameras come from the TOML (:func:`wandcal.capture.formats.anipose_opencv.read_anipose_toml`);
the points from the 2D files anipose users keep (:mod:`wandcal.capture.importers.deeplabcut`):
DeepLabCut CSVs, one per camera, or aniposelib's points array (``.npy``, every camera). Every
keypoint becomes a labelled row of ``points.csv`` (its ``point`` column): a (keypoint, frame)
pair is one 3D point. There is no wand: the calibration has no metric scale. docs/import.md.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import PointObservations, Rig, WandObservations
from wandcal.capture.folder import Capture, CaptureFormatError
from wandcal.capture.formats.anipose_opencv import read_anipose_toml
from wandcal.capture.formats.cameras import PosedCameras
from wandcal.capture.formats.cameras_in import POSES_FILE
from wandcal.capture.importers.deeplabcut import DEFAULT_MIN_LIKELIHOOD, Keypoints, read_dlc_csv, read_points_npy
from wandcal.capture.importers.summary import Imported

DLC_SCORER = "DLC_"  # DeepLabCut names its output <video>DLC_<network>...: the camera is in <video>


def read_anipose(toml: str | Path, points: list[str] | None = None, unit: str = "m",
                 min_likelihood: float = DEFAULT_MIN_LIKELIHOOD) -> tuple[Imported, PosedCameras]:
    """Import an anipose ``calibration.toml`` and its 2D keypoints.

    Args:
        toml: the calibration file; its ``[cam_i]`` tables give the cameras (pixels, top-left).
        points: ``FILE`` or ``CAMERA=FILE`` entries: one DeepLabCut CSV per camera (a bare
            ``FILE`` is matched to the camera its name carries, as anipose's ``cam_regex`` does),
            or one aniposelib ``.npy`` array (C, N, J, 2) or (C, N, 2) in the TOML's camera order.
        unit: the TOML's translation unit (``m`` or ``mm``).
        min_likelihood: DeepLabCut keypoints below this likelihood are left out.

    Returns:
        the import, and the TOML's cameras with their poses (metres).
    """
    toml = Path(toml)
    try:
        text = toml.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CaptureFormatError(f"{toml}: cannot read the calibration ({exc}); give anipose's calibration.toml") from None
    try:
        posed = read_anipose_toml(text, unit, str(toml))
    except CaptureFormatError:
        raise
    except CalibrationError as exc:
        raise CaptureFormatError(str(exc)) from None
    names = [c.id for c in posed.cameras]
    tables = _camera_tables(text)
    notes = [f"the TOML's poses are written to {POSES_FILE} (a wandcal-result/1 document; translations read in "
             f"{unit}); the calibration solves its own"]
    if not points:
        # a capture without a wand needs its points (docs/capture-format.md): no capture to write
        raise CaptureFormatError(f"{toml}: no --points given; give the 2D keypoints (DeepLabCut CSVs or an aniposelib "
                                 ".npy) to calibrate, or read the cameras alone with 'wandcal import cameras'")
    per_camera = _read_points(points, names, tables, toml, min_likelihood)
    obs, note = _observations(per_camera)
    notes.append(note)
    try:
        rig = Rig(tuple(posed.cameras), None)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{toml}: {exc}") from None
    wand = WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    source = str(toml) + "".join(f", {p}" for p in points or ())
    return Imported(Capture(rig=rig, wand=wand, static=None, points=obs), source, tuple(notes)), posed


def _camera_tables(text: str) -> dict[str, str]:
    """Camera name -> its ``[cam_i]`` table name, for messages."""
    import tomllib

    doc = tomllib.loads(text)
    return {str(v.get("name", k)): k for k, v in doc.items() if isinstance(v, dict) and k != "metadata"}


def _read_points(entries: list[str], names: list[str], tables: dict[str, str], toml: Path,
                 min_likelihood: float) -> dict[int, Keypoints]:
    """Keypoints per camera index, every TOML camera named by some file."""
    npys = [e for e in entries if e.lower().endswith(".npy")]
    if npys:
        if len(entries) != 1:
            raise CaptureFormatError(f"{npys[0]}: an aniposelib points array holds every camera; give it alone as "
                                     "--points, not with other files")
        arrays = read_points_npy(Path(npys[0]), len(names), str(toml))
        return dict(enumerate(arrays))
    per_camera: dict[int, Keypoints] = {}
    for entry in entries:
        cam, path = _camera_of(entry, names)
        if cam in per_camera:
            raise CaptureFormatError(f"{path}: camera {names[cam]!r} already has {per_camera[cam].source}; give one "
                                     "DeepLabCut file per camera")
        per_camera[cam] = read_dlc_csv(path, min_likelihood)
    missing = [n for i, n in enumerate(names) if i not in per_camera]
    if missing:
        raise CaptureFormatError(
            f"{toml}: [{tables.get(missing[0], '?')}] name = {missing[0]!r}: no --points file names this camera; give "
            f"--points {missing[0]}=FILE with its keypoints, or remove the camera from the TOML")
    return per_camera


def _camera_of(entry: str, names: list[str]) -> tuple[int, Path]:
    """(camera index, path) of a ``CAMERA=FILE`` or ``FILE`` entry; a bare file name must carry
    exactly one camera's name as a word (``..._camA-...`` or ``..._A_...``)."""
    name, sep, rest = entry.partition("=")
    if sep and name in names:
        return names.index(name), Path(rest)
    path = Path(entry)
    video = path.stem.split(DLC_SCORER)[0]  # DeepLabCut appends its scorer to the video's name
    words = {w.lower() for w in re.split(r"[^A-Za-z0-9]+", video) if w}
    hits = [i for i, n in enumerate(names) if n.lower() in words or f"cam{n}".lower() in words]
    if len(hits) != 1:
        said = "names no camera" if not hits else f"names cameras {', '.join(names[i] for i in hits)}"
        raise CaptureFormatError(f"{path}: the file name {said} of the TOML ({', '.join(names)}); give "
                                 f"--points CAMERA={path}")
    return hits[0], path


def _observations(per_camera: dict[int, Keypoints]) -> tuple[PointObservations, str]:
    """Labelled point rows from every camera's keypoints, sorted by frame and camera."""
    frame = np.concatenate([k.frame for k in per_camera.values()])
    camera = np.concatenate([np.full(len(k.frame), c) for c, k in per_camera.items()])
    uv = np.concatenate([k.uv for k in per_camera.values()])
    label = np.concatenate([k.label for k in per_camera.values()])
    order = np.lexsort((label, camera, frame))
    left_out = sum(k.left_out for k in per_camera.values())
    parts = sorted(set(label.tolist()))
    note = (f"{len(parts)} keypoints ({', '.join(parts[:8])}{', ...' if len(parts) > 8 else ''}) as labelled points; "
            f"{left_out} camera-keypoint-frames left out (not seen, or below the likelihood threshold)")
    return PointObservations(frame[order], camera[order], uv[order], label[order]), note
