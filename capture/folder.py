"""Read and write the points level of a ``wandcal-capture/1`` folder (docs/capture-format.md).

Every error names the file, the field or row, and says what to fix.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.rig import (
    AXIS_ROLES,
    AxisObservations,
    PointObservations,
    Rig,
    StaticObservations,
    VerticalObservations,
    WandObservations,
)
from wandcal.capture.csv_tables import (
    camera_cell,
    csv_rows,
    float_cell,
    frame_rows,
    frame_table,
    read_csv_text,
    write_csv,
)
from wandcal.capture.rig_file import CaptureFormatError, read_rig, rig_to_json
from wandcal.capture.world_references import reference_clash
from wandcal.drivers.capture_files import (
    AXIS_FILE,
    DROP_FILE,
    FLOOR_FILE,
    POINTS_FILE,
    RIG_FILE,
    STATIC_FILE,
    WAND_FILE,
)

WAND_COLUMNS = ("frame", "camera", "u", "v")
STATIC_COLUMNS = ("camera", "u", "v")
POINTS_COLUMNS = ("frame", "camera", "u", "v")
POINT_COLUMN = "point"  # points.csv's optional last column: the point's name (labelled points)
AXIS_COLUMNS = ("role", "camera", "u", "v")
FLOOR_COLUMNS = ("point", "camera", "u", "v")
DROP_COLUMNS = ("frame", "camera", "u", "v")


@dataclass(frozen=True, eq=False)
class Capture:
    """A points-level capture: the rig, its wand blobs, its optional static-object blobs, and the
    optional single-point tracks (points.csv) and axis points (axis.csv)."""

    rig: Rig
    wand: WandObservations
    static: StaticObservations | None
    points: PointObservations | None = None
    axis: AxisObservations | None = None
    vertical: VerticalObservations | None = None


def parse_wand_csv(text: str, rig: Rig, source: str = WAND_FILE) -> WandObservations:
    """Parse wand.csv text; errors name the line and the column."""
    return WandObservations(*frame_table(text, rig, WAND_COLUMNS, source))


def parse_static_csv(text: str, rig: Rig, source: str = STATIC_FILE) -> StaticObservations:
    rows = csv_rows(text, STATIC_COLUMNS, source)
    camera = np.empty(len(rows), dtype=np.int64)
    uv = np.empty((len(rows), 2))
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    for k, (line, row) in enumerate(rows):
        camera[k] = camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        uv[k] = float_cell(row["u"], f"{source} line {line}, column 'u'"), float_cell(
            row["v"], f"{source} line {line}, column 'v'"
        )
    return StaticObservations(camera=camera, uv=uv)


def parse_points_csv(text: str, rig: Rig, source: str = POINTS_FILE) -> PointObservations:
    """Parse points.csv text; errors name the line and column.

    ``frame,camera,u,v``: one unlabelled marker per camera-frame, the same 3D point in every
    camera that saw it in that frame. With the optional ``point`` column, every row names its
    point (a body keypoint, a marker of a rigid object) and a (point, frame) pair is one 3D point.
    """
    # a camera-frame with two points is ambiguous; like a wand camera-frame with three blobs it is
    # dropped and counted by the pipeline (wandcal.calib.observations.point_tracks), not refused here
    first = text.lstrip("\ufeff").partition("\n")[0]
    if POINT_COLUMN not in (h.strip() for h in first.split(",")):
        return PointObservations(*frame_table(text, rig, POINTS_COLUMNS, source))
    rows = csv_rows(text, (*POINTS_COLUMNS, POINT_COLUMN), source)
    frame, camera, uv = frame_rows(rows, rig, source)
    names = [(row[POINT_COLUMN] or "").strip() for _, row in rows]
    named = [k for k, n in enumerate(names) if n]
    if named and len(named) < len(names):
        blank = next(k for k, n in enumerate(names) if not n)
        raise CaptureFormatError(
            f"{source} line {rows[blank][0]}, column '{POINT_COLUMN}': empty, but line {rows[named[0]][0]} names point "
            f"{names[named[0]]!r}; name the point on every row, or drop the '{POINT_COLUMN}' column for one unlabelled "
            "point per camera and frame")
    return PointObservations(frame, camera, uv, np.array(names, dtype=str) if named else None)


def parse_axis_csv(text: str, rig: Rig, source: str = AXIS_FILE) -> AxisObservations:
    """Parse axis.csv text (``role,camera,u,v``, role one of ``AXIS_ROLES``)."""
    rows = csv_rows(text, AXIS_COLUMNS, source)
    role, camera, uv = [], np.empty(len(rows), dtype=np.int64), np.empty((len(rows), 2))
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    seen: dict[tuple[str, int], int] = {}
    for k, (line, row) in enumerate(rows):
        name = (row["role"] or "").strip().lower()
        if name not in AXIS_ROLES:
            raise CaptureFormatError(
                f"{source} line {line}, column 'role': {row['role']!r} is not one of {', '.join(AXIS_ROLES)}"
            )
        role.append(name)
        camera[k] = camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        uv[k] = float_cell(row["u"], f"{source} line {line}, column 'u'"), float_cell(
            row["v"], f"{source} line {line}, column 'v'"
        )
        first = seen.setdefault((name, int(camera[k])), line)
        if first != line:
            raise CaptureFormatError(
                f"{source} line {line}: camera {rig.ids[camera[k]]!r} already has the {name!r} point (line {first}); "
                "give each axis point once per camera"
            )
    if rows and "origin" not in role:
        raise CaptureFormatError(f"{source}: no 'origin' row; the axis points need an origin seen by some camera")
    return AxisObservations(role=np.array(role, dtype=str), camera=camera, uv=uv)


def parse_floor_csv(text: str, rig: Rig, source: str = FLOOR_FILE) -> VerticalObservations:
    """Parse floor.csv text (``point,camera,u,v``: each floor point by name, once per camera that sees it)."""
    rows = csv_rows(text, FLOOR_COLUMNS, source)
    lookup = {cid: i for i, cid in enumerate(rig.ids)}
    names: dict[str, int] = {}
    seen: dict[tuple[int, int], int] = {}
    key, camera, uv = np.empty(len(rows), dtype=np.int64), np.empty(len(rows), dtype=np.int64), np.empty((len(rows), 2))
    for k, (line, row) in enumerate(rows):
        name = (row["point"] or "").strip()
        if not name:
            raise CaptureFormatError(f"{source} line {line}, column 'point': empty; name each floor point")
        key[k] = names.setdefault(name, len(names))
        camera[k] = camera_cell(row["camera"], lookup, rig, f"{source} line {line}")
        uv[k] = float_cell(row["u"], f"{source} line {line}, column 'u'"), float_cell(
            row["v"], f"{source} line {line}, column 'v'")
        first = seen.setdefault((int(key[k]), int(camera[k])), line)
        if first != line:
            raise CaptureFormatError(f"{source} line {line}: camera {rig.ids[camera[k]]!r} already has floor point "
                                     f"{name!r} (line {first}); give each floor point once per camera")
    return VerticalObservations("floor", key, camera, uv)


def parse_drop_csv(text: str, rig: Rig, source: str = DROP_FILE) -> VerticalObservations:
    """Parse drop.csv text (``frame,camera,u,v``: the dropped object, one blob per camera and frame)."""
    frame, camera, uv = frame_table(text, rig, DROP_COLUMNS, source)
    pairs = frame.astype(np.int64) * len(rig.cameras) + camera
    unique, counts = np.unique(pairs, return_counts=True)
    if len(unique) < len(pairs):
        twice = int(unique[np.argmax(counts > 1)])
        raise CaptureFormatError(f"{source}: camera {rig.ids[twice % len(rig.cameras)]!r} has two blobs in frame "
                                 f"{twice // len(rig.cameras)}; give the dropped object once per camera and frame")
    return VerticalObservations("drop", frame, camera, uv)


def _read_vertical(folder: Path, rig: Rig) -> VerticalObservations | None:
    """floor.csv or drop.csv, or None; both at once are refused (:func:`_refuse_clash`) before
    either is read."""
    floor_path, drop_path = folder / FLOOR_FILE, folder / DROP_FILE
    _refuse_clash(folder, [path.name for path in (floor_path, drop_path) if path.is_file()])
    if floor_path.is_file():
        return parse_floor_csv(read_csv_text(floor_path), rig, str(floor_path))
    if drop_path.is_file():
        return parse_drop_csv(read_csv_text(drop_path), rig, str(drop_path))
    return None


def _refuse_clash(folder: Path, given: list[str]) -> None:
    """The world-reference rule (:mod:`wandcal.capture.world_references`) on the reference files
    of ``folder`` that have rows, ``given``."""
    clash = reference_clash(given)
    if clash is not None:
        raise CaptureFormatError(f"{folder / clash.at_fault}: {clash.message()}")


def read_capture(folder: str | Path) -> Capture:
    """Read a points-level capture folder: rig.json, wand.csv, and the optional static.csv,
    points.csv and axis.csv. A capture with points.csv may have no wand (no ``wand.length_m``,
    wand.csv absent or empty)."""
    folder = Path(folder)
    if not folder.is_dir():
        hint = f" (the folder that holds it: {Path(folder).parent})" if Path(folder).is_file() else ""
        raise CaptureFormatError(f"{folder}: not a folder; give the path of a wandcal-capture/1 folder{hint}")
    points_path = folder / POINTS_FILE
    has_points = points_path.is_file()
    rig = read_rig(folder, allow_no_wand=has_points)
    wand_path = folder / WAND_FILE
    if wand_path.is_file():
        wand = parse_wand_csv(read_csv_text(wand_path), rig, str(wand_path))
    elif has_points:
        wand = WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    else:
        raise CaptureFormatError(
            f"{wand_path}: not found; run 'wandcal detect {folder}' on an image-level capture first"
        )
    static = None
    static_path = folder / STATIC_FILE
    if static_path.is_file():
        static = parse_static_csv(read_csv_text(static_path), rig, str(static_path))
        if rig.static_markers is None:
            raise CaptureFormatError(
                f"{static_path}: static blobs are given but rig.json has no 'static_object.markers_m'; "
                "add the static object's marker coordinates or remove static.csv"
            )
    points = parse_points_csv(read_csv_text(points_path), rig, str(points_path)) if has_points else None
    check_wandless(rig, wand, points, str(folder / RIG_FILE), str(wand_path), str(points_path))
    axis_path = folder / AXIS_FILE
    axis = parse_axis_csv(read_csv_text(axis_path), rig, str(axis_path)) if axis_path.is_file() else None
    vertical = _read_vertical(folder, rig)
    held = ((STATIC_FILE, static.camera if static is not None else ()), (AXIS_FILE, axis.camera if axis is not None else ()),
            (f"{vertical.kind}.csv" if vertical is not None else FLOOR_FILE, vertical.camera if vertical is not None else ()))
    _refuse_clash(folder, [name for name, rows in held if len(rows)])
    return Capture(rig=rig, wand=wand, static=static, points=points, axis=axis, vertical=vertical)


def check_capture(capture: Capture, source: str) -> None:
    """Refuse (naming ``source``) a capture that :func:`read_capture` would refuse once written,
    so that an import never writes a capture that ``wandcal calibrate`` then refuses: it is
    written to a temporary folder and read back by the one reader."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="wandcal-check-") as tmp:
        save_capture(tmp, capture)
        try:
            back = read_capture(tmp)
        except CaptureFormatError as exc:
            raise CaptureFormatError(str(exc).replace(tmp + "/", f"{source}: the capture's ").replace(tmp, source)
                                     + "; nothing was written") from None
    if len(back.wand) != len(capture.wand):
        raise CaptureFormatError(f"{source}: {len(capture.wand)} wand rows would read back as {len(back.wand)}; "
                                 "nothing was written")


def check_wandless(rig: Rig, wand: WandObservations, points: PointObservations | None, rig_source: str = RIG_FILE,
                   wand_source: str = WAND_FILE, points_source: str = POINTS_FILE) -> None:
    """A capture without a wand (no ``wand.length_m``) has no wand rows and some point rows."""
    if rig.wand_length is None and len(wand):
        raise CaptureFormatError(
            f"{wand_source}: {len(wand)} wand rows but {rig_source} gives no 'wand.length_m'; "
            "give the wand's marker distance in metres, or remove the wand rows"
        )
    if rig.wand_length is None and (points is None or not len(points)):
        raise CaptureFormatError(
            f"{points_source}: no rows; a capture without a wand needs point tracks in points.csv "
            f"(or give 'wand.length_m' in rig.json and the wand in wand.csv)"
        )


def write_capture(
    folder: str | Path,
    rig: Rig,
    wand: WandObservations,
    static: StaticObservations | None,
    points: PointObservations | None = None,
    axis: AxisObservations | None = None,
    vertical: VerticalObservations | None = None,
) -> None:
    """Write the points level of a capture folder, creating it if needed. wand.csv is always
    written (header only for a capture without a wand); points.csv, axis.csv and floor.csv or
    drop.csv when given."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RIG_FILE).write_text(json.dumps(rig_to_json(rig), indent=2) + "\n")
    ids = rig.ids
    px = lambda uv: (f"{uv[0]:.4f}", f"{uv[1]:.4f}")  # noqa: E731
    write_csv(folder / WAND_FILE, WAND_COLUMNS, ([int(f), ids[c], *px(uv)] for f, c, uv in zip(wand.frame, wand.camera, wand.uv)))
    if static is not None:
        write_csv(folder / STATIC_FILE, STATIC_COLUMNS, ([ids[c], *px(uv)] for c, uv in zip(static.camera, static.uv)))
    if points is not None and points.point is not None:
        write_csv(folder / POINTS_FILE, (*POINTS_COLUMNS, POINT_COLUMN),
                   ([int(f), ids[c], *px(uv), str(n)]
                    for f, c, uv, n in zip(points.frame, points.camera, points.uv, points.point)))
    elif points is not None:
        write_csv(folder / POINTS_FILE, POINTS_COLUMNS,
                   ([int(f), ids[c], *px(uv)] for f, c, uv in zip(points.frame, points.camera, points.uv)))
    if axis is not None:
        write_csv(folder / AXIS_FILE, AXIS_COLUMNS, ([str(r), ids[c], *px(uv)] for r, c, uv in zip(axis.role, axis.camera, axis.uv)))
    if vertical is not None:
        name, columns = (FLOOR_FILE, FLOOR_COLUMNS) if vertical.kind == "floor" else (DROP_FILE, DROP_COLUMNS)
        key = (lambda k: f"p{k + 1}") if vertical.kind == "floor" else int
        write_csv(folder / name, columns,
                   ([key(k), ids[c], *px(uv)] for k, c, uv in zip(vertical.key, vertical.camera, vertical.uv)))


def save_capture(folder: str | Path, capture: Capture) -> None:
    """Write every part of ``capture`` (see :func:`write_capture`)."""
    write_capture(folder, capture.rig, capture.wand, capture.static, capture.points, capture.axis, capture.vertical)


