"""Read a ``wandcal-result/1`` file back: the cameras' intrinsics and poses, checked field by field.

``wandcal export``, ``report``, ``check`` and ``calibrate --from`` start here, so a hand-edited or
truncated result stops with a message that names the file, the camera and the field.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig
from wandcal.capture.folder import CaptureFormatError
from wandcal.capture.result_schema import CAMERA_FIELDS, RESULT_FIELDS, check_fields
from wandcal.capture.rig_file import MAX_IMAGE_SIDE_PX, positive_number

RESULT_FORMAT = "wandcal-result/1"
ROTATION_TOLERANCE = 1e-6  # |R^T R - I|: a result written by wandcal is orthonormal to ~1e-15


@dataclass(frozen=True, eq=False)
class ResultFile:
    """A parsed result.

    doc: the JSON document as read; rig: its cameras (intrinsics as refined) and wand length
    (None without a wand); R: (N, 3, 3), t: (N, 3) world->camera, metres.
    """

    path: Path
    doc: dict
    rig: Rig
    R: np.ndarray
    t: np.ndarray


def read_result(path: str | Path) -> ResultFile:
    """Read and check a result file; raises :class:`CaptureFormatError` naming what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; give a result file written by 'wandcal calibrate'")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8-sig"), parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError, NaN, digit limit
        raise CaptureFormatError(f"{path}: not a JSON result file ({type(exc).__name__}: {str(exc)[:200]})") from None
    return result_from_json(doc, str(path), path)


def result_from_json(doc: object, source: str = "result", path: Path | None = None, rig: Rig | None = None) -> ResultFile:
    """Check a parsed result document; errors name ``source``, the camera and the field. A camera
    entry without intrinsics (width, height, K, dist, model) takes them from ``rig``, if given."""
    cameras, R, t = check_result(doc, source, rig)
    assert isinstance(doc, dict)
    wand = doc.get("wand")
    length = wand.get("length_m") if isinstance(wand, dict) else None
    try:
        rig = Rig(cameras, float(length) if length is not None else None)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None
    return ResultFile(path or Path(source), doc, rig, np.array(R), np.array(t))


def check_result(doc: object, source: str = "result", rig: Rig | None = None) -> tuple[list[Camera], list, list]:
    """The cameras, rotations and translations of a result document, every field its consumers
    use checked (capture/result_schema.py); raises :class:`CaptureFormatError` naming the field."""
    by_id = {c.id: c for c in rig.cameras} if rig is not None else {}
    if not isinstance(doc, dict):
        raise CaptureFormatError(f"{source}: the top level must be a JSON object")
    if doc.get("format") != RESULT_FORMAT:
        from wandcal.capture.rig_file import check_format  # the capture and result formats' one version check

        check_format(doc.get("format"), RESULT_FORMAT, source, hint="give a file written by 'wandcal calibrate'")
    entries = doc.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise CaptureFormatError(f"{source}: 'cameras' must be a non-empty list")
    cameras, R, t = [], [], []
    for k, entry in enumerate(entries):
        where = f"{source}: cameras[{k}]"
        if not isinstance(entry, dict):
            raise CaptureFormatError(f"{where} must be a JSON object")
        where = f"{source}: camera {entry.get('id', k)!r}"
        if not isinstance(entry.get("model", "pinhole"), str):
            raise CaptureFormatError(f"{where}: 'model' must be \"pinhole\" or \"fisheye\"")
        known = by_id.get(entry.get("id")) if isinstance(entry.get("id"), str) else None
        if known is not None:  # a result without intrinsics takes them from the capture's rig
            entry = {"width": known.width, "height": known.height, "K": known.K.tolist(), "dist": known.dist.tolist(),
                     "model": known.model} | {key: v for key, v in entry.items() if v is not None}
        try:
            cameras.append(Camera(entry.get("id"), _int(entry, "width", where), _int(entry, "height", where),
                                  _array(entry, "K", (3, 3), where), _array(entry, "dist", None, where),
                                  entry.get("model", "pinhole")))
        except CaptureFormatError:
            raise
        except CalibrationError as exc:
            raise CaptureFormatError(f"{source}: {exc}") from None
        Rk = _array(entry, "R", (3, 3), where)
        if np.abs(Rk.T @ Rk - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(Rk) < 0:
            raise CaptureFormatError(f"{where}: 'R' is not a rotation matrix (orthonormal, determinant +1)")
        R.append(Rk)
        t.append(_array(entry, "t", (3,), where))
        check_fields(entry, CAMERA_FIELDS, f"{where}:")
    check_fields(doc, RESULT_FIELDS, f"{source}:")
    wand = doc.get("wand")
    length = wand.get("length_m") if isinstance(wand, dict) else None
    if length is not None and not positive_number(length):
        raise CaptureFormatError(f"{source}: 'wand.length_m' must be a positive number of metres")
    ids = [c.id for c in cameras]
    if len(set(ids)) != len(ids):
        raise CaptureFormatError(f"{source}: camera ids must be unique; {ids}")
    return cameras, R, t


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _int(entry: dict, key: str, where: str) -> int:
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0 or value > MAX_IMAGE_SIDE_PX:
        raise CaptureFormatError(f"{where}: {key!r} must be a positive whole number of pixels, got {value!r}")
    return value


def _array(entry: dict, key: str, shape: tuple | None, where: str) -> np.ndarray:
    value = entry.get(key)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        arr = None
    if arr is None or value is None or (shape is not None and arr.shape != shape) or (shape is None and arr.ndim != 1):
        want = "x".join(map(str, shape)) + " numbers" if shape else "a list of numbers"
        raise CaptureFormatError(f"{where}: {key!r} must be {want}")
    if not np.all(np.isfinite(arr)):
        raise CaptureFormatError(f"{where}: {key!r} holds a value that is not finite")
    return arr
