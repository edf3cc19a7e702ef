"""Posed cameras: the common ground of every exchange format, and the checks when they are read.

Each format writes a ``wandcal-result/1`` document's cameras (:func:`posed_cameras`) and reads its
own text back into :class:`PosedCameras` (:func:`read_cameras`); docs/formats.md states every
format's conventions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import PINHOLE, Camera, Rig

UNITS = {"m": 1.0, "mm": 1000.0}
TOP_LEFT, BOTTOM_LEFT = "top-left", "bottom-left"
ROTATION_TOLERANCE = 1e-4  # |R^T R - I| of a rotation read from text: five printed digits pass, a non-rotation not


@dataclass(frozen=True, eq=False)
class PosedCameras:
    """Cameras with their poses, as written to or read from a format.

    cameras: intrinsics (pixels, top-left origin, OpenCV lens model); R: (N, 3, 3) and t: (N, 3)
    world->camera, ``x_cam = R @ x_world + t``, metres; rms_px: (N,) reprojection RMS, pixels,
    NaN where unknown; observations: (N,) observation counts, -1 where unknown.
    """

    cameras: tuple[Camera, ...]
    R: np.ndarray
    t: np.ndarray
    rms_px: np.ndarray
    observations: np.ndarray

    @property
    def centers(self) -> np.ndarray:
        """(N, 3) camera centres in the world, metres."""
        return -np.einsum("nji,nj->ni", self.R, self.t)


def posed_cameras(result: dict, rig: Rig | None = None) -> PosedCameras:
    """The cameras of a result document, intrinsics from the result or else from ``rig``."""
    if not isinstance(result, dict) or not isinstance(result.get("cameras"), list) or not result["cameras"]:
        raise CalibrationError("the result has no 'cameras'; export needs a finished wandcal-result/1 document")
    by_id = {c.id: c for c in rig.cameras} if rig is not None else {}
    cams, R, t, rms, obs = [], [], [], [], []
    for entry in result["cameras"]:
        cid = str(entry.get("id"))
        cam = by_id.get(cid)
        Rk = np.asarray(_pick(entry, cid, "R", None), dtype=float)
        tk = np.asarray(_pick(entry, cid, "t", None), dtype=float).ravel()
        if Rk.shape != (3, 3) or tk.shape != (3,):
            raise CalibrationError(f"camera {cid!r}: 'R' must be 3x3 and 't' must hold 3 numbers")
        fallback = {"width": cam.width, "height": cam.height, "K": cam.K, "dist": cam.dist, "model": cam.model} if cam else {}
        fallback.setdefault("model", PINHOLE)
        field = {key: _pick(entry, cid, key, fallback.get(key)) for key in ("width", "height", "K", "dist", "model")}
        try:
            cams.append(Camera(cid, int(field["width"]), int(field["height"]), np.asarray(field["K"], dtype=float).reshape(3, 3),
                               np.asarray(field["dist"], dtype=float).ravel(), str(field["model"])))
        except CalibrationError:
            raise
        except (TypeError, ValueError) as exc:
            raise CalibrationError(f"camera {cid!r}: width, height, K or dist is malformed ({exc})") from None
        R.append(Rk)
        t.append(tk)
        rms.append(entry.get("reprojection_rms_px"))
        obs.append(entry.get("observations"))
    return PosedCameras(tuple(cams), np.array(R), np.array(t), _numbers(rms, np.nan), _numbers(obs, -1).astype(int))


def _pick(entry: dict, cid: str, key: str, fallback):
    """A camera's field from the result, else from the rig; named when neither has it."""
    value = entry.get(key)
    if value is None:
        value = fallback
    if value is None:
        raise CalibrationError(f"camera {cid!r}: the result has no {key!r} and no rig was given to supply it")
    return value


def _numbers(values: list, missing: float) -> np.ndarray:
    return np.array([missing if v is None else float(v) for v in values])


def check_unit(unit: str) -> float:
    """Metres -> ``unit``: the factor; raises for an unknown unit."""
    if unit not in UNITS:
        raise CalibrationError(f"unit must be one of {', '.join(UNITS)}, not {unit!r}")
    return UNITS[unit]

def read_cameras(cams: list[Camera], R: list, t: list, source: str, rms=None) -> PosedCameras:
    """What a reader found, checked: at least one camera, and rotations that are rotations."""
    if not cams:
        raise CalibrationError(f"{source}: no cameras found")
    for cam, Rk, tk in zip(cams, R, t):
        if not (np.all(np.isfinite(Rk)) and np.all(np.isfinite(tk))):  # NaN passed the comparisons below
            raise CalibrationError(f"{source}: camera {cam.id!r}: the rotation or translation holds a number that is "
                                   "not finite (NaN or infinity)")
        if not np.abs(Rk.T @ Rk - np.eye(3)).max() <= ROTATION_TOLERANCE or np.linalg.det(Rk) < 0:
            raise CalibrationError(f"{source}: camera {cam.id!r}: the rotation is not a rotation matrix")
    n = len(cams)
    rms = np.full(n, np.nan) if rms is None else np.asarray(rms, dtype=float)
    return PosedCameras(tuple(cams), np.array(R), np.array(t), rms, np.full(n, -1))
