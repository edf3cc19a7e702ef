"""DLT coefficients: 11 per camera, as DLTdv, easyWand and Argus read and write them.

``u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)``, ``v`` likewise with L5..L8:
the pinhole projection ``K [R | t]`` scaled so that its last entry, L12, is 1. The division
needs the world origin off every camera's focal plane (``t_z != 0``); wandcal's world frames
put it inside the volume (calib/start/world.py). DLT has no lens distortion: points are undistorted
before they meet the coefficients. Conventions: docs/formats.md.
"""

from __future__ import annotations

import io

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig
from wandcal.capture.formats.cameras import (
    BOTTOM_LEFT,
    TOP_LEFT,
    PosedCameras,
    check_unit,
    posed_cameras,
    read_cameras,
)

DLT_COEFFICIENTS = 11
DLT_ORIGINS = (BOTTOM_LEFT, TOP_LEFT)  # DLTdv, easyWand and Argus: y up from the bottom edge
# |t_z| below this share of the camera's distance from the world origin: the origin is in the
# focal plane and L12 = 1 cannot be had (float rounding alone is ~1e-16 of it)
FOCAL_PLANE_TOL = 1e-9


def _flip(height: float) -> np.ndarray:
    """(3, 3) y-down pixels <-> y-up pixels, ``v' = H - v`` (its own inverse; docs/import.md)."""
    return np.array([[1.0, 0.0, 0.0], [0.0, -1.0, float(height)], [0.0, 0.0, 1.0]])


def dlt_coefficients(K: np.ndarray, R: np.ndarray, t: np.ndarray, height: int | None = None,
                     camera: str = "the camera") -> np.ndarray:
    """(11,) DLT coefficients L1..L11 of the pinhole camera ``K [R | t]`` (no lens distortion).

    Args:
        K: (3, 3) pixels; R: (3, 3) world->camera; t: (3,) in the unit the DLT is wanted in.
        height: with it, v is measured up from the bottom edge (``v' = height - v``, DLTdv /
            easyWand / Argus) instead of down from the top.
        camera: the camera's name, for the error.
    """
    P = K @ np.hstack([R, t[:, None]])
    if height is not None:
        P = _flip(height) @ P
    if abs(P[2, 3]) <= FOCAL_PLANE_TOL * max(float(np.linalg.norm(t)), 1e-300):
        raise CalibrationError(
            f"{camera}: the world origin lies in its focal plane (depth {t[2]:.3g}), so DLT cannot normalise L12 = 1; "
            "recalibrate with this wandcal (a wand-only world now has its origin inside the wand volume), or give "
            "axis points or an L-frame whose origin the cameras look at"
        )
    return (P / P[2, 3]).ravel()[:DLT_COEFFICIENTS]


def to_dlt_csv(result: dict, rig: Rig | None = None, unit: str = "m", origin: str = BOTTOM_LEFT) -> str:
    """DLT coefficients as CSV: 11 rows, one column per camera in the result's order, no header
    (the layout DLTdv and Argus read), lengths in ``unit``, pixels from the ``origin`` corner."""
    if origin not in DLT_ORIGINS:
        raise CalibrationError(f"origin must be one of {', '.join(DLT_ORIGINS)}, not {origin!r}")
    scale = check_unit(unit)
    pc = posed_cameras(result, rig)
    cols = [
        dlt_coefficients(cam.K, pc.R[i], pc.t[i] * scale, cam.height if origin == BOTTOM_LEFT else None, f"camera {cam.id!r}")
        for i, cam in enumerate(pc.cameras)
    ]
    table = np.stack(cols, axis=1)
    return "\n".join(",".join(repr(float(v)) for v in row) for row in table) + "\n"


def read_dlt_csv(text: str, sizes: list[tuple[int, int]], origin: str = BOTTOM_LEFT, unit: str = "m",
                 ids: list[str] | None = None, source: str = "DLT CSV") -> PosedCameras:
    """DLT coefficients (11 rows, a column per camera) back as pinhole cameras.

    Args:
        sizes: (width, height) of each camera's image, pixels: DLT does not hold them, and a
            bottom-left origin needs the height.
        origin, unit: the pixel origin and length unit the coefficients were written with.
        ids: camera names (default ``cam1``...).

    Each column is decomposed (RQ) into ``K`` (upper triangular: a general DLT has skew and
    unequal focal lengths), ``R`` and ``t``; the distortion is zero.
    """
    if origin not in DLT_ORIGINS:
        raise CalibrationError(f"origin must be one of {', '.join(DLT_ORIGINS)}, not {origin!r}")
    scale = check_unit(unit)
    try:
        table = np.loadtxt(io.StringIO(text), delimiter=",", ndmin=2)
    except ValueError as exc:
        raise CalibrationError(f"{source}: not a table of numbers ({exc})") from None
    if table.shape[0] != DLT_COEFFICIENTS or not np.all(np.isfinite(table)):
        raise CalibrationError(f"{source}: want {DLT_COEFFICIENTS} rows of finite coefficients, one column per "
                               f"camera; got {table.shape[0]} rows")
    n = table.shape[1]
    if len(sizes) != n:
        raise CalibrationError(f"{source}: {n} cameras (columns) but {len(sizes)} image sizes were given")
    ids = list(ids) if ids is not None else [f"cam{c + 1}" for c in range(n)]
    cams, R, t = [], [], []
    for c in range(n):
        width, height = sizes[c]
        P = np.append(table[:, c], 1.0).reshape(3, 4)
        if origin == BOTTOM_LEFT:
            P = _flip(height) @ P
        K, Rc, tc = decompose_projection(P, f"{source}: camera {ids[c]!r}")
        cams.append(Camera(ids[c], width, height, K, np.zeros(5)))
        R.append(Rc)
        t.append(tc / scale)
    return read_cameras(cams, R, t, source)


def decompose_projection(P: np.ndarray, where: str = "camera") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P = s K [R | t]`` (3, 4) -> K (3, 3) with a positive diagonal and ``K[2, 2] = 1``, R
    (3, 3) a rotation, t (3,): the RQ decomposition of its left 3x3 block, with the overall sign
    chosen so that R is proper (the scene in front of the camera)."""
    M = P[:, :3]
    det = np.linalg.det(M)
    if not np.isfinite(det) or abs(det) < 1e-300:
        raise CalibrationError(f"{where}: the coefficients' 3x3 block is singular; this is not a camera's DLT")
    if det < 0:  # P = s K [R | t] with s < 0: the same camera, written with the other sign
        P, M = -P, -M
    rev = np.eye(3)[::-1]
    Q, U = np.linalg.qr((rev @ M).T)
    K = rev @ U.T @ rev
    R = rev @ Q.T
    signs = np.diag(np.sign(np.diag(K)))
    K, R = K @ signs, signs @ R
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t
