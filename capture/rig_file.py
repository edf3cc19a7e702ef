"""``rig.json``, the rig description of a ``wandcal-capture/1`` folder (docs/capture-format.md):
its reader, checked field by field, and its writer; and the capture format's own error.

Every error names the file and the field, and says what to fix.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig
from wandcal.drivers.capture_files import POINTS_FILE, RIG_FILE

CAPTURE_FORMAT = "wandcal-capture/1"
MAX_IMAGE_SIDE_PX = 1 << 20  # no sensor is a million pixels wide: a larger width or height is a typo
# The largest optical motion-capture stages run a few hundred cameras. The solve's normal equations
# grow with the square of the cameras (15 parameters each: 7,680 x 7,680, 0.5 GB, at 512), so past
# this a rig is calibrated in overlapping groups (docs/reliability.md, "Bounded work").
MAX_CAMERAS = 512


class CaptureFormatError(CalibrationError):
    """A capture folder that does not follow wandcal-capture/1."""


class NewerFormatError(CaptureFormatError):
    """A file written by a newer wandcal (a later version of a format this release reads): refused by
    its name and version, never read as if it were the version this release knows."""


def check_format(value: object, expected: str, source: str, hint: str = "") -> None:
    """Refuse a ``format`` field that is not ``expected`` (``"family/N"``, e.g. ``wandcal-result/1``).

    A later version of the same family is a :class:`NewerFormatError` that names it ("written by a
    newer wandcal: format wandcal-result/2; upgrade wandcal"); anything else a
    :class:`CaptureFormatError` (``hint``: what to give instead, appended to the message).
    """
    if value == expected:
        return
    family, _, version = expected.rpartition("/")
    if isinstance(value, str) and value.startswith(family + "/"):
        theirs = value[len(family) + 1:]
        if theirs.isdecimal() and theirs.isascii() and len(theirs) <= 9 and int(theirs) > int(version):
            raise NewerFormatError(f"{source}: written by a newer wandcal: format {value}; upgrade wandcal (this "
                                   f"release reads {expected})")
    raise CaptureFormatError(f"{source}: 'format' must be {expected!r}, got {value!r}" + (f"; {hint}" if hint else ""))


def rig_from_json(doc: object, source: str = RIG_FILE, allow_no_wand: bool = False) -> Rig:
    """Build a :class:`Rig` from a parsed rig.json document; errors name the field.

    ``allow_no_wand``: accept a rig.json without ``wand`` (or with ``wand.length_m: null``), giving
    ``Rig.wand_length = None``; only a capture with points.csv may have no wand (read_capture).
    """
    if not isinstance(doc, dict):
        raise CaptureFormatError(f"{source}: the top level must be a JSON object")
    check_format(doc.get("format"), CAPTURE_FORMAT, source)
    cams = doc.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise CaptureFormatError(f"{source}: 'cameras' must be a non-empty list")
    if len(cams) > MAX_CAMERAS:
        raise CaptureFormatError(f"{source}: {len(cams)} cameras, more than the {MAX_CAMERAS} this release calibrates "
                                 "at once; calibrate the rig in overlapping groups of cameras")
    cameras = [_camera_from_json(c, f"{source}: cameras[{i}]") for i, c in enumerate(cams)]
    length, wand_markers = _wand_from_json(doc.get("wand"), source, allow_no_wand)
    markers = None
    if doc.get("static_object") is not None:
        so = doc["static_object"]
        if not isinstance(so, dict) or "markers_m" not in so:
            raise CaptureFormatError(f"{source}: 'static_object' needs 'markers_m', a list of [x, y, z] in metres")
        markers = _matrix(so["markers_m"], None, f"{source}: static_object.markers_m")
    try:
        return Rig(cameras=tuple(cameras), wand_length=None if length is None else float(length), static_markers=markers,
                   wand_markers=wand_markers)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None


def _camera_from_json(c: object, where: str) -> Camera:
    """One entry of rig.json's ``cameras``; ``where`` names it in errors ("rig.json: cameras[2]")."""
    if not isinstance(c, dict):
        raise CaptureFormatError(f"{where} must be an object")
    for key in ("id", "width", "height", "K", "dist"):
        if key not in c:
            raise CaptureFormatError(f"{where} has no {key!r}; every camera needs id, width, height, K and dist")
    if not isinstance(c.get("model", "pinhole"), str):
        raise CaptureFormatError(f"{where}.model must be \"pinhole\" or \"fisheye\", got {c['model']!r}")
    try:
        return Camera(
            id=str(c["id"]),
            width=_positive_int(c["width"], f"{where}.width"),
            height=_positive_int(c["height"], f"{where}.height"),
            K=_matrix(c["K"], (3, 3), f"{where}.K"),
            dist=_matrix(c["dist"], None, f"{where}.dist"),
            model=c.get("model", "pinhole"),
            focal_std_px=_focal_std(c.get("focal_std_px"), f"{where}.focal_std_px"),
        )
    except CaptureFormatError:
        raise
    except CalibrationError as exc:
        raise CaptureFormatError(f"{where}: {exc}") from None


def _wand_from_json(wand: object, source: str, allow_no_wand: bool) -> tuple[object, np.ndarray | None]:
    """rig.json's ``wand``: (length in metres as given, or None; the (M, 3) marker layout, metres, or None)."""
    length = wand.get("length_m") if isinstance(wand, dict) else None
    if wand is not None and not isinstance(wand, dict):
        raise CaptureFormatError(f"{source}: 'wand' must be an object like {{\"length_m\": 0.5}}, got {wand!r}")
    wand_markers = None
    if isinstance(wand, dict) and wand.get("markers_m") is not None:
        wand_markers = _matrix(wand["markers_m"], None, f"{source}: wand.markers_m")
        try:
            from wandcal.calib.wandlayout import check_layout, span

            length = span(check_layout(wand_markers, f"{source}: wand.markers_m")) if length is None else length
        except CaptureFormatError:
            raise
        except CalibrationError as exc:
            raise CaptureFormatError(str(exc)) from None
    if length is None:
        if not allow_no_wand:
            raise CaptureFormatError(
                f"{source}: 'wand.length_m' is missing; give the wand's marker distance in metres "
                f"(only a capture with {POINTS_FILE} may have no wand)"
            )
    elif not positive_number(length):
        raise CaptureFormatError(f"{source}: 'wand.length_m' must be a positive number of metres, got {length!r}")
    return length, wand_markers


def rig_to_json(rig: Rig) -> dict:
    doc: dict[str, Any] = {
        "format": CAPTURE_FORMAT,
        "cameras": [
            {"id": c.id, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist()}
            | ({"model": c.model} if c.model != "pinhole" else {})
            | ({"focal_std_px": c.focal_std_px} if c.focal_std_px is not None else {})
            for c in rig.cameras
        ],
    }
    if rig.wand_length is not None:  # a capture without a wand (points.csv only) has no "wand"
        doc["wand"] = {"length_m": rig.wand_length}
    if rig.wand_markers is not None:
        doc["wand"]["markers_m"] = rig.wand_markers.tolist()
    if rig.static_markers is not None:
        doc["static_object"] = {"markers_m": rig.static_markers.tolist()}
    return doc


def read_rig(folder: Path, allow_no_wand: bool = False) -> Rig:
    path = Path(folder) / RIG_FILE
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; a capture folder needs rig.json (see docs/capture-format.md)")
    return rig_from_json(load_json(path.read_bytes(), str(path)), str(path), allow_no_wand)


def load_json(data: bytes | str, source: str, what: str = "the rig description (docs/capture-format.md)"):
    """The parsed JSON document ``data``; anything that is not JSON (other bytes, another
    encoding, integers of thousands of digits, nesting deeper than the parser's stack) raises
    CaptureFormatError naming ``source``."""
    try:
        text = data.decode("utf-8-sig") if isinstance(data, bytes) else data
        return json.loads(text)
    except UnicodeDecodeError:
        raise CaptureFormatError(f"{source}: not a text file (it does not decode as UTF-8); give {what}") from None
    except RecursionError:
        raise CaptureFormatError(f"{source}: not valid JSON (nested too deeply); give {what}") from None
    except ValueError as exc:  # JSONDecodeError, and integers past Python's digit limit
        raise CaptureFormatError(f"{source}: not valid JSON ({exc}); give {what}") from None


def _focal_std(value: object, where: str) -> float | None:
    """A camera's optional focal_std_px: None, or a positive number of pixels."""
    if value is None:
        return None
    if not positive_number(value):
        raise CaptureFormatError(f"{where} must be a positive number of pixels (the focal length's 1-sigma), got "
                                 f"{str(value)[:40]!r}; leave it out where it is not known")
    return float(value)


def _positive_int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 < value <= MAX_IMAGE_SIDE_PX:
        raise CaptureFormatError(f"{where} must be a positive whole number of pixels up to {MAX_IMAGE_SIDE_PX}, "
                                 f"got {value!r}")
    return value


def positive_number(value: object) -> bool:
    """True for a JSON number that is a positive float (an integer past float range is not)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value)) and value > 0
    except OverflowError:
        return False


def _matrix(value: object, shape: tuple[int, int] | None, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise CaptureFormatError(f"{where} must be numbers, got {str(value)[:80]}") from None
    if shape is not None and arr.shape != shape:
        raise CaptureFormatError(f"{where} must be {shape[0]}x{shape[1]}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CaptureFormatError(f"{where} holds a non-finite number")
    return arr
