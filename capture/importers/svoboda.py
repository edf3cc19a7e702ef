"""A MultiCamSelfCal (Svoboda et al. 2005) folder as a capture without a wand.

Files (whitespace-separated text):

| file | holds |
|---|---|
| ``points.dat`` | 3 rows per camera (u, v, 1), one column per frame; NaN or 0 where unseen |
| ``IdMat.dat`` | one row per camera, one column per frame: 1 seen, 0 not (the authoritative mask) |
| ``Res.dat`` | one row per camera: image width and height, pixels |
| ``camera_order.txt`` | optional: the cameras' names, one per row (else ``cam1..camN``) |
| ``<basename>N.rad`` | optional: camera N's Bouguet intrinsics ``K11 = ...`` .. ``K33``, ``kc1..kc4`` (or ``kc5``) |

The one bright point seen in a frame is one single-point track: ``points.csv`` frame = column
index (0-based). Pixels are top-left, y down, as in OpenCV (Flydra's detections and Bouguet's
toolbox both put the centre of the top-left pixel at (0, 0)); they are taken as they are.
Bouguet's ``kc`` is OpenCV's ``[k1, k2, p1, p2, k3]``. ``<basename>`` is the ``Basename:`` of
``multicamselfcal.cfg`` when present, else ``basename``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, PointObservations, Rig, WandObservations
from wandcal.capture.folder import Capture, CaptureFormatError
from wandcal.capture.importers.dltdv import read_text
from wandcal.capture.importers.summary import Imported

CONFIG_FILE = "multicamselfcal.cfg"
DEFAULT_BASENAME = "basename"
MAX_BASENAME = 200  # with "N.rad" it stays under the 255 bytes a file name may have
RAD_KEY = re.compile(r"^\s*(K[1-3][1-3]|kc[1-5])\s*=\s*(\S+)\s*$")


def read_svoboda(folder: str | Path, focal_px: float | None = None) -> Imported:
    """Import a MultiCamSelfCal folder.

    Args:
        focal_px: focal length in pixels for cameras without a ``.rad`` file (principal point at
            the image centre, no distortion); without it every camera needs its ``.rad``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureFormatError(f"{folder}: not a folder; give a MultiCamSelfCal folder with points.dat, IdMat.dat "
                                 "and Res.dat")
    res = _matrix(folder / "Res.dat", "image sizes (width height per camera)")
    if res.ndim != 2 or res.shape[1] < 2 or np.any(res[:, :2] <= 0) or np.any(res[:, :2] != np.round(res[:, :2])):
        raise CaptureFormatError(f"{folder / 'Res.dat'}: each row must be a camera's width and height in whole pixels")
    n = len(res)
    ids = _camera_names(folder, n)
    ident = _matrix(folder / "IdMat.dat", "visibility matrix (one row per camera)")
    if ident.shape[0] != n or not np.all(np.isin(ident, (0, 1))):
        raise CaptureFormatError(f"{folder / 'IdMat.dat'}: {ident.shape[0]} rows of 0/1 expected {n}, one per camera "
                                 "in Res.dat")
    pts = _matrix(folder / "points.dat", "points (3 rows per camera: u, v, 1)")
    if pts.shape != (3 * n, ident.shape[1]):
        raise CaptureFormatError(f"{folder / 'points.dat'}: shape {pts.shape[0]}x{pts.shape[1]}, expected "
                                 f"{3 * n}x{ident.shape[1]} (3 rows per camera of Res.dat, one column per frame of "
                                 "IdMat.dat)")
    uv = pts.reshape(n, 3, -1)[:, :2]
    seen = ident.astype(bool)
    bad = seen & ~np.all(np.isfinite(uv), axis=1)
    if bad.any():
        c, f = np.argwhere(bad)[0]
        raise CaptureFormatError(f"{folder / 'points.dat'}: camera {ids[c]} frame {f} (column {f + 1}) is marked seen "
                                 "in IdMat.dat but its point is not a number; fix IdMat.dat or points.dat")
    notes, assumed = [], []
    cameras = []
    basename = _basename(folder)
    for c in range(n):
        w, h = int(res[c, 0]), int(res[c, 1])
        rad = folder / f"{basename}{c + 1}.rad"
        if rad.is_file():
            K, dist = _read_rad(rad)
        elif focal_px is not None:
            K = np.array([[focal_px, 0, (w - 1) / 2], [0, focal_px, (h - 1) / 2], [0, 0, 1.0]])
            dist = np.zeros(5)
            assumed.append(ids[c])
        else:
            raise CaptureFormatError(f"{rad}: not found; give every camera's intrinsics as {basename}N.rad, or "
                                     "--focal-px F to assume a focal length, a centred principal point and no distortion")
        try:
            cameras.append(Camera(id=ids[c], width=w, height=h, K=K, dist=dist))
        except CalibrationError as exc:
            raise CaptureFormatError(f"{rad}: {exc}") from None
    if assumed:
        notes.append(f"no {basename}N.rad for {', '.join(assumed)}: assumed f = {focal_px:g} px (--focal-px), the "
                     "principal point at the image centre and no distortion")
    cam_idx, frame = np.nonzero(seen)
    order = np.lexsort((cam_idx, frame))
    cam_idx, frame = cam_idx[order], frame[order]
    points = PointObservations(frame, cam_idx, uv[cam_idx, :, frame])
    views = seen.sum(axis=0)
    if (views == 1).any():
        notes.append(f"{int((views == 1).sum())} frames seen by one camera only (kept; they constrain nothing)")
    notes.append("no wand: the calibration has no metric scale (rig.json has no 'wand')")
    if (folder / "original_cam_centers.dat").is_file():
        notes.append("original_cam_centers.dat (earlier camera centres for Align-Existing) is not imported")
    try:
        rig = Rig(tuple(cameras), None)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{folder / 'Res.dat'}: {exc}") from None
    wand = WandObservations(np.zeros(0), np.zeros(0), np.zeros((0, 2)))
    return Imported(Capture(rig=rig, wand=wand, static=None, points=points), str(folder), tuple(notes))


def _matrix(path: Path, what: str) -> np.ndarray:
    text = read_text(path, f"MultiCamSelfCal {what}")
    try:
        rows = [[float(x) for x in line.split()] for line in text.splitlines() if line.strip()]
    except ValueError as exc:
        raise CaptureFormatError(f"{path}: not whitespace-separated numbers ({exc}); it should hold the {what}") from None
    lengths = {len(r) for r in rows}
    if not rows or len(lengths) != 1:
        raise CaptureFormatError(f"{path}: rows of unequal length or no rows; it should hold the {what}")
    return np.array(rows, dtype=float)


def _camera_names(folder: Path, n: int) -> list[str]:
    path = folder / "camera_order.txt"
    if not path.is_file():
        return [f"cam{c + 1}" for c in range(n)]
    names = [line.strip() for line in read_text(path, "camera names").splitlines() if line.strip()]
    if len(names) != n or len(set(names)) != n:
        raise CaptureFormatError(f"{path}: {len(names)} names (unique: {len(set(names))}), expected {n} unique names, one "
                                 "per camera of Res.dat")
    return names


def _basename(folder: Path) -> str:
    cfg = folder / CONFIG_FILE
    if cfg.is_file():
        for line in read_text(cfg, "MultiCamSelfCal settings").splitlines():
            key, _, value = line.partition(":")
            if key.strip().lower() == "basename" and value.strip():
                name = value.strip()
                if len(name) > MAX_BASENAME or any(c in name for c in "/\\\0"):
                    raise CaptureFormatError(f"{cfg}: Basename {name[:40]!r} is not a plain file name (no folders, at "
                                             f"most {MAX_BASENAME} characters); give the start of the .rad files' names")
                return name
    return DEFAULT_BASENAME


def _read_rad(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """K (3, 3) and OpenCV dist (5,) from a Bouguet ``.rad`` file."""
    values = {}
    for line_no, line in enumerate(read_text(path, "camera intrinsics (.rad)").splitlines(), start=1):
        if not line.strip():
            continue
        m = RAD_KEY.match(line)
        if not m:
            raise CaptureFormatError(f"{path} line {line_no}: expected 'Kij = number' or 'kcN = number', got {line!r}")
        try:
            values[m.group(1)] = float(m.group(2))
        except ValueError:
            raise CaptureFormatError(f"{path} line {line_no}: {m.group(2)!r} is not a number") from None
    missing = [f"K{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3) if f"K{i}{j}" not in values]
    if missing:
        raise CaptureFormatError(f"{path}: no {', '.join(missing)}; a .rad file gives K11..K33 and kc1..kc4")
    K = np.array([[values[f"K{i}{j}"] for j in (1, 2, 3)] for i in (1, 2, 3)])
    dist = np.array([values.get(f"kc{k}", 0.0) for k in range(1, 6)])
    return K, dist
