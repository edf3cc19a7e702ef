"""anipose / aniposelib / Pose2Sim ``calibration.toml`` and OpenCV ``FileStorage`` YAML: writers and readers.

Both hold OpenCV's conventions (top-left pixels, ``x_cam = R x + t``, the rotation as a Rodrigues
vector in the TOML and a matrix in the YAML); docs/formats.md.
"""

from __future__ import annotations

import tomllib

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import matrix_to_rotvec, rotvec_to_matrix
from wandcal.calib.rig import FISHEYE, PINHOLE, Camera, Rig
from wandcal.capture.formats.cameras import PosedCameras, check_unit, posed_cameras, read_cameras
from wandcal.capture.formats.opencv_yaml import parse_number, parse_opencv_yaml

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
    except ValueError as exc:  # an integer of more than 4300 digits (Python's int-from-text limit; fuzzing found it)
        raise CalibrationError(f"{source}: a number too long to read ({str(exc)[:120]}); give anipose's "
                               "calibration.toml") from None
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


MAX_YAML_CAMERAS = 1024  # four times the largest rig wandcal simulates (calib.sim.shapes.MAX_CAMERAS)


def read_opencv_yaml(text: str, source: str = "calibration.yaml") -> PosedCameras:
    """YAML written by :func:`to_opencv_yaml` (or by ``cv2.FileStorage`` in its layout) back as cameras.

    Parsed in Python (:mod:`wandcal.capture.formats.opencv_yaml`), never by ``cv2.FileStorage``,
    whose parser can corrupt the heap and abort the process on a damaged file. ``t`` is in the
    file's ``unit`` (default m) and returned in metres.
    """
    if not text.strip():
        raise CalibrationError(f"{source}: empty; give the YAML 'wandcal export --format opencv-yaml' writes")
    doc = parse_opencv_yaml(text, source)
    unit = _yaml_text(doc.get("unit"), "m")
    try:
        scale = check_unit(unit)
    except CalibrationError as exc:
        raise CalibrationError(f"{source}: {exc}") from None
    cameras = doc.get("cameras")
    if not isinstance(cameras, list):
        raise CalibrationError(f"{source}: no 'cameras' sequence; docs/formats.md, opencv-yaml")
    if len(cameras) > MAX_YAML_CAMERAS:
        raise CalibrationError(f"{source}: {len(cameras)} cameras, more than the {MAX_YAML_CAMERAS} a file may hold")
    cams, R, t, rms = [], [], [], []
    for i, cam in enumerate(cameras):
        where = f"{source}: cameras[{i}]"
        if not isinstance(cam, dict):
            raise CalibrationError(f"{where} is not a map of id, model, image_width, image_height, camera_matrix, ...")
        fields = (_yaml_text(cam.get("id"), f"cam{i + 1}"), _yaml_whole(cam, "image_width", where),
                  _yaml_whole(cam, "image_height", where), _yaml_matrix_field(cam, "camera_matrix", where),
                  _yaml_matrix_field(cam, "distortion_coefficients", where).ravel(), _yaml_text(cam.get("model"), PINHOLE))
        try:
            cams.append(Camera(*fields))
        except CalibrationError as exc:  # Camera's checks name the camera, not the file
            raise CalibrationError(f"{where}: {exc}") from None
        R.append(_yaml_matrix_field(cam, "R", where))
        t.append(_yaml_matrix_field(cam, "t", where).ravel() / scale)
        rms.append(_yaml_real(cam, "reprojection_rms_px", where) if "reprojection_rms_px" in cam else np.nan)
    return read_cameras(cams, R, t, source, rms)


def _yaml_text(value, default: str) -> str:
    """A scalar as text; ``default`` for a missing or empty one (as ``FileNode.string()`` gave)."""
    return value if isinstance(value, str) and value else default


def _yaml_real(cam: dict, key: str, where: str) -> float:
    value = cam[key]
    try:
        if not isinstance(value, str):
            raise ValueError(f"a {type(value).__name__}")
        return parse_number(value)
    except ValueError as exc:
        raise CalibrationError(f"{where}: {key!r} must be a number ({exc})") from None


def _yaml_whole(cam: dict, key: str, where: str) -> int:
    if key not in cam:
        raise CalibrationError(f"{where} has no {key!r}")
    value = _yaml_real(cam, key, where)
    if not (np.isfinite(value) and value == int(value)):
        raise CalibrationError(f"{where}: {key!r} must be a whole number of pixels, not {cam[key]!r}")
    return int(value)


def _yaml_matrix_field(cam: dict, key: str, where: str) -> np.ndarray:
    m = cam.get(key)
    if not isinstance(m, np.ndarray):
        raise CalibrationError(f"{where} has no matrix {key!r} (a !!opencv-matrix map of rows, cols, dt, data)")
    return m
