"""anipose / aniposelib / Pose2Sim ``calibration.toml`` and OpenCV ``FileStorage`` YAML: writers and readers.

Both hold OpenCV's conventions (top-left pixels, ``x_cam = R x + t``, the rotation as a Rodrigues
vector in the TOML and a matrix in the YAML); docs/formats.md.
"""

from __future__ import annotations

import tomllib

import cv2
import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import matrix_to_rotvec, rotvec_to_matrix
from wandcal.calib.rig import FISHEYE, PINHOLE, Camera, Rig
from wandcal.capture.formats.cameras import PosedCameras, check_unit, posed_cameras, read_cameras

OPENCV_SHORT_DIST = 4  # OpenCV's shortest pinhole distortion vector, [k1, k2, p1, p2]


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
            dist = np.array(entry["distortions"], dtype=float).ravel()
            if model == PINHOLE and len(dist) == OPENCV_SHORT_DIST:
                dist = np.r_[dist, 0.0]  # OpenCV's [k1, k2, p1, p2] (Pose2Sim writes four): k3 = 0
            cams.append(Camera(str(entry.get("name", key)), size[0], size[1], np.array(entry["matrix"], dtype=float),
                               dist, model))
            R.append(rotvec_to_matrix(np.array(entry["rotation"], dtype=float).reshape(3)))
            t.append(np.array(entry["translation"], dtype=float).reshape(3) / scale)
        except KeyError as exc:
            raise CalibrationError(f"{where} has no {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError, OverflowError) as exc:  # OverflowError: a size of inf or 1e400
            raise CalibrationError(f"{where}: {exc}") from None
    return read_cameras(cams, R, t, source)




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
    if not text.strip():  # OpenCV fails on an empty buffer with a SystemError, not its own error
        raise CalibrationError(f"{source}: empty; give the YAML 'wandcal export --format opencv-yaml' writes")
    try:
        fs = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    except (cv2.error, SystemError) as exc:  # OpenCV's parse errors reach Python as either
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
    except cv2.error as exc:  # a node of another kind than the one asked for (a map where a sequence was)
        raise CalibrationError(f"{source}: not the OpenCV YAML wandcal writes ({str(exc).strip().splitlines()[-1]}); "
                               "docs/formats.md, opencv-yaml") from None
    except (ValueError, OverflowError) as exc:  # an image size of NaN or infinity
        raise CalibrationError(f"{source}: a camera's image_width or image_height is not a whole number ({exc})") from None
    finally:
        fs.release()
