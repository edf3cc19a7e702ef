"""Read and write the points level of a ``wandcal-capture/1`` folder (docs/capture-format.md).

Every error names the file, the field or row, and says what to fix.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calib.errors import CalibrationError
from calib.rig import AxisObservations, Camera, PointObservations, Rig, StaticObservations, WandObservations

CAPTURE_FORMAT = "wandcal-capture/1"
RIG_FILE = "rig.json"
WAND_FILE = "wand.csv"
STATIC_FILE = "static.csv"
WAND_COLUMNS = ("frame", "camera", "u", "v")
STATIC_COLUMNS = ("camera", "u", "v")


class CaptureFormatError(CalibrationError):
    """A capture folder that does not follow wandcal-capture/1."""


@dataclass(frozen=True, eq=False)
class Capture:
    """A points-level capture: the rig, its wand blobs, its optional static-object blobs, and the
    optional single-point tracks (points.csv) and axis points (axis.csv)."""

    rig: Rig
    wand: WandObservations
    static: StaticObservations | None
    points: PointObservations | None = None
    axis: AxisObservations | None = None


def rig_from_json(doc: object, source: str = RIG_FILE) -> Rig:
    """Build a :class:`Rig` from a parsed rig.json document; errors name the field."""
    if not isinstance(doc, dict):
        raise CaptureFormatError(f"{source}: the top level must be a JSON object")
    if doc.get("format") != CAPTURE_FORMAT:
        raise CaptureFormatError(f"{source}: 'format' must be {CAPTURE_FORMAT!r}, got {doc.get('format')!r}")
    cams = doc.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise CaptureFormatError(f"{source}: 'cameras' must be a non-empty list")
    cameras = []
    for i, c in enumerate(cams):
        where = f"{source}: cameras[{i}]"
        if not isinstance(c, dict):
            raise CaptureFormatError(f"{where} must be an object")
        for key in ("id", "width", "height", "K", "dist"):
            if key not in c:
                raise CaptureFormatError(f"{where} has no {key!r}; every camera needs id, width, height, K and dist")
        try:
            cameras.append(
                Camera(
                    id=str(c["id"]),
                    width=_positive_int(c["width"], f"{where}.width"),
                    height=_positive_int(c["height"], f"{where}.height"),
                    K=_matrix(c["K"], (3, 3), f"{where}.K"),
                    dist=_matrix(c["dist"], None, f"{where}.dist"),
                    model=c.get("model", "pinhole"),
                )
            )
        except CaptureFormatError:
            raise
        except CalibrationError as exc:
            raise CaptureFormatError(f"{source}: {exc}") from None
    wand = doc.get("wand")
    if not isinstance(wand, dict) or "length_m" not in wand:
        raise CaptureFormatError(f"{source}: 'wand.length_m' is missing; give the wand's marker distance in metres")
    length = wand["length_m"]
    if isinstance(length, bool) or not isinstance(length, (int, float)) or not math.isfinite(length) or length <= 0:
        raise CaptureFormatError(f"{source}: 'wand.length_m' must be a positive number of metres, got {length!r}")
    markers = None
    if doc.get("static_object") is not None:
        so = doc["static_object"]
        if not isinstance(so, dict) or "markers_m" not in so:
            raise CaptureFormatError(f"{source}: 'static_object' needs 'markers_m', a list of [x, y, z] in metres")
        markers = _matrix(so["markers_m"], None, f"{source}: static_object.markers_m")
    try:
        return Rig(cameras=tuple(cameras), wand_length=float(length), static_markers=markers)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None


def rig_to_json(rig: Rig) -> dict:
    doc = {
        "format": CAPTURE_FORMAT,
        "cameras": [
            {"id": c.id, "width": c.width, "height": c.height, "K": c.K.tolist(), "dist": c.dist.tolist()}
            | ({"model": c.model} if c.model != "pinhole" else {})
            for c in rig.cameras
        ],
        "wand": {"length_m": rig.wand_length},
    }
    if rig.static_markers is not None:
        doc["static_object"] = {"markers_m": rig.static_markers.tolist()}
    return doc


def read_rig(folder: Path) -> Rig:
    path = Path(folder) / RIG_FILE
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; a capture folder needs rig.json (see docs/capture-format.md)")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureFormatError(f"{path}: not valid JSON ({exc})") from None
    return rig_from_json(doc, str(path))


def parse_wand_csv(text: str, rig: Rig, source: str = WAND_FILE) -> WandObservations:
    """Parse wand.csv text; errors name the line and the column."""
    rows = _rows(text, WAND_COLUMNS, source)
    frame = np.empty(len(rows), dtype=np.int64)
    camera = np.empty(len(rows), dtype=np.int64)
    uv = np.empty((len(rows), 2))
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    for k, (line, row) in enumerate(rows):
        frame[k] = _int_cell(row["frame"], f"{source} line {line}, column 'frame'")
        camera[k] = _camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        uv[k] = _float_cell(row["u"], f"{source} line {line} (frame {frame[k]}), column 'u'"), _float_cell(
            row["v"], f"{source} line {line} (frame {frame[k]}), column 'v'"
        )
    return WandObservations(frame=frame, camera=camera, uv=uv)


def parse_static_csv(text: str, rig: Rig, source: str = STATIC_FILE) -> StaticObservations:
    rows = _rows(text, STATIC_COLUMNS, source)
    camera = np.empty(len(rows), dtype=np.int64)
    uv = np.empty((len(rows), 2))
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    for k, (line, row) in enumerate(rows):
        camera[k] = _camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        uv[k] = _float_cell(row["u"], f"{source} line {line}, column 'u'"), _float_cell(
            row["v"], f"{source} line {line}, column 'v'"
        )
    return StaticObservations(camera=camera, uv=uv)


def read_capture(folder: str | Path) -> Capture:
    """Read a points-level capture folder (rig.json, wand.csv, optional static.csv)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureFormatError(f"{folder}: not a folder; give the path of a wandcal-capture/1 folder")
    rig = read_rig(folder)
    wand_path = folder / WAND_FILE
    if not wand_path.is_file():
        raise CaptureFormatError(
            f"{wand_path}: not found; run 'wandcal detect {folder}' on an image-level capture first"
        )
    wand = parse_wand_csv(wand_path.read_text(), rig, str(wand_path))
    static = None
    static_path = folder / STATIC_FILE
    if static_path.is_file():
        static = parse_static_csv(static_path.read_text(), rig, str(static_path))
        if rig.static_markers is None:
            raise CaptureFormatError(
                f"{static_path}: static blobs are given but rig.json has no 'static_object.markers_m'; "
                "add the static object's marker coordinates or remove static.csv"
            )
    return Capture(rig=rig, wand=wand, static=static)


def write_capture(folder: str | Path, rig: Rig, wand: WandObservations, static: StaticObservations | None) -> None:
    """Write the points level of a capture folder, creating it if needed."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
    ids = rig.ids
    with open(folder / WAND_FILE, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(WAND_COLUMNS)
        for f, c, (u, v) in zip(wand.frame, wand.camera, wand.uv):
            w.writerow([int(f), ids[c], f"{u:.4f}", f"{v:.4f}"])
    if static is not None:
        with open(folder / STATIC_FILE, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(STATIC_COLUMNS)
            for c, (u, v) in zip(static.camera, static.uv):
                w.writerow([ids[c], f"{u:.4f}", f"{v:.4f}"])


def _rows(text: str, columns: tuple[str, ...], source: str) -> list[tuple[int, dict]]:
    reader = csv.DictReader(text.splitlines())
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in columns if c not in header]
    if missing:
        raise CaptureFormatError(
            f"{source}: missing column(s) {', '.join(missing)}; the header must be {','.join(columns)}"
        )
    reader.fieldnames = header
    out = []
    for line, row in enumerate(reader, start=2):
        if not any((v or "").strip() for v in row.values() if isinstance(v, str)):
            continue
        out.append((line, row))
    return out


def _camera_cell(value: str | None, lookup: dict[str, int], rig: Rig, where: str) -> int:
    key = (value or "").strip()
    if key not in lookup:
        raise CaptureFormatError(f"{where}: unknown camera id {key!r}; rig.json lists {', '.join(rig.ids)}")
    return lookup[key]


def _float_cell(value: str | None, where: str) -> float:
    try:
        x = float((value or "").strip())
    except ValueError:
        raise CaptureFormatError(f"{where}: {value!r} is not a number") from None
    if not math.isfinite(x):
        raise CaptureFormatError(f"{where}: {value!r} is not finite; drop rows of undetected blobs instead of NaN")
    return x


def _int_cell(value: str | None, where: str) -> int:
    try:
        return int((value or "").strip())
    except ValueError:
        raise CaptureFormatError(f"{where}: {value!r} is not a whole frame number") from None


def _positive_int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise CaptureFormatError(f"{where} must be a positive whole number of pixels, got {value!r}")
    return value


def _matrix(value: object, shape: tuple[int, int] | None, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise CaptureFormatError(f"{where} must be numbers, got {value!r}") from None
    if shape is not None and arr.shape != shape:
        raise CaptureFormatError(f"{where} must be {shape[0]}x{shape[1]}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CaptureFormatError(f"{where} holds a non-finite number")
    return arr
