"""easyWand sessions as captures: the saved ``*_easyWandData.mat`` or easyWand's input files.

Field by field mapping and pixel conventions: docs/import.md. In short: cameras ``cam1..camN``
from the profile fields (``--intrinsics optimised``, the default, takes ``focalLengths``,
``principalPoints`` and ``nlin``, which easyWand's final result used; ``profile`` takes the
starting estimates ``estFocalLengths``, ``pp_est`` and ``nlin_est``), ``wandPts`` rows as wand
frames (row index = frame), ``backgroundPts`` rows as single-point frames from
:func:`wandcal.capture.importers.dltdv.first_free_frame` on, and ``axisPts`` as axis points when they are
1-4 static points (roles from their count, checked against easyWand's own ``axisXYZ5``); a
gravity recording (``gravityFreq`` set) is not an axis and is left out.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wandcal.calib.rig import AXIS_ROLES, Camera, Rig, WandObservations
from wandcal.capture.folder import Capture, CaptureFormatError
from wandcal.capture.importers.dltdv import (
    AXIS_ROLES_BY_COUNT,
    XyTable,
    axis_from_points,
    camera_from_y_up,
    check_inside,
    first_free_frame,
    parse_profile,
    parse_xypts,
    points_from_table,
    read_text,
    wand_from_table,
)
from wandcal.capture.importers.summary import Imported

STRUCT = "easyWandData"
INTRINSICS = {  # --intrinsics: (focal lengths, principal points y up, distortion) fields
    "optimised": ("focalLengths", "principalPoints", "nlin"),
    "profile": ("estFocalLengths", "pp_est", "nlin_est"),
}
NOT_USED = ("easyWand's own results (coefs, DLT*, sba_R, sba_tv, rotationMatrices, translationVector, "
            "ptMatu, dDLT, wandScore) are not imported")
AXIS_ON_AXIS_TOL = 1e-6  # axisXYZ5 puts reference points exactly on the axes; off-axis parts are rounding


def read_easywand_mat(path: str | Path, intrinsics: str = "optimised", height: int | None = None) -> Imported:
    """Import an easyWand session saved by easyWand 5 (``*_easyWandData.mat``).

    Args:
        intrinsics: ``optimised`` (what easyWand's final result used) or ``profile`` (the
            camera profile's starting estimates).
        height: image height in pixels for every camera, overriding ``imageHeight``.
    """
    if intrinsics not in INTRINSICS:
        raise CaptureFormatError(f"--intrinsics must be one of {', '.join(INTRINSICS)}, not {intrinsics!r}")
    path = Path(path)
    ew = _load_struct(path)
    n = int(_ints(ew, "nCams", path, 1)[0])
    f_field, pp_field, dist_field = INTRINSICS[intrinsics]
    focal = _floats(ew, f_field, path, n)
    pp = _floats(ew, pp_field, path, 2 * n).reshape(n, 2)
    dist = _floats(ew, dist_field, path, 5 * n).reshape(n, 5)
    widths = _ints(ew, "imageWidth", path, n)
    heights = np.full(n, int(height)) if height else _ints(ew, "imageHeight", path, n)
    cameras = [
        camera_from_y_up(f"cam{c + 1}", focal[c], widths[c], heights[c], pp[c, 0], pp[c, 1], dist[c],
                         f"{path}: {STRUCT} camera {c + 1} ({f_field}, {pp_field}, {dist_field})")
        for c in range(n)
    ]
    wand_pts = _table(ew, "wandPts", path, n, 4 * n)
    background = _table(ew, "backgroundPts", path, n)
    if wand_pts is None and background is None:
        raise CaptureFormatError(f"{path}: {STRUCT}.wandPts and backgroundPts are both empty; this session has no "
                                 "points to import")
    wand_length = _floats(ew, "wandLen", path, 1)[0] if wand_pts is not None else None
    notes = [f"intrinsics: {intrinsics} ({f_field}, {pp_field}, {dist_field})"]
    axis = None
    axis_pts = _table(ew, "axisPts", path, n, 2 * n)
    if axis_pts is not None:
        axis, note = _axis(ew, axis_pts, cameras, path)
        notes.append(note)
    marked = _marked(ew)
    if marked:
        notes.append(marked)
    last = len(wand_pts.values) - 1 if wand_pts is not None else -1
    imported = _imported(cameras, wand_length, wand_pts, background, axis, last,
                         f"{path} ({STRUCT}, easyWand {getattr(ew, 'version', '?')})", notes)
    return Imported(imported.capture, imported.source, imported.notes + (NOT_USED,))


def read_easywand_files(wand_csv: str | Path | None, profile: str | Path, wand_length_m: float | None,
                        background: str | Path | None = None, axis: str | Path | None = None,
                        height: int | None = None) -> Imported:
    """Import easyWand's input files: wand points (two tracks), a camera profile, and the
    optional background (unpaired) and axis points, all in DLTdv's y-up layout
    (:mod:`wandcal.capture.importers.dltdv`). Without ``wand_csv`` (a background-only session)
    the capture has no wand and no metric scale."""
    cameras = parse_profile(read_text(profile, "camera profile"), str(profile), height)
    n = len(cameras)
    wand = None
    if wand_csv is not None:
        wand = parse_xypts(read_text(wand_csv, "wand points CSV"), str(wand_csv), n, 4 * n)
    if wand is None and background is None:
        raise CaptureFormatError(f"{profile}: give the wand points (--wand) or the background points (--background); "
                                 "there is nothing to calibrate from")
    bg = None
    if background is not None:
        bg = parse_xypts(read_text(background, "background points CSV"), str(background), n)
    notes = []
    axis_obs = None
    if axis is not None:
        table = parse_xypts(read_text(axis, "axis points CSV"), str(axis), n, 2 * n)
        axis_obs, note = axis_from_table(table, cameras)
        notes.append(note)
    return _imported(cameras, wand_length_m, wand, bg, axis_obs, int(wand.frames.max()) if wand is not None else -1,
                     ", ".join(str(p) for p in (wand_csv, profile, background, axis) if p), notes)


def read_easywand(wand_csv: str | Path, profile: str | Path, wand_length_m: float,
                  height: int | None = None) -> Capture:
    """A points-level capture (no static object) from easyWand's wand CSV and profile."""
    return read_easywand_files(wand_csv, profile, wand_length_m, height=height).capture


def axis_from_table(table: XyTable, cameras: list[Camera]) -> tuple[object, str]:
    """Axis observations from a reference-points table (one row per point, one track), with a
    note; more than 4 rows is a gravity or plane recording and gives None."""
    rows = table.values[np.any(np.isfinite(table.values), axis=1)]
    if len(rows) not in AXIS_ROLES_BY_COUNT:
        return None, (f"{table.source}: {len(rows)} reference rows are a gravity or plane recording, not 1-4 axis "
                      "points; not imported (wandcal aligns no axes to gravity)")
    roles = AXIS_ROLES_BY_COUNT[len(rows)]
    axis = axis_from_points(rows.reshape(len(rows), len(cameras), 2), roles, cameras)
    return axis, f"{table.source}: {len(rows)} reference points taken as {', '.join(roles)} (by their count)"


def _imported(cameras, wand_length, wand_table: XyTable | None, background: XyTable | None, axis, last_wand_frame: int,
              source: str, notes: list[str]) -> Imported:
    if wand_table is not None:
        check_inside(wand_table.values, cameras, wand_table.source)
        wand, one_end = wand_from_table(wand_table, cameras)
        if one_end.any():
            notes.append("left out camera-frames of the wand with one end only (the other end not digitised): "
                         + ", ".join(f"{c.id} {k}" for c, k in zip(cameras, one_end)))
    if wand_table is None or (not len(wand) and background is not None):
        wand = WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
        wand_length = None
        notes.append("no wand points: background points only, so the calibration has no metric scale")
    points = None
    if background is not None:
        check_inside(background.values, cameras, background.source)
        first = first_free_frame(last_wand_frame)
        points = points_from_table(background, cameras, first)
        above = ", above every wand frame" if wand_length is not None else ""
        notes.append(f"background point r of {background.source} (its source_row or row index, 0-based) is "
                     f"points.csv frame {first} + r{above}")
        if not len(points):
            points = None
    if wand_length is None and points is None:
        raise CaptureFormatError(f"{source}: no wand points and no background point seen; there is nothing to "
                                 "calibrate from")
    try:
        rig = Rig(tuple(cameras), None if wand_length is None else float(wand_length))
    except (ValueError, TypeError) as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None
    return Imported(Capture(rig=rig, wand=wand, static=None, points=points, axis=axis), source, tuple(notes))


def _load_struct(path: Path):
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; give the path of an easyWand session (*_easyWandData.mat)")
    import scipy.io

    try:
        mat = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    except scipy.io.matlab.MatReadError as exc:  # truncated, or a header that lies about its contents
        raise CaptureFormatError(f"{path}: not a complete MATLAB .mat file ({exc}); give the *_easyWandData.mat "
                                 "that easyWand's Save wrote") from None
    except NotImplementedError:
        raise CaptureFormatError(f"{path}: a MATLAB v7.3 (HDF5) file; re-save it in MATLAB with "
                                 f"save(file, '{STRUCT}', '-v7') and import that") from None
    except Exception as exc:  # scipy's parser raises whatever damaged bytes lead it to (zlib.error
        # from corrupted compressed data, struct.error, OverflowError, ...): each means this file is not readable
        raise CaptureFormatError(f"{path}: not a MATLAB .mat file ({type(exc).__name__}: {exc}); give the "
                                 "*_easyWandData.mat that easyWand's Save wrote") from None
    if STRUCT not in mat:
        found = ", ".join(k for k in mat if not k.startswith("__")) or "nothing"
        raise CaptureFormatError(f"{path}: no {STRUCT!r} struct (it holds {found}); this is not an easyWand "
                                 "session: give the *_easyWandData.mat that easyWand's Save wrote")
    ew = mat[STRUCT]
    if not hasattr(ew, "_fieldnames"):
        raise CaptureFormatError(f"{path}: {STRUCT!r} is not a struct; give an easyWand 5 session file")
    return ew


def _field(ew, name: str, path: Path):
    if name not in ew._fieldnames:
        raise CaptureFormatError(f"{path}: {STRUCT} has no field {name!r}; the session is incomplete (save it "
                                 "again from easyWand after computing the calibration)")
    return getattr(ew, name)


def _floats(ew, name: str, path: Path, size: int | None = None) -> np.ndarray:
    value = _field(ew, name, path)
    try:
        arr = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
    except (TypeError, ValueError):
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} is not numeric") from None
    if size is not None and arr.size != size:
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} has {arr.size} values, expected {size} "
                                 "(one or more per camera, nCams cameras)")
    if not np.all(np.isfinite(arr)):
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} holds a non-finite value")
    return arr


def _ints(ew, name: str, path: Path, size: int | None = None) -> np.ndarray:
    arr = _floats(ew, name, path, size)
    if np.any(arr != np.round(arr)) or np.any(arr <= 0):
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} must hold positive whole numbers, got {arr.tolist()}")
    return arr.astype(int)


def _table(ew, name: str, path: Path, n: int, columns: int | None = None) -> XyTable | None:
    """An xypts-layout matrix field as a table (row index = frame), or None when empty."""
    if name not in ew._fieldnames:
        return None
    try:
        arr = np.asarray(getattr(ew, name), dtype=float)
    except (TypeError, ValueError):
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} is not a numeric matrix") from None
    if arr.size == 0:
        return None
    if arr.ndim <= 1:  # squeeze_me turns a single row into a vector, a single value into a scalar
        arr = arr.reshape(1, -1)
    width = arr.shape[1]
    if arr.ndim != 2 or (columns and width != columns) or width % (2 * n):
        raise CaptureFormatError(f"{path}: {STRUCT}.{name} is {arr.shape}, expected "
                                 f"{columns or f'a multiple of {2 * n}'} columns for nCams = {n}")
    arr = arr.copy()
    arr[~np.isfinite(arr)] = np.nan
    return XyTable(np.arange(len(arr), dtype=np.int64), arr, f"{path}: {STRUCT}.{name}")


def _axis(ew, table: XyTable, cameras: list[Camera], path: Path):
    rows = table.values[np.any(np.isfinite(table.values), axis=1)]
    if "gravityFreq" in ew._fieldnames or len(rows) not in AXIS_ROLES_BY_COUNT:
        freq = getattr(ew, "gravityFreq", None)
        return None, (f"axisPts: {len(rows)} frames of a gravity recording"
                      + (f" at {float(freq):g} Hz" if freq is not None else "")
                      + ", not axis points; not imported (wandcal aligns no axes to gravity)")
    roles = AXIS_ROLES_BY_COUNT[len(rows)]
    xyz = np.asarray(getattr(ew, "axisXYZ5", np.zeros(0)), dtype=float).reshape(-1, 3) \
        if "axisXYZ5" in ew._fieldnames else np.zeros((0, 3))
    how = "by their count"
    if len(xyz) == len(rows):
        seen = _roles_from_xyz(xyz)
        if seen is not None and seen != roles:
            roles, how = seen, "from axisXYZ5, where easyWand put them"
        elif seen == roles:
            how = "by their count, as axisXYZ5 confirms"
    axis = axis_from_points(rows.reshape(len(rows), len(cameras), 2), roles, cameras)
    return axis, f"axisPts: {len(rows)} points taken as {', '.join(roles)} ({how})"


def _roles_from_xyz(xyz: np.ndarray) -> tuple[str, ...] | None:
    """Roles of easyWand's final axis points (P, 3) when each lies at the origin or on a positive
    axis, else None."""
    scale = max(float(np.abs(xyz).max()), 1e-12)
    roles = []
    for p in xyz:
        if np.abs(p).max() <= AXIS_ON_AXIS_TOL * scale:
            roles.append("origin")
            continue
        k = int(np.argmax(np.abs(p)))
        off = np.delete(np.abs(p), k)
        if p[k] <= 0 or off.max() > AXIS_ON_AXIS_TOL * scale:
            return None
        roles.append(AXIS_ROLES[1 + k])
    return tuple(roles) if len(set(roles)) == len(roles) else None


def _marked(ew) -> str | None:
    counts = []
    for name, what in (("rmpts", "wand"), ("bkrmpts", "background")):
        if name in ew._fieldnames:
            k = int(np.count_nonzero(np.asarray(getattr(ew, name))))
            if k:
                counts.append(f"{k} {what} ({name})")
    if not counts:
        return None
    return ("easyWand had marked " + " and ".join(counts) + " entries as outliers; they are imported all the "
            "same, wandcal finds its own outliers")
