"""Write a ``wandcal-result/1`` document in other tools' formats, and read those formats back.

Pure functions from the result dict (plus the rig, for whatever the result leaves out) to text,
and from text to :class:`PosedCameras`. Every format's conventions are stated once, in
docs/formats.md; conversions between conventions happen here, at the edge, and nowhere else.

| format | module | read back by |
|---|---|---|
| ``anipose-toml`` | here | :func:`read_anipose_toml` |
| ``opencv-yaml`` | here | :func:`read_opencv_yaml` |
| ``dlt-csv`` | :mod:`calib.export_dlt` | :func:`calib.export_dlt.read_dlt_csv` (with the image sizes) |
| ``qca`` | :mod:`calib.export_xml` | :func:`calib.export_xml.read_qca` |
| ``xcp`` | :mod:`calib.export_xml` | :func:`calib.export_xml.read_xcp` |
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from calib.errors import CalibrationError
from calib.geometry import matrix_to_rotvec, rotvec_to_matrix
from calib.rig import FISHEYE, PINHOLE, Camera, Rig

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
    """The calibration as an anipose / aniposelib / Pose2Sim ``calibration.toml``.

    One ``[cam_i]`` table per camera with ``name``, ``size`` [w, h], ``matrix`` (3x3),
    ``distortions``, ``rotation`` (Rodrigues vector, world->camera) and ``translation``
    (``unit``; Pose2Sim reads metres, anipose the unit of its board, often mm), ``fisheye``, and a
    ``[metadata]`` table with the mean reprojection RMS as ``error``.
    """
    scale = check_unit(unit)
    pc = posed_cameras(result, rig)
    lines = []
    for i, cam in enumerate(pc.cameras):
        lines += [
            f"[cam_{i}]",
            f"name = {_toml_value(cam.id)}",
            f"size = {_toml_value([cam.width, cam.height])}",
            f"matrix = {_toml_value(cam.K.tolist())}",
            f"distortions = {_toml_value(cam.dist.tolist())}",
            f"rotation = {_toml_value(matrix_to_rotvec(pc.R[i]).tolist())}",
            f"translation = {_toml_value((pc.t[i] * scale).tolist())}",
            f"fisheye = {_toml_value(cam.model == FISHEYE)}",
            "",
        ]
    rms = pc.rms_px[np.isfinite(pc.rms_px)]
    lines += ["[metadata]", "adjusted = true", f"error = {_toml_value(float(rms.mean()) if len(rms) else 0.0)}", ""]
    return "\n".join(lines)


def read_anipose_toml(text: str, unit: str = "m", source: str = "calibration.toml") -> PosedCameras:
    """A ``calibration.toml`` (anipose, Pose2Sim) back as cameras; ``unit`` is its translations'."""
    scale = check_unit(unit)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{source}: not TOML ({exc})") from None
    cams, R, t = [], [], []
    for key, entry in doc.items():
        if key == "metadata":
            continue
        where = f"{source}: [{key}]"
        if not isinstance(entry, dict):
            raise CalibrationError(f"{where} must be a table with name, size, matrix, distortions, rotation, translation")
        try:
            size = [int(v) for v in entry["size"]]
            model = FISHEYE if entry.get("fisheye", False) else PINHOLE
            cams.append(Camera(str(entry.get("name", key)), size[0], size[1], np.array(entry["matrix"], dtype=float),
                               np.array(entry["distortions"], dtype=float), model))
            R.append(rotvec_to_matrix(np.array(entry["rotation"], dtype=float).reshape(3)))
            t.append(np.array(entry["translation"], dtype=float).reshape(3) / scale)
        except KeyError as exc:
            raise CalibrationError(f"{where} has no {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError) as exc:
            raise CalibrationError(f"{where}: {exc}") from None
    return read_cameras(cams, R, t, source)


def read_cameras(cams: list[Camera], R: list, t: list, source: str, rms=None) -> PosedCameras:
    """What a reader found, checked: at least one camera, and rotations that are rotations."""
    if not cams:
        raise CalibrationError(f"{source}: no cameras found")
    for cam, Rk in zip(cams, R):
        if np.abs(Rk.T @ Rk - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(Rk) < 0:
            raise CalibrationError(f"{source}: camera {cam.id!r}: the rotation is not a rotation matrix")
    n = len(cams)
    rms = np.full(n, np.nan) if rms is None else np.asarray(rms, dtype=float)
    return PosedCameras(tuple(cams), np.array(R), np.array(t), rms, np.full(n, -1))


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

    Top level: ``unit``, ``camera_count`` and ``cameras``, a sequence of maps with ``id``,
    ``model``, ``image_width``, ``image_height``, ``camera_matrix`` (3x3),
    ``distortion_coefficients`` (1xN), ``R`` (3x3), ``rvec`` (3x1), ``t`` (3x1, ``unit``) and
    ``reprojection_rms_px``. Read with ``fs.getNode("cameras").at(i).getNode("R").mat()``.
    """
    scale = check_unit(unit)
    pc = posed_cameras(result, rig)
    lines = ["%YAML:1.0", "---", f"format: {_yaml_string(str(result.get('format', 'wandcal-result/1')))}",
             f"unit: {unit}", f"camera_count: {len(pc.cameras)}", "cameras:"]
    for i, cam in enumerate(pc.cameras):
        lines += [
            "   -",
            f"      id: {_yaml_string(cam.id)}",
            f"      model: {cam.model}",
            f"      image_width: {cam.width}",
            f"      image_height: {cam.height}",
        ]
        lines += _yaml_matrix("camera_matrix", cam.K, "      ")
        lines += _yaml_matrix("distortion_coefficients", cam.dist[None, :], "      ")
        lines += _yaml_matrix("R", pc.R[i], "      ")
        lines += _yaml_matrix("rvec", matrix_to_rotvec(pc.R[i])[:, None], "      ")
        lines += _yaml_matrix("t", pc.t[i][:, None] * scale, "      ")
        if np.isfinite(pc.rms_px[i]):
            lines.append(f"      reprojection_rms_px: {float(pc.rms_px[i])!r}")
    return "\n".join(lines) + "\n"


def read_opencv_yaml(text: str, source: str = "calibration.yaml") -> PosedCameras:
    """YAML written by :func:`to_opencv_yaml` back as cameras, read with ``cv2.FileStorage``."""
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    except cv2.error as exc:
        raise CalibrationError(f"{source}: not OpenCV YAML ({str(exc).strip().splitlines()[-1]})") from None
    try:
        unit = fs.getNode("unit").string() or "m"
        scale = check_unit(unit)
        node = fs.getNode("cameras")
        if not node.isSeq():
            raise CalibrationError(f"{source}: no 'cameras' sequence")
        cams, R, t, rms = [], [], [], []
        for i in range(node.size()):
            cam = node.at(i)
            where = f"{source}: cameras[{i}]"

            def mat(key, cam=cam, where=where):
                m = cam.getNode(key).mat()
                if m is None:
                    raise CalibrationError(f"{where} has no matrix {key!r}")
                return m

            cams.append(Camera(cam.getNode("id").string() or f"cam{i + 1}", int(cam.getNode("image_width").real()),
                               int(cam.getNode("image_height").real()), mat("camera_matrix"),
                               mat("distortion_coefficients").ravel(), cam.getNode("model").string() or PINHOLE))
            R.append(mat("R"))
            t.append(mat("t").ravel() / scale)
            r = cam.getNode("reprojection_rms_px")
            rms.append(r.real() if not r.empty() else np.nan)
        return read_cameras(cams, R, t, source, rms)
    finally:
        fs.release()


@dataclass(frozen=True)
class Format:
    """An exchange format: its writer, and the units and pixel origins it can be written in (the
    first of each is the default)."""

    name: str
    write: Callable[..., str]
    units: tuple[str, ...]
    origins: tuple[str, ...]


def formats() -> dict[str, Format]:
    """Every format by name (docs/formats.md)."""
    from calib import export_dlt, export_xml

    return {f.name: f for f in (
        Format("anipose-toml", to_anipose_toml, ("m", "mm"), (TOP_LEFT,)),
        Format("opencv-yaml", to_opencv_yaml, ("m", "mm"), (TOP_LEFT,)),
        # DLTdv, easyWand and Argus, the tools that read DLT coefficients, put y up (decision 0009)
        Format("dlt-csv", export_dlt.to_dlt_csv, ("m", "mm"), (BOTTOM_LEFT, TOP_LEFT)),
        Format("qca", export_xml.to_qca, ("mm",), (TOP_LEFT,)),
        Format("xcp", export_xml.to_xcp, ("mm",), (TOP_LEFT,)),
    )}


FORMAT_NAMES = ("anipose-toml", "opencv-yaml", "dlt-csv", "qca", "xcp")


def export(result: dict, fmt: str, rig: Rig | None = None, unit: str | None = None, origin: str | None = None) -> str:
    """The result in format ``fmt``; ``unit`` and ``origin`` default to the format's own, and a
    choice the format cannot hold is refused with a message saying what it holds."""
    table = formats()
    if fmt not in table:
        raise CalibrationError(f"unknown format {fmt!r}; choose one of {', '.join(table)}")
    f = table[fmt]
    unit = unit or f.units[0]
    if unit not in f.units:
        raise CalibrationError(f"{fmt} writes lengths in {' or '.join(f.units)} only, not {unit!r} (docs/formats.md)")
    origin = origin or f.origins[0]
    if origin not in f.origins:
        raise CalibrationError(f"{fmt} has its pixel origin at the {' or '.join(f.origins)} only, not {origin!r}; "
                               "the pixel origin is a choice for dlt-csv (docs/formats.md)")
    kwargs = {"unit": unit} if len(f.units) > 1 else {}
    if len(f.origins) > 1:
        kwargs["origin"] = origin
    return f.write(result, rig, **kwargs)

