"""The marker-system XML calibrations: Qualisys ``.qca`` and Vicon ``.xcp``, written and read.

Both hold pinhole cameras with a radial (and, for Qualisys, tangential) lens, positions in mm
and the camera centre rather than ``t``. The conventions, and where each comes from, are in
docs/formats.md; in short:

- **qca** (as Pose2Sim's ``calib_toml_to_qca`` / ``calib_qca_to_toml`` read and write it, and as
  the Pose2Sim demo's file bears out): ``transform`` ``r11..r33`` is the world->camera rotation
  of a camera that looks along its -z with y up, ``M = diag(1, -1, -1) R``; ``x, y, z`` is the
  camera centre, mm; intrinsics and lens coefficients in 1/64 pixel (``* 64``), the principal
  point from the ``fov_video`` corner; ``fov_*`` ``right``/``bottom`` are the last pixel's index.
- **xcp** (Vicon's documentation; Pose2Sim's ``read_vicon`` and OpenCap's reader):
  ``ORIENTATION`` the world->camera rotation as a quaternion ``x y z w`` (real part last), camera
  axes as OpenCV's; ``POSITION`` the camera centre, mm; ``FOCAL_LENGTH`` fx and
  ``PIXEL_ASPECT_RATIO`` fx/fy, pixels; ``VICON_RADIAL2`` ``ThirdOrderRadial cx cy k1 k2 k3``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import matrix_to_rotvec, rotvec_to_matrix
from wandcal.calib.rig import FISHEYE, PINHOLE, Camera, Rig
from wandcal.capture.formats.cameras import PosedCameras, posed_cameras, read_cameras

MM = 1000.0  # both formats hold lengths in millimetres
QCA_UNITS = 64.0  # Qualisys intrinsics are in 1/64 pixel (Pose2Sim divides and multiplies by 64)
QUALISYS_AXES = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes -> Qualisys's (looking along -z, y up)
VICON_RADIAL_MODEL = "ThirdOrderRadial"  # VICON_RADIAL2's first token: the model's name


def _f(value: float) -> str:
    return repr(float(value))


def _lens(cam: Camera, fmt: str) -> np.ndarray:
    """(5,) ``[k1, k2, p1, p2, k3]`` of a pinhole camera; a fisheye lens has no place in ``fmt``."""
    if cam.model == FISHEYE:
        raise CalibrationError(f"camera {cam.id!r} has a fisheye lens, which {fmt} cannot hold; export "
                               "anipose-toml or opencv-yaml, or dlt-csv with undistorted points")
    return cam.dist


def _residual_mm(pc: PosedCameras, i: int) -> float:
    """A camera's reprojection RMS as millimetres at the distance of the world origin,
    ``rms_px * |t| / f``: what Pose2Sim turns back into pixels; 0 where the RMS is unknown."""
    rms = pc.rms_px[i]
    return float(rms * np.linalg.norm(pc.t[i]) * MM / pc.cameras[i].K[0, 0]) if np.isfinite(rms) else 0.0


def _xml(root: ET.Element) -> str:
    ET.indent(root, space="  ")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _parse(text: str, source: str, root_tag: str) -> ET.Element:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise CalibrationError(f"{source}: not XML ({exc})") from None
    if root.tag != root_tag:
        raise CalibrationError(f"{source}: the root element is <{root.tag}>, not <{root_tag}>")
    return root


def _numbers(element: ET.Element, names, where: str) -> np.ndarray:
    try:
        values = np.array([float(element.attrib[n]) for n in names])
    except KeyError as exc:
        raise CalibrationError(f"{where}: <{element.tag}> has no {exc.args[0]!r}") from None
    except ValueError as exc:
        raise CalibrationError(f"{where}: <{element.tag}>: {exc}") from None
    if not np.all(np.isfinite(values)):
        raise CalibrationError(f"{where}: <{element.tag}> holds a value that is not finite")
    return values


def _number(element: ET.Element, name: str, default: float, where: str) -> float:
    """An optional numeric attribute."""
    try:
        value = float(element.attrib.get(name, default))
    except ValueError:
        raise CalibrationError(f"{where}: <{element.tag}> {name}={element.attrib[name]!r} is not a number") from None
    if not np.isfinite(value):
        raise CalibrationError(f"{where}: <{element.tag}> {name} is not finite")
    return value


def _child(element: ET.Element, path: str, where: str) -> ET.Element:
    child = element.find(path)
    if child is None:
        raise CalibrationError(f"{where}: no <{path}>")
    return child


def to_qca(result: dict, rig: Rig | None = None) -> str:
    """The calibration as a Qualisys-style ``.qca.txt`` (conventions in the module docstring)."""
    pc = posed_cameras(result, rig)
    wand = result.get("wand") or {}
    root = ET.Element("calibration", {
        "source": "wandcal", "type": "regular",
        "wandLength": _f(wand["length_m"] * MM) if wand.get("length_m") else "none",
    })
    if wand.get("length_std_m") is not None:
        ET.SubElement(root, "results", {"std-dev": _f(wand["length_std_m"] * MM)})
    cameras = ET.SubElement(root, "cameras")
    for i, cam in enumerate(pc.cameras):
        k1, k2, p1, p2, k3 = _lens(cam, "qca")
        attrib = {"active": "1", "avg-residual": _f(_residual_mm(pc, i)), "serial": cam.id, "model": "none",
                  "viewrotation": "0"}
        if pc.observations[i] >= 0:
            attrib["point-count"] = str(int(pc.observations[i]))
        camera = ET.SubElement(cameras, "camera", attrib)
        fov = {"left": "0", "top": "0", "right": str(cam.width - 1), "bottom": str(cam.height - 1)}
        for tag in ("fov_marker", "fov_marker_max", "fov_video", "fov_video_max"):
            ET.SubElement(camera, tag, fov)
        M, C = QUALISYS_AXES @ pc.R[i], pc.centers[i] * MM
        transform = {"x": _f(C[0]), "y": _f(C[1]), "z": _f(C[2])}
        transform |= {f"r{r + 1}{c + 1}": _f(M[r, c]) for r in range(3) for c in range(3)}
        ET.SubElement(camera, "transform", transform)
        K = cam.K * QCA_UNITS
        ET.SubElement(camera, "intrinsic", {
            "sensorMinU": "0", "sensorMaxU": _f((cam.width - 1) * QCA_UNITS),
            "sensorMinV": "0", "sensorMaxV": _f((cam.height - 1) * QCA_UNITS),
            "focalLengthU": _f(K[0, 0]), "focalLengthV": _f(K[1, 1]),
            "centerPointU": _f(K[0, 2]), "centerPointV": _f(K[1, 2]), "skew": _f(K[0, 1]),
            "radialDistortion1": _f(k1 * QCA_UNITS), "radialDistortion2": _f(k2 * QCA_UNITS),
            "radialDistortion3": _f(k3 * QCA_UNITS),
            "tangentalDistortion1": _f(p1 * QCA_UNITS), "tangentalDistortion2": _f(p2 * QCA_UNITS),
        })
    return _xml(root)


def _camera_elements(text: str, source: str, root_tag: str, path: str, id_attribute: str):
    """Each camera element of the document, with its id and the words that place it in errors."""
    root = _parse(text, source, root_tag)
    for k, camera in enumerate(root.findall(path)):
        cid = camera.attrib.get(id_attribute) or f"cam{k + 1}"
        yield camera, cid, f"{source}: camera {cid!r}"


def read_qca(text: str, source: str = "calibration.qca.txt") -> PosedCameras:
    """A Qualisys-style ``.qca.txt`` back as cameras (every ``<camera>``, active or not)."""
    cams, R, t = [], [], []
    for camera, cid, where in _camera_elements(text, source, "calibration", "cameras/camera", "serial"):
        left, top, right, bottom = _numbers(_child(camera, "fov_video", where), ("left", "top", "right", "bottom"), where)
        intr = _child(camera, "intrinsic", where)
        fu, fv, cu, cv = _numbers(intr, ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV"), where) / QCA_UNITS
        skew = _number(intr, "skew", 0.0, where) / QCA_UNITS
        lens = np.array([_number(intr, n, 0.0, where) for n in ("radialDistortion1", "radialDistortion2",
                         "tangentalDistortion1", "tangentalDistortion2", "radialDistortion3")]) / QCA_UNITS
        K = np.array([[fu, skew, cu - left], [0.0, fv, cv - top], [0.0, 0.0, 1.0]])
        try:
            cams.append(Camera(cid, int(right - left + 1), int(bottom - top + 1), K, lens, PINHOLE))
        except CalibrationError as exc:
            raise CalibrationError(f"{source}: {exc}") from None
        tr = _child(camera, "transform", where)
        M = _numbers(tr, [f"r{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3)], where).reshape(3, 3)
        Rk = QUALISYS_AXES @ M
        R.append(Rk)
        t.append(-Rk @ (_numbers(tr, ("x", "y", "z"), where) / MM))
    # avg-residual is a 3D figure in mm, not the pixel RMS: the RMS is left unknown
    return read_cameras(cams, R, t, source)


def quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion ``x y z w`` (real part last, w >= 0) of the rotation matrix R."""
    rotvec = matrix_to_rotvec(R)
    angle = float(np.linalg.norm(rotvec))
    axis = rotvec / angle if angle > 0 else np.zeros(3)
    return np.append(axis * np.sin(angle / 2), np.cos(angle / 2))


def rotation_from_xyzw(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation of the quaternion ``x y z w`` (normalised first)."""
    q = np.asarray(q, dtype=float) / np.linalg.norm(q)
    w = q[3]
    angle = 2 * np.arctan2(np.linalg.norm(q[:3]), w)
    axis = q[:3] / np.linalg.norm(q[:3]) if angle > 0 else np.zeros(3)
    return rotvec_to_matrix(axis * angle)


def to_xcp(result: dict, rig: Rig | None = None) -> str:
    """The calibration as a Vicon ``.xcp`` (conventions in the module docstring). A camera with
    tangential distortion is refused: ``VICON_RADIAL2`` is radial only."""
    pc = posed_cameras(result, rig)
    root = ET.Element("Cameras", {"NAME": "wandcal", "VERSION": "1.0"})
    for i, cam in enumerate(pc.cameras):
        k1, k2, p1, p2, k3 = _lens(cam, "xcp")
        if p1 or p2:
            raise CalibrationError(f"camera {cam.id!r} has tangential distortion (p1 {p1:.3g}, p2 {p2:.3g}), which "
                                   "xcp's radial model cannot hold; export qca, anipose-toml or opencv-yaml")
        K = cam.K
        camera = ET.SubElement(root, "Camera", {
            "DEVICEID": cam.id, "NAME": cam.id, "USERID": str(i + 1), "TYPE": "wandcal", "DISPLAY_TYPE": "wandcal",
            "SENSOR": "", "SENSOR_SIZE": f"{cam.width} {cam.height}", "PIXEL_ASPECT_RATIO": _f(K[0, 0] / K[1, 1]),
            "SKEW": _f(K[0, 1]), "SYSTEM": "",
        })
        frames = ET.SubElement(camera, "KeyFrames")
        C = pc.centers[i] * MM
        rms = pc.rms_px[i]
        ET.SubElement(frames, "KeyFrame", {
            "FRAME": "0", "FOCAL_LENGTH": _f(K[0, 0]),
            "PRINCIPAL_POINT": f"{_f(K[0, 2])} {_f(K[1, 2])}",
            "ORIENTATION": " ".join(_f(v) for v in quaternion_xyzw(pc.R[i])),
            "POSITION": " ".join(_f(v) for v in C),
            "VICON_RADIAL2": f"{VICON_RADIAL_MODEL} {_f(K[0, 2])} {_f(K[1, 2])} {_f(k1)} {_f(k2)} {_f(k3)}",
            "IMAGE_ERROR": _f(rms if np.isfinite(rms) else 0.0), "WORLD_ERROR": _f(_residual_mm(pc, i)),
        })
    return _xml(root)


def _vector(element: ET.Element, name: str, n: int, where: str) -> np.ndarray:
    """The last ``n`` numbers of a space-separated attribute (``VICON_RADIAL2`` starts with a name)."""
    try:
        values = np.array(element.attrib[name].split()[-n:], dtype=float)
    except KeyError:
        raise CalibrationError(f"{where}: no {name!r}") from None
    except ValueError as exc:
        raise CalibrationError(f"{where}: {name!r}: {exc}") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise CalibrationError(f"{where}: {name!r} must hold {n} finite numbers")
    return values


def read_xcp(text: str, source: str = "calibration.xcp") -> PosedCameras:
    """A Vicon ``.xcp`` back as cameras (the first ``KeyFrame`` of each camera)."""
    cams, R, t, rms = [], [], [], []
    for camera, cid, where in _camera_elements(text, source, "Cameras", "Camera", "DEVICEID"):
        frame = _child(camera, "KeyFrames/KeyFrame", where)
        width, height = _vector(camera, "SENSOR_SIZE", 2, where)
        (f,) = _vector(frame, "FOCAL_LENGTH", 1, where)
        aspect = _number(camera, "PIXEL_ASPECT_RATIO", 1.0, where)
        cx, cy = _vector(frame, "PRINCIPAL_POINT", 2, where)
        K = np.array([[f, _number(camera, "SKEW", 0.0, where), cx], [0.0, f / aspect if aspect else 0.0, cy], [0.0, 0.0, 1.0]])
        radial = _vector(frame, "VICON_RADIAL2", 3, where) if "VICON_RADIAL2" in frame.attrib else np.zeros(3)
        try:
            cams.append(Camera(cid, int(width), int(height), K, np.array([radial[0], radial[1], 0.0, 0.0, radial[2]])))
        except CalibrationError as exc:
            raise CalibrationError(f"{source}: {exc}") from None
        q = _vector(frame, "ORIENTATION", 4, where)
        if not np.linalg.norm(q) > 0:
            raise CalibrationError(f"{where}: 'ORIENTATION' is a zero quaternion")
        Rk = rotation_from_xyzw(q)
        R.append(Rk)
        t.append(-Rk @ (_vector(frame, "POSITION", 3, where) / MM))
        rms.append(_number(frame, "IMAGE_ERROR", 0.0, where) or np.nan)
    return read_cameras(cams, R, t, source, rms)
