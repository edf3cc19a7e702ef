"""OpenPTV's calibration and targets read as wandcal cameras seen through a flat window
(calib/refraction.py): ``parameters/ptv.par`` (image size, pixel pitch, refractive indices, glass
thickness), ``camN.ori`` (exterior orientation, principal distance, glass vector), ``camN.addpar``
(lens terms) and ``_targets`` files (detected blob centroids).

OpenPTV's conventions, converted here (docs/conventions.md): lengths in mm; ``dm`` rotates camera
to world with the camera looking along its -z and image y up, so wandcal's ``R = diag(1, -1, -1)
dm^T``; image coordinates are mm from the image centre, ``x_mm = (x_px - imx / 2) pix_x``,
``y_mm = (imy / 2 - y_px) pix_y``, and its pixels count from the top-left pixel's corner, so
``u = x_px - 0.5``. ptv.par's refractive indices are read in OpenPTV's order: n1 the camera's
medium, n2 the glass, n3 the observed medium (liboptv ``read_control_par``); the glass vector
points from the world origin to the glass's face on the observed medium's side, the glass's other
face ``thickness`` further out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wandcal.calib.refraction import FlatWindow
from wandcal.calib.rig import Camera, Rig
from wandcal.capture.rig_file import CaptureFormatError

MM = 1e-3  # OpenPTV's lengths are millimetres
PIXEL_CORNER = 0.5  # OpenPTV's pixel coordinates count from the top-left pixel's corner (docs/conventions.md)
TARGET_COLUMNS = 8  # pnr x y n nx ny sumg tnr
ORI_NUMBERS = 21  # centre 3, angles 3, dm 9, xh yh 2, cc 1, glass vector 3
ADDPAR_NUMBERS = 7  # k1 k2 k3 p1 p2 scx she
FLIP = np.diag([1.0, -1.0, -1.0])  # OpenPTV's camera axes (y up, looking along -z) to OpenCV's


@dataclass(frozen=True)
class ControlPar:
    """ptv.par's numbers: image size (px), pixel pitch (mm), refractive indices, glass thickness (mm)."""

    cameras: int
    imx: int
    imy: int
    pix_x: float
    pix_y: float
    n_air: float
    n_glass: float
    n_water: float
    thickness_mm: float


@dataclass(frozen=True, eq=False)
class OpenPTVCameras:
    """OpenPTV's calibrated cameras in wandcal's terms: rig (pinhole intrinsics, no distortion),
    R (C, 3, 3), t (C, 3) world->camera in metres, each camera's window (metres)."""

    rig: Rig
    R: np.ndarray
    t: np.ndarray
    windows: tuple[FlatWindow, ...]


def _numbers(path: Path, want: int | None = None) -> list[float]:
    try:
        values = [float(v) for v in path.read_text().split()]
    except (OSError, ValueError) as exc:
        raise CaptureFormatError(f"{path}: cannot be read as OpenPTV numbers ({exc}); give the file OpenPTV wrote") from None
    if want is not None and len(values) != want:
        raise CaptureFormatError(f"{path}: holds {len(values)} numbers, an OpenPTV file of this kind {want}")
    return values


def read_control_par(path: Path) -> ControlPar:
    """ptv.par: the camera count, then two image names a camera (at least four cameras' worth,
    OpenPTV's Tcl heritage), then hp_flag, allcam_flag, tiff_flag, imx, imy, pix_x, pix_y,
    chfield, n1, n2, n3, d."""
    try:
        lines = [line.strip() for line in path.read_text().splitlines() if line.strip()]
        cameras = int(lines[0])
        tail = lines[1 + 2 * max(cameras, 4):]
        imx, imy = int(tail[3]), int(tail[4])
        pix_x, pix_y, n1, n2, n3, d = (float(tail[i]) for i in (5, 6, 8, 9, 10, 11))
    except (OSError, ValueError, IndexError) as exc:
        raise CaptureFormatError(f"{path}: not an OpenPTV ptv.par ({exc}); it lists the camera count, two image names a "
                                 "camera, then flags, image size, pixel size, n1, n2, n3 and the glass thickness") from None
    if not all(np.isfinite((pix_x, pix_y, n1, n2, n3, d))) or min(n1, n2, n3) < 1:
        raise CaptureFormatError(f"{path}: the pixel size, the refractive indices (each at least 1) and the glass "
                                 f"thickness must be finite numbers (got {pix_x}, {pix_y} mm; n = {n1}, {n2}, {n3}; "
                                 f"d = {d} mm)")
    if not (cameras > 0 and imx > 0 and imy > 0 and pix_x > 0 and pix_y > 0 and d >= 0):
        raise CaptureFormatError(f"{path}: camera count, image size and pixel size must be positive and the glass "
                                 f"thickness not negative (got {cameras}, {imx}x{imy}, {pix_x}x{pix_y} mm, d = {d} mm)")
    return ControlPar(cameras, imx, imy, pix_x, pix_y, n1, n2, n3, d)


def read_camera(ori: Path, addpar: Path, control: ControlPar, camera_id: str) -> tuple[Camera, np.ndarray, np.ndarray,
                                                                                       FlatWindow]:
    """One camera from its .ori and .addpar: (intrinsics, R (3, 3), t (3,) metres, window)."""
    v = np.array(_numbers(ori, ORI_NUMBERS))
    if not np.isfinite(v).all():
        raise CaptureFormatError(f"{ori}: holds a number that is not finite; give the file OpenPTV wrote")
    centre, dm, (xh, yh), cc, glass = v[0:3], v[6:15].reshape(3, 3), v[15:17], v[17], v[18:21]
    k1, k2, k3, p1, p2, scx, she = _numbers(addpar, ADDPAR_NUMBERS)
    if any((k1, k2, k3, p1, p2, she)) or scx != 1:
        raise CaptureFormatError(f"{addpar}: OpenPTV's lens terms (k1 k2 k3 p1 p2 = {k1} {k2} {k3} {p1} {p2}, scale {scx}, "
                                 f"shear {she}) are not converted; only a distortion-free camera (zeros, scale 1) is read")
    if not (cc > 0 and np.linalg.norm(glass) > 0):
        raise CaptureFormatError(f"{ori}: the principal distance must be positive and the glass vector non-zero "
                                 f"(got cc = {cc} mm, glass {glass.tolist()})")
    f = np.array([cc / control.pix_x, cc / control.pix_y])
    K = np.array([[f[0], 0.0, control.imx / 2 + xh / control.pix_x - PIXEL_CORNER],
                  [0.0, f[1], control.imy / 2 - yh / control.pix_y - PIXEL_CORNER], [0.0, 0.0, 1.0]])
    u, _, vt = np.linalg.svd(dm)  # the nearest rotation: the file prints dm to 7 digits, orthonormal to ~1e-7
    R = FLIP @ (u @ vt).T
    t = -R @ (centre * MM)
    distance = float(np.linalg.norm(glass))
    window = FlatWindow(glass / distance, distance * MM, control.thickness_mm * MM,
                        control.n_air, control.n_glass, control.n_water)
    return Camera(camera_id, control.imx, control.imy, K, np.zeros(5)), R, t, window


def read_openptv_cameras(control_par: Path, ori: list[Path], addpar: list[Path],
                         ids: list[str] | None = None) -> OpenPTVCameras:
    """Cameras from ptv.par and each camera's .ori and .addpar (in the same order)."""
    control = read_control_par(control_par)
    if len(ori) != len(addpar) or not ori:
        raise CaptureFormatError(f"give one .addpar for each .ori ({len(ori)} .ori, {len(addpar)} .addpar)")
    ids = ids or [f"cam{i + 1}" for i in range(len(ori))]
    read = [read_camera(o, a, control, name) for o, a, name in zip(ori, addpar, ids)]
    return OpenPTVCameras(Rig(tuple(r[0] for r in read), None), np.stack([r[1] for r in read]),
                          np.stack([r[2] for r in read]), tuple(r[3] for r in read))


def read_targets(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A ``_targets`` file: (uv (N, 2) wandcal pixels, tnr (N,) OpenPTV's correspondence number, -1 none).
    The first line is the count; each row ``pnr x y n nx ny sumg tnr``."""
    try:
        text = path.read_text().split("\n", 1)
        count = int(text[0])
        rows = np.loadtxt(text[1].splitlines(), ndmin=2) if count else np.zeros((0, TARGET_COLUMNS))
    except (OSError, ValueError, IndexError) as exc:
        raise CaptureFormatError(f"{path}: not an OpenPTV _targets file ({exc}); its first line is the count, then "
                                 "one row 'pnr x y n nx ny sumg tnr' a target") from None
    if rows.shape != (count, TARGET_COLUMNS):
        raise CaptureFormatError(f"{path}: announces {count} targets of {TARGET_COLUMNS} columns but holds "
                                 f"{rows.shape[0]} rows of {rows.shape[1] if rows.ndim == 2 else 0}")
    if not np.isfinite(rows).all() or (len(rows) and np.abs(rows[:, 7]).max() > 2**53):
        raise CaptureFormatError(f"{path}: holds a number that is not finite, or a correspondence number out of range; "
                                 "give the file OpenPTV wrote")
    return rows[:, 1:3] - PIXEL_CORNER, rows[:, 7].astype(np.int64)
