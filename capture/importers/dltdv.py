"""What easyWand and Argus share with Hedrick's DLTdv: camera profiles, ``xypts`` tables and
y-up pixels.

**Pixels.** DLTdv, easyWand and Argus put the pixel origin at the lower left with y up:
``v_up = H - v_down`` (Hedrick's ``dlt_invert.m`` uses H, not H + 1). The lens model is
Bouguet's / OpenCV's applied in that y-up frame. Flipping y negates the normalised y
coordinate, so the same lens in the y-down frame has ``cy_down = H - cy_up`` and
``[k1, k2, -p1, p2, k3]``: the radial terms are symmetric, and p1 (the coefficient of ``2xy`` in
x and of ``r² + 2y²`` in y) changes sign while p2 does not. The conversion is exact, so raw
pixels are flipped before undistortion (:func:`camera_from_y_up`, :func:`flip_v`).

**Profiles.** One row per camera, space- or comma-separated:
``camera#, f, width, height, cx, cy, AR, k1, k2, t1, t2, k3`` (pixels, principal point y up;
``AR`` is 1: square pixels; rows of 7 numbers have no distortion).

**xypts tables.** One row per frame; for each track (a marker) two columns per camera:
``pt1_cam1_X, pt1_cam1_Y, pt1_cam2_X, ..., pt2_cam1_X, ...`` (Argus names them
``track_cam_1_x``); NaN or empty where not digitised. A wand is two tracks, one per end. A header
row is optional; a first column named ``source_row`` or ``frame`` gives frame numbers, else the
row's index (0-based, header excluded) is its frame.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import AxisObservations, Camera, PointObservations, WandObservations
from wandcal.capture.folder import CaptureFormatError

PROFILE_MIN_COLUMNS = 7  # camera#, f, width, height, cx, cy, AR: no distortion columns
PROFILE_COLUMNS = 12  # ... and k1, k2, t1, t2, k3
FRAME_COLUMN_NAMES = ("source_row", "frame")
# Reference (axis) points by count, DLTdv/easyWand/Argus convention (argus-wand's comment: "One
# point - an origin; Two - origin and +z-axis; Three - origin, +x-axis, +y-axis; Four - origin,
# +x-axis, +y-axis, +z-axis; More - gravity or surface reference points")
AXIS_ROLES_BY_COUNT = {
    1: ("origin",),
    2: ("origin", "+z"),
    3: ("origin", "+x", "+y"),
    4: ("origin", "+x", "+y", "+z"),
}


@dataclass(frozen=True, eq=False)
class XyTable:
    """A parsed xypts table: ``frames`` (R,) int frame numbers, ``values`` (R, C) float, NaN where
    not digitised, C a multiple of 2 x cameras."""

    frames: np.ndarray
    values: np.ndarray
    source: str


def read_text(path: str | Path, what: str) -> str:
    """The text of ``path``; a missing, unreadable or binary file raises CaptureFormatError."""
    path = Path(path)
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; give the path of the {what}")
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CaptureFormatError(f"{path}: not a text file (not UTF-8); give the {what} as text") from None
    except OSError as exc:
        raise CaptureFormatError(f"{path}: cannot be read ({exc.strerror}); give a readable {what}") from None
    if "\0" in text:
        raise CaptureFormatError(f"{path}: holds binary data (NUL bytes); give the {what} as text")
    return text


def camera_from_y_up(cam_id: str, f: float, width: int, height: int, cx: float, cy_up: float,
                     dist_up, where: str, aspect: float = 1.0) -> Camera:
    """A wandcal camera (y down) from DLTdv-style intrinsics with the principal point y up.

    Args:
        f: focal length, pixels; ``fy = f * aspect``.
        cx, cy_up: principal point, pixels, origin lower left, y up.
        dist_up: (5,) ``[k1, k2, p1, p2, k3]`` in the y-up frame (fewer are zero-padded).
        where: the file and line or field, for errors.
    """
    d = np.zeros(5)
    given = np.asarray(dist_up, dtype=float).ravel()[:5]
    d[: len(given)] = given
    dist = np.array([d[0], d[1], 0.0 - d[2], d[3], d[4]])  # y -> -y negates p1 only (module docstring)
    K = np.array([[f, 0.0, cx], [0.0, f * aspect, height - cy_up], [0.0, 0.0, 1.0]])
    try:
        return Camera(id=cam_id, width=int(width), height=int(height), K=K, dist=dist)
    except (CalibrationError, ValueError, OverflowError) as exc:
        raise CaptureFormatError(f"{where}: {exc}") from None


def parse_profile(text: str, source: str, height: int | None = None) -> list[Camera]:
    """Cameras from a DLTdv / easyWand / Argus profile (module docstring); ``height`` overrides
    every row's image height (some profiles carry a wrong one)."""
    cams = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith(("#", "%")):
            continue
        where = f"{source} line {line_no}"
        try:
            v = [float(x) for x in line.replace(",", " ").split()]
        except ValueError:
            raise CaptureFormatError(
                f"{where}: not a profile row of numbers; each row is camera#, f, width, height, cx, cy, AR, "
                "k1, k2, t1, t2, k3"
            ) from None
        if len(v) not in (PROFILE_MIN_COLUMNS, PROFILE_COLUMNS) or not np.all(np.isfinite(v)):
            raise CaptureFormatError(
                f"{where}: {len(v)} numbers; a profile row has {PROFILE_MIN_COLUMNS} or {PROFILE_COLUMNS} finite "
                "numbers (camera#, f, width, height, cx, cy, AR[, k1, k2, t1, t2, k3]); an omnidirectional "
                "(CMei) profile cannot be imported"
            )
        if v[6] <= 0:
            raise CaptureFormatError(f"{where}: aspect ratio (column 7) is {v[6]:g}; it must be positive (usually 1)")
        if v[2] != int(v[2]) or v[3] != int(v[3]):
            raise CaptureFormatError(f"{where}: image width and height (columns 3, 4) must be whole pixels")
        h = int(height) if height else int(v[3])
        cams.append(camera_from_y_up(f"cam{int(v[0])}", v[1], int(v[2]), h, v[4], v[5], v[7:12], where, v[6]))
    if not cams:
        raise CaptureFormatError(f"{source}: no camera rows; a profile has one row per camera")
    ids = [c.id for c in cams]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise CaptureFormatError(f"{source}: camera number {dup[0][3:]} appears twice; number the rows' cameras 1..N")
    return cams


def parse_xypts(text: str, source: str, n_cams: int, columns: int | None = None) -> XyTable:
    """Parse an xypts table for ``n_cams`` cameras (module docstring).

    Args:
        columns: the number of coordinate columns required (4 x cameras for a wand); else any
            multiple of 2 x cameras.
    """
    if source.lower().endswith(".tsv"):
        raise CaptureFormatError(f"{source}: a sparse .tsv table cannot be imported; save the points as a dense "
                                 "-xypts.csv (Argus Clicker's options, 'Save format')")
    try:
        rows = [r for r in csv.reader(io.StringIO(text)) if any(c.strip() for c in r)]
    except csv.Error as exc:
        raise CaptureFormatError(f"{source}: not a CSV table ({exc})") from None
    header = rows[0] if rows and not _numeric(rows[0]) else None
    body = rows[1:] if header else rows
    has_frame = header is not None and header[0].strip().strip('"').lower() in FRAME_COLUMN_NAMES
    frame_column = header[0] if header is not None else ""  # named in messages when has_frame
    first_line = 2 if header else 1
    frames, values = [], []
    width = None
    for k, row in enumerate(body):
        line = first_line + k
        cells = row[1:] if has_frame else row
        if width is None:
            width = len(cells)
            want = f"{columns}" if columns else f"a multiple of {2 * n_cams}"
            if (columns and width != columns) or width == 0 or width % (2 * n_cams):
                raise CaptureFormatError(
                    f"{source} line {line}: {width} coordinate columns, expected {want} for {n_cams} cameras "
                    f"(two per camera and track: pt1_cam1_X, pt1_cam1_Y, pt1_cam2_X, ...); is the profile for these "
                    "cameras?"
                )
        elif len(cells) != width:
            raise CaptureFormatError(f"{source} line {line}: {len(cells)} coordinate columns, the rows above have {width}")
        try:
            values.append([float(c) if c.strip() else np.nan for c in cells])
        except ValueError:
            bad = next(i for i, c in enumerate(cells) if c.strip() and not _is_float(c))
            raise CaptureFormatError(
                f"{source} line {line}, column {bad + 1 + has_frame}: {cells[bad]!r} is not a number "
                "(write NaN or leave empty where a point was not digitised)"
            ) from None
        if has_frame:
            if not _is_float(row[0]) or float(row[0]) != int(float(row[0])):
                raise CaptureFormatError(f"{source} line {line}, column 1 ({frame_column}): {row[0]!r} is not a frame number")
            frames.append(int(float(row[0])))
        else:
            frames.append(k)
    if not values:
        raise CaptureFormatError(f"{source}: no rows of points")
    table = np.array(values, dtype=float)
    table[np.isinf(table)] = np.nan
    return XyTable(np.array(frames, dtype=np.int64), table, source)


def flip_v(uv_up: np.ndarray, height: int) -> np.ndarray:
    """(M, 2) y-up pixels -> y-down pixels, ``v_down = H - v_up`` (module docstring)."""
    out = np.array(uv_up, dtype=float).reshape(-1, 2)
    out[:, 1] = height - out[:, 1]
    return out


def check_inside(values: np.ndarray, cameras: list[Camera], source: str) -> None:
    """Refuse points far outside their camera's image: a wrong image height or a wrong profile.

    Args:
        values: (R, C) an xypts table, C a multiple of 2 x cameras, y-up pixels.
    """
    n = len(cameras)
    xy = values.reshape(len(values), -1, n, 2)
    for c, cam in enumerate(cameras):
        u, v = xy[:, :, c, 0], xy[:, :, c, 1]
        if np.any(np.isfinite(v)) and (np.nanmax(v) > cam.height + 1 or np.nanmin(v) < -1):
            raise CaptureFormatError(
                f"{source}: camera {cam.id} has points at v = {np.nanmin(v):.1f}..{np.nanmax(v):.1f} px (y up), "
                f"outside its {cam.height} px high image; the image height is wrong (give --height H) or the "
                "points belong to other cameras"
            )
        if np.any(np.isfinite(u)) and (np.nanmax(u) > cam.width + 1 or np.nanmin(u) < -1):
            raise CaptureFormatError(
                f"{source}: camera {cam.id} has points at u = {np.nanmin(u):.1f}..{np.nanmax(u):.1f} px, outside its "
                f"{cam.width} px wide image; check the profile's width and the camera order"
            )


def wand_from_table(table: XyTable, cameras: list[Camera]) -> tuple[WandObservations, np.ndarray]:
    """Wand blobs from a two-track xypts table (track 1 and track 2 are the two ends).

    Returns the observations (y-down pixels; a camera-frame only when both ends were seen) and
    (N,) the number of camera-frames per camera with one end only, which are left out.
    """
    n = len(cameras)
    xy = table.values.reshape(len(table.values), 2, n, 2)  # row, end, camera, (u, v)
    seen = np.all(np.isfinite(xy), axis=3)
    both = seen.all(axis=1)
    frames, cams, uv = [], [], []
    for c, cam in enumerate(cameras):
        rows = np.flatnonzero(both[:, c])
        for end in range(2):
            frames.append(table.frames[rows])
            cams.append(np.full(len(rows), c))
            uv.append(flip_v(xy[rows, end, c], cam.height))
    order = np.lexsort((np.concatenate(cams), np.concatenate(frames)))
    obs = WandObservations(np.concatenate(frames)[order], np.concatenate(cams)[order], np.concatenate(uv)[order])
    return obs, (seen.sum(axis=1) == 1).sum(axis=0)


def points_from_table(table: XyTable, cameras: list[Camera], first_frame: int) -> PointObservations:
    """Single-point observations from an xypts table of one or more tracks (unpaired points).

    Track t's row with frame number r becomes the point of frame ``first_frame + t * span + r``,
    ``span`` being one more than the table's largest frame number, so that no two points (and no
    wand frame below ``first_frame``) share a frame.
    """
    n = len(cameras)
    xy = table.values.reshape(len(table.values), -1, n, 2)  # row, track, camera, (u, v)
    span = int(table.frames.max()) + 1
    frames, cams, uv = [], [], []
    for t in range(xy.shape[1]):
        for c, cam in enumerate(cameras):
            rows = np.flatnonzero(np.all(np.isfinite(xy[:, t, c]), axis=1))
            frames.append(first_frame + t * span + table.frames[rows])
            cams.append(np.full(len(rows), c))
            uv.append(flip_v(xy[rows, t, c], cam.height))
    frame, camera = np.concatenate(frames), np.concatenate(cams)
    order = np.lexsort((camera, frame))
    return PointObservations(frame[order], camera[order], np.concatenate(uv)[order])


def first_free_frame(last_wand_frame: int) -> int:
    """The frame number where other points start: the smallest power of ten above every wand
    frame (1000 after wand frames 0..101), so the two never collide and are told apart at a glance."""
    return 10 ** len(str(max(int(last_wand_frame), 0) + 1)) if last_wand_frame >= 0 else 0


def axis_from_points(xy_up: np.ndarray, roles: tuple[str, ...], cameras: list[Camera]) -> AxisObservations:
    """Axis observations from (P, N, 2) y-up pixels of P reference points in N cameras, NaN where
    unseen; ``roles`` (P,) names each point."""
    role, cam, uv = [], [], []
    for p, name in enumerate(roles):
        for c, camera in enumerate(cameras):
            if np.all(np.isfinite(xy_up[p, c])):
                role.append(name)
                cam.append(c)
                uv.append(flip_v(xy_up[p, c], camera.height)[0])
    return AxisObservations(np.array(role, dtype=str), np.array(cam, dtype=np.int64), np.array(uv).reshape(-1, 2))


def _numeric(row: list[str]) -> bool:
    return all(_is_float(x) for x in row if x.strip())


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
