"""Import easyWand / DLTdv sessions (wand points and camera profiles) as a points-level capture.

easyWand's pixels have their origin at the lower left with y up. The lens model is OpenCV's
applied in that frame; with radial-only distortion (p1 = p2 = 0, as easyWand uses) it is
symmetric about the principal point, so raw pixels convert as ``v_down = H - v_up`` with the
principal point mapped the same way (Hedrick's ``dlt_invert.m`` uses H, not H + 1).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from calib.rig import Camera, Rig, WandObservations
from capture.folder import Capture, CaptureFormatError


def read_profile(path: str | Path, height: int | None = None) -> list[Camera]:
    """Cameras from an easyWand profile: rows ``cam#, f, width, height, ppx, ppy, type[, k1, k2,
    t1, t2, k3]`` (y-up principal point). ``height`` overrides the profile's (some profiles
    carry a wrong one)."""
    cams = []
    for line_no, line in enumerate(Path(path).read_text().splitlines(), start=1):
        if not line.strip():
            continue
        v = [float(x) for x in line.replace(",", " ").split()]
        if len(v) < 7:
            raise CaptureFormatError(f"{path} line {line_no}: an easyWand profile row needs at least 7 numbers")
        f, w, h, ppx, ppy = v[1], int(v[2]), int(height or v[3]), v[4], v[5]
        k1, k2, t1, t2, k3 = (v[7:12] + [0.0] * 5)[:5]
        if t1 or t2:
            raise CaptureFormatError(f"{path} line {line_no}: tangential distortion cannot be flipped to y-down exactly")
        K = np.array([[f, 0, ppx], [0, f, h - ppy], [0, 0, 1.0]])
        cams.append(Camera(id=f"cam{int(v[0])}", width=w, height=h, K=K, dist=np.array([k1, k2, 0.0, 0.0, k3])))
    return cams


def read_wand_points(path: str | Path, cameras: list[Camera]) -> WandObservations:
    """Wand points in easyWand's layout ``pt1_cam1_X, pt1_cam1_Y, ..., pt2_camN_Y`` (an optional
    leading ``source_row`` column is the frame number), NaN where not digitised."""
    n = len(cameras)
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    header = rows[0] if rows and not _numeric(rows[0]) else None
    body = rows[1:] if header else rows
    has_frame = header is not None and header[0].strip().lower() in ("source_row", "frame")
    frames, cams, uv = [], [], []
    for k, row in enumerate(body):
        values = np.array([float(x) if x.strip() else np.nan for x in row], dtype=float)
        frame = int(values[0]) if has_frame else k
        pts = values[1:] if has_frame else values
        if len(pts) != 4 * n:
            raise CaptureFormatError(f"{path} row {k + 1}: expected {4 * n} coordinates for {n} cameras, got {len(pts)}")
        for end in range(2):
            for c, cam in enumerate(cameras):
                u, v = pts[end * 2 * n + 2 * c : end * 2 * n + 2 * c + 2]
                if np.isfinite(u) and np.isfinite(v):
                    frames.append(frame)
                    cams.append(c)
                    uv.append((u, cam.height - v))
    return WandObservations(np.array(frames), np.array(cams), np.array(uv).reshape(-1, 2))


def read_easywand(wand_csv: str | Path, profile: str | Path, wand_length_m: float, height: int | None = None) -> Capture:
    """A points-level capture (no static object) from easyWand files."""
    cameras = read_profile(profile, height)
    return Capture(rig=Rig(tuple(cameras), wand_length_m), wand=read_wand_points(wand_csv, cameras), static=None)


def _numeric(row: list[str]) -> bool:
    try:
        [float(x) for x in row if x.strip()]
    except ValueError:
        return False
    return True
