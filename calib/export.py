"""Write a ``wandcal-result/1`` document in other tools' formats: anipose, OpenCV, DLT.

Pure functions from the result dict (plus the rig, for whatever the result leaves out) to text.
Poses stay world->camera (``x_cam = R @ x_world + t``); lengths are metres unless ``unit="mm"``.
Conversions between conventions happen here, at the edge, and nowhere else.
"""

from __future__ import annotations

import numpy as np

from calib.errors import CalibrationError
from calib.geometry import matrix_to_rotvec
from calib.rig import FISHEYE, PINHOLE, Rig

UNITS = {"m": 1.0, "mm": 1000.0}
DLT_ORIGINS = ("top-left", "bottom-left")
DLT_COEFFICIENTS = 11


def _cameras(result: dict, rig: Rig | None, unit: str) -> list[dict]:
    """Per camera: id, width, height, model, K (3,3), dist, R (3,3), t (3,) in ``unit``."""
    if not isinstance(result, dict) or not isinstance(result.get("cameras"), list) or not result["cameras"]:
        raise CalibrationError("the result has no 'cameras'; export needs a finished wandcal-result/1 document")
    if unit not in UNITS:
        raise CalibrationError(f"unit must be one of {', '.join(UNITS)}, not {unit!r}")
    by_id = {c.id: c for c in rig.cameras} if rig is not None else {}
    out = []
    for entry in result["cameras"]:
        cid = str(entry.get("id"))
        cam = by_id.get(cid)

        def pick(key, fallback):
            value = entry.get(key)
            if value is None:
                value = fallback
            if value is None:
                raise CalibrationError(
                    f"camera {cid!r}: the result has no {key!r} and no rig was given to supply it"
                )
            return value

        R = np.asarray(pick("R", None), dtype=float)
        t = np.asarray(pick("t", None), dtype=float).ravel()
        if R.shape != (3, 3) or t.shape != (3,):
            raise CalibrationError(f"camera {cid!r}: 'R' must be 3x3 and 't' must hold 3 numbers")
        out.append(
            {
                "id": cid,
                "width": int(pick("width", cam.width if cam else None)),
                "height": int(pick("height", cam.height if cam else None)),
                "model": str(pick("model", cam.model if cam else PINHOLE)),
                "K": np.asarray(pick("K", cam.K if cam else None), dtype=float).reshape(3, 3),
                "dist": np.asarray(pick("dist", cam.dist if cam else None), dtype=float).ravel(),
                "R": R,
                "t": t * UNITS[unit],
                "rms": entry.get("reprojection_rms_px"),
            }
        )
    return out


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return repr(float(value))


def to_anipose_toml(result: dict, rig: Rig | None = None, unit: str = "m") -> str:
    """The calibration as an anipose / aniposelib ``calibration.toml``.

    One ``[cam_i]`` table per camera with ``name``, ``size`` [w, h], ``matrix`` (3x3),
    ``distortions``, ``rotation`` (Rodrigues vector, world->camera) and ``translation``
    (``unit``; anipose uses the unit of its board, often mm), ``fisheye = true`` for fisheye
    cameras, and a ``[metadata]`` table with the mean reprojection RMS as ``error``.
    """
    cams = _cameras(result, rig, unit)
    lines = []
    for i, c in enumerate(cams):
        lines += [
            f"[cam_{i}]",
            f"name = {_toml_value(c['id'])}",
            f"size = {_toml_value([c['width'], c['height']])}",
            f"matrix = {_toml_value(c['K'].tolist())}",
            f"distortions = {_toml_value(c['dist'].tolist())}",
            f"rotation = {_toml_value(matrix_to_rotvec(c['R']).tolist())}",
            f"translation = {_toml_value(c['t'].tolist())}",
        ]
        if c["model"] == FISHEYE:
            lines.append("fisheye = true")
        lines.append("")
    rms = [c["rms"] for c in cams if c["rms"] is not None]
    lines += ["[metadata]", "adjusted = true", f"error = {_toml_value(float(np.mean(rms)) if rms else 0.0)}", ""]
    return "\n".join(lines)


def _yaml_matrix(name: str, m: np.ndarray, indent: str) -> list[str]:
    m = np.atleast_2d(m)
    data = ", ".join(repr(float(v)) for v in m.ravel())
    return [
        f"{indent}{name}: !!opencv-matrix",
        f"{indent}   rows: {m.shape[0]}",
        f"{indent}   cols: {m.shape[1]}",
        f"{indent}   dt: d",
        f"{indent}   data: [ {data} ]",
    ]


def _yaml_string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def to_opencv_yaml(result: dict, rig: Rig | None = None, unit: str = "m") -> str:
    """The calibration as YAML that ``cv2.FileStorage`` reads.

    Top level: ``camera_count`` and ``cameras``, a sequence of maps with ``id``, ``model``,
    ``image_width``, ``image_height``, ``camera_matrix`` (3x3), ``distortion_coefficients``
    (1xN), ``R`` (3x3), ``rvec`` (3x1), ``t`` (3x1, ``unit``) and ``reprojection_rms_px``.
    Read with ``fs.getNode("cameras").at(i).getNode("R").mat()``.
    """
    cams = _cameras(result, rig, unit)
    lines = ["%YAML:1.0", "---", f"format: {_yaml_string(str(result.get('format', 'wandcal-result/1')))}",
             f"unit: {unit}", f"camera_count: {len(cams)}", "cameras:"]
    for c in cams:
        lines += [
            "   -",
            f"      id: {_yaml_string(c['id'])}",
            f"      model: {c['model']}",
            f"      image_width: {c['width']}",
            f"      image_height: {c['height']}",
        ]
        lines += _yaml_matrix("camera_matrix", c["K"], "      ")
        lines += _yaml_matrix("distortion_coefficients", c["dist"][None, :], "      ")
        lines += _yaml_matrix("R", c["R"], "      ")
        lines += _yaml_matrix("rvec", matrix_to_rotvec(c["R"])[:, None], "      ")
        lines += _yaml_matrix("t", c["t"][:, None], "      ")
        if c["rms"] is not None:
            lines.append(f"      reprojection_rms_px: {float(c['rms'])!r}")
    return "\n".join(lines) + "\n"


def dlt_coefficients(K: np.ndarray, R: np.ndarray, t: np.ndarray, height: int | None = None) -> np.ndarray:
    """(11,) DLT coefficients L1..L11 of the pinhole camera ``K [R | t]`` (no lens distortion):

    ``u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)``, v likewise with L5..L8.
    With ``height`` given, v is measured up from the bottom edge (``v' = height - v``, the
    DLTdv / Argus convention) instead of down from the top.
    """
    P = K @ np.hstack([R, t[:, None]])
    if height is not None:
        P = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, float(height)], [0.0, 0.0, 1.0]]) @ P
    if abs(P[2, 3]) < 1e-12:
        raise CalibrationError("the world origin lies in the camera's focal plane; DLT cannot normalise L12 = 1")
    return (P / P[2, 3]).ravel()[:DLT_COEFFICIENTS]


def to_dlt_csv(result: dict, rig: Rig | None = None, unit: str = "m", origin: str = "top-left") -> str:
    """DLT coefficients as CSV: 11 rows, one column per camera in the result's order, no header
    (the layout DLTdv and Argus read). DLT has no lens distortion: undistort points before use."""
    if origin not in DLT_ORIGINS:
        raise CalibrationError(f"origin must be one of {', '.join(DLT_ORIGINS)}, not {origin!r}")
    cams = _cameras(result, rig, unit)
    cols = [
        dlt_coefficients(c["K"], c["R"], c["t"], c["height"] if origin == "bottom-left" else None) for c in cams
    ]
    table = np.stack(cols, axis=1)
    return "\n".join(",".join(repr(float(v)) for v in row) for row in table) + "\n"

