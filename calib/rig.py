"""Rig description and observation containers shared by every stage.

Conventions (``docs/conventions.md``): pixels have their origin at the top-left, y down;
poses are world->camera, ``x_cam = R @ x_world + t``, in metres.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.errors import CalibrationError

PINHOLE = "pinhole"
FISHEYE = "fisheye"
DIST_COEFFS = {PINHOLE: 5, FISHEYE: 4}
# Camera ids are written unquoted into CSV files (wand.csv, sync.csv, blobs.csv), file names and
# exported formats, and read back by several readers: the safe set has no separator, quote,
# whitespace or control character, so every writer and reader agrees on what an id is
# (docs/capture-format.md). 64 characters hold any serial number or "cam_north_upper_left".
# Physical plausibility where a rig enters (rig.json, imports, results): values past these are
# typos or damage, and reached the linear algebra as LinAlgError or overflow (1e308 intrinsics).
MAX_FOCAL_PX = 1e6  # a 1000 mm lens on 1 um pixels; mocap and machine-vision lenses are 300-20,000 px
MAX_DIST_COEFF = 1e3  # OpenCV fits of strong lenses give |k3| in the tens; thousands is no lens
MAX_WORLD_M = 1e4  # static-object coordinates and wand lengths: a rig's volume is metres, not kilometres
MIN_MARKER_SEPARATION_M = 1e-3  # markers are balls of 3 mm and more: two closer than 1 mm are one marker
MIN_MARKER_SPREAD_M = 1e-3  # the static object's markers must span a plane (an L-frame's arms are decimetres)
MIN_WAND_M = 1e-3  # a wand shorter than a marker ball's diameter cannot be seen as two blobs

# Spaces inside an id ("Camera 1", as Qualisys and Vicon name them) are safe; at its ends the CSV
# readers would strip them.
CAMERA_ID = re.compile(r"[A-Za-z0-9](?:[A-Za-z0-9_.:+@# -]{0,62}[A-Za-z0-9_.:+@#-])?")
CAMERA_ID_RULE = ("1-64 characters: ASCII letters, digits, spaces and _ . - : + @ #, starting with a letter or "
                  "digit and not ending in a space (no commas, quotes, tabs, line ends or control characters)")
LENGTH_AGREEMENT_M = 1e-6  # wand.length_m beside markers_m: the same length to a micrometre (printed digits)


@dataclass(frozen=True, eq=False)
class Camera:
    """One camera's known intrinsics.

    Args:
        id: the camera's name, unique in the rig.
        width, height: image size in pixels.
        K: (3, 3) intrinsic matrix in pixels.
        dist: (5,) OpenCV ``[k1, k2, p1, p2, k3]``, or (4,) ``[k1, k2, k3, k4]`` for fisheye.
        model: ``"pinhole"`` or ``"fisheye"``.
        focal_std_px: the focal length's 1-sigma, pixels, where it is known (an OpenCV calibration's
            standard error, a lens's stated tolerance); None: the judgement assumes
            :data:`wandcal.calib.judge.intrinsic_limits.DEFAULT_FOCAL_REL_STD` of the focal length.
    """

    id: str
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    model: str = PINHOLE
    focal_std_px: float | None = None

    def __post_init__(self) -> None:
        where = f"camera {self.id!r}"
        if not isinstance(self.id, str) or not CAMERA_ID.fullmatch(self.id):
            given = repr(self.id[:80]) if isinstance(self.id, str) else f"{type(self.id).__name__} {str(self.id)[:40]}"
            raise CalibrationError(f"camera id {given} is not allowed: an id is {CAMERA_ID_RULE}; give every camera "
                                   "such a name")
        if self.model not in DIST_COEFFS:
            raise CalibrationError(f"{where}: 'model' must be 'pinhole' or 'fisheye', not {self.model!r}")
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise CalibrationError(f"{where}: 'K' must be a finite 3x3 matrix")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1) > 1e-9 or np.any(K[2, :2] != 0):
            raise CalibrationError(f"{where}: 'K' must have positive fx, fy and last row [0, 0, 1]")
        dist = np.asarray(self.dist, dtype=float).ravel()
        want = DIST_COEFFS[self.model]
        if dist.shape != (want,) or not np.all(np.isfinite(dist)):
            raise CalibrationError(
                f"{where}: 'dist' must hold {want} finite coefficients for model {self.model!r}, got {dist.size}"
            )
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CalibrationError(f"{where}: 'width' and 'height' must be positive pixel counts")
        w, h = int(self.width), int(self.height)
        if not (K[0, 0] <= MAX_FOCAL_PX and K[1, 1] <= MAX_FOCAL_PX):
            raise CalibrationError(f"{where}: 'K' focal lengths {K[0, 0]:.4g}, {K[1, 1]:.4g} px are past {MAX_FOCAL_PX:g} px"
                                   "; give the focal length in pixels (focal length / pixel pitch)")
        if np.abs(K[:2, 1:]).max() > MAX_FOCAL_PX:  # principal point and skew, each bounded as a focal length is
            raise CalibrationError(f"{where}: 'K' principal point ({K[0, 2]:.4g}, {K[1, 2]:.4g}) px or skew {K[0, 1]:.4g} "
                                   f"is past {MAX_FOCAL_PX:g} px for a {w} x {h} image; the principal point lies near "
                                   "the image's centre, in pixels from its top-left")
        if np.abs(dist).max(initial=0.0) > MAX_DIST_COEFF:
            raise CalibrationError(f"{where}: 'dist' holds {np.abs(dist).max():.4g}, past {MAX_DIST_COEFF:g}; give the "
                                   "OpenCV distortion coefficients of the lens")
        if self.focal_std_px is not None:
            std = float(self.focal_std_px)
            if not (np.isfinite(std) and 0 < std < K[0, 0]):
                raise CalibrationError(f"{where}: 'focal_std_px' must be a positive number of pixels under the focal "
                                       f"length, got {self.focal_std_px!r}; leave it out where it is not known")
            object.__setattr__(self, "focal_std_px", std)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @property
    def focal(self) -> np.ndarray:
        """(2,) fx, fy in pixels: converts normalised image coordinates to pixels."""
        return np.array([self.K[0, 0], self.K[1, 1]])


@dataclass(frozen=True, eq=False)
class Rig:
    """Cameras, the wand and the optional static object (an L-frame on the floor).

    Args:
        cameras: the cameras, in the order that observation ``camera`` indices refer to.
        wand_length: distance between the wand's two marker centres, metres; None for a capture
            without a wand (single-point tracks only), which calibrates up to scale.
        static_markers: (M, 3) marker coordinates of the static object in its own frame
            (metres, z up), or None.
        wand_markers: (K, 3) the wand's marker positions in its own frame (metres), 2-5
            collinear markers (wandcal.calib.wandlayout), or None for the two-marker wand of
            ``wand_length``; ``wand_length`` is then the distance between its extreme markers.
    """

    cameras: tuple[Camera, ...]
    wand_length: float | None
    static_markers: np.ndarray | None = None
    wand_markers: np.ndarray | None = None

    def __post_init__(self) -> None:
        ids = [c.id for c in self.cameras]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise CalibrationError(f"camera id {dup[0]!r} appears more than once in the rig; ids must be unique")
        if len(self.cameras) < 2:
            raise CalibrationError(
                f"the rig has {len(self.cameras)} camera(s); wand calibration needs at least two cameras"
            )
        if self.wand_markers is not None:
            self._set_wand_markers()
        if self.wand_length is not None:
            length = float(self.wand_length)
            if not np.isfinite(length) or length <= 0:
                raise CalibrationError(f"wand.length_m must be a positive length in metres, got {self.wand_length!r}")
            if not MIN_WAND_M <= length <= MAX_WORLD_M:
                raise CalibrationError(f"wand.length_m {length:.4g} is not a wand's length; give the distance between "
                                       f"its two marker centres in metres ({MIN_WAND_M:g} to {MAX_WORLD_M:g})")
            object.__setattr__(self, "wand_length", length)
        object.__setattr__(self, "cameras", tuple(self.cameras))
        if self.static_markers is not None:
            markers = np.asarray(self.static_markers, dtype=float)
            if markers.ndim != 2 or markers.shape[1] != 3 or len(markers) < 4 or not np.all(np.isfinite(markers)):
                raise CalibrationError(
                    "static_object.markers_m must be a list of at least 4 finite [x, y, z] points in metres"
                )
            _check_static_markers(markers)
            object.__setattr__(self, "static_markers", markers)

    def _set_wand_markers(self) -> None:
        from wandcal.calib.wandlayout import check_layout, span

        markers = check_layout(np.asarray(self.wand_markers, dtype=float))
        if self.wand_length is not None and abs(float(self.wand_length) - span(markers)) > LENGTH_AGREEMENT_M:
            raise CalibrationError(f"wand.length_m is {float(self.wand_length)!r} but wand.markers_m spans "
                                   f"{span(markers)!r} m between its extreme markers; give one, or make them agree")
        object.__setattr__(self, "wand_markers", markers)
        object.__setattr__(self, "wand_length", span(markers))

    @property
    def ids(self) -> list[str]:
        return [c.id for c in self.cameras]

    def index(self, camera_id: str) -> int:
        try:
            return self.ids.index(camera_id)
        except ValueError:
            raise CalibrationError(
                f"unknown camera id {camera_id!r}; rig.json lists {', '.join(self.ids)}"
            ) from None


def _check_static_markers(markers: np.ndarray) -> None:
    """The static object's markers (M, 3), metres: within the world's size, distinct, spanning a
    plane; each failure names static_object.markers_m and the markers."""
    where = "static_object.markers_m"
    if np.abs(markers).max() > MAX_WORLD_M:
        raise CalibrationError(f"{where}: a coordinate of {np.abs(markers).max():.4g} m is past {MAX_WORLD_M:g} m; give "
                               "the markers' positions in metres in the object's own frame")
    gaps = np.where(np.eye(len(markers), dtype=bool), np.inf, np.linalg.norm(markers[:, None] - markers[None], axis=-1))
    i, j = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[i, j] < MIN_MARKER_SEPARATION_M:
        raise CalibrationError(f"{where}: markers {min(i, j)} and {max(i, j)} are {gaps[i, j] * 1000:.3g} mm apart, "
                               "so they are one marker; give each marker's own position")
    try:
        spread = np.linalg.svd(markers - markers.mean(axis=0), compute_uv=False)
    except np.linalg.LinAlgError:
        spread = np.zeros(3)
    if spread[1] / np.sqrt(len(markers)) < MIN_MARKER_SPREAD_M:
        raise CalibrationError(f"{where}: the markers lie on one line, which fixes no orientation; give an object "
                               "whose markers span a plane (an L-frame)")


@dataclass(frozen=True, eq=False)
class WandObservations:
    """Unlabeled wand-marker blobs.

    Args:
        frame: (B,) int, synchronised frame-set index.
        camera: (B,) int, index into ``Rig.cameras``.
        uv: (B, 2) raw (distorted) pixel coordinates, origin top-left, y down.
    """

    frame: np.ndarray
    camera: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame", np.asarray(self.frame, dtype=np.int64).ravel())
        object.__setattr__(self, "camera", np.asarray(self.camera, dtype=np.int64).ravel())
        object.__setattr__(self, "uv", np.asarray(self.uv, dtype=float).reshape(-1, 2))
        if not (len(self.frame) == len(self.camera) == len(self.uv)):
            raise CalibrationError("wand observations: frame, camera and uv must have the same length")

    def __len__(self) -> int:
        return len(self.frame)


@dataclass(frozen=True, eq=False)
class StaticObservations:
    """Unlabeled static-object blobs, one averaged position per marker and camera.

    Args:
        camera: (S,) int, index into ``Rig.cameras``.
        uv: (S, 2) raw pixel coordinates.
    """

    camera: np.ndarray
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self) -> None:
        object.__setattr__(self, "camera", np.asarray(self.camera, dtype=np.int64).ravel())
        object.__setattr__(self, "uv", np.asarray(self.uv, dtype=float).reshape(-1, 2))
        if len(self.camera) != len(self.uv):
            raise CalibrationError("static observations: camera and uv must have the same length")

    def for_camera(self, index: int) -> np.ndarray:
        """(k, 2) the blobs seen by camera ``index``."""
        return self.uv[self.camera == index]


@dataclass(frozen=True, eq=False)
class PointObservations(WandObservations):
    """Point tracks (``points.csv``): the same 3D point for every camera that saw it in a frame.

    Unlabelled (``point`` None): one marker per camera and frame (an LED, a laser spot, easyWand's
    background points), and a frame is a 3D point. Labelled: several named points per frame
    (body keypoints, the markers of a rigid object), and a (point, frame) pair is a 3D point.

    Args:
        frame, camera, uv: as :class:`WandObservations`.
        point: (B,) str, each row's point name, or None for unlabelled rows; never partly empty.
    """

    point: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.point is None:
            return
        point = np.asarray(self.point, dtype=str).ravel()
        if len(point) != len(self.frame):
            raise CalibrationError("point observations: point must have one name per row")
        if len(point) and not np.all(np.char.str_len(np.char.strip(point)) > 0):
            raise CalibrationError("point observations: a row has an empty point name; name every point "
                                   "or none (points.csv's 'point' column)")
        object.__setattr__(self, "point", point)


AXIS_ROLES = ("origin", "+x", "+y", "+z")


@dataclass(frozen=True, eq=False)
class AxisObservations:
    """Axis points (``axis.csv``) that set the world frame without an L-frame: an origin and one
    or more points on the positive world axes, each seen by some cameras.

    Args:
        role: (A,) str, one of :data:`AXIS_ROLES`.
        camera: (A,) int, index into ``Rig.cameras``.
        uv: (A, 2) raw pixel coordinates.
    """

    role: np.ndarray
    camera: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "role", np.asarray(self.role, dtype=str).ravel())
        object.__setattr__(self, "camera", np.asarray(self.camera, dtype=np.int64).ravel())
        object.__setattr__(self, "uv", np.asarray(self.uv, dtype=float).reshape(-1, 2))
        if not (len(self.role) == len(self.camera) == len(self.uv)):
            raise CalibrationError("axis observations: role, camera and uv must have the same length")
        bad = sorted(set(self.role) - set(AXIS_ROLES))
        if bad:
            raise CalibrationError(f"axis point role {bad[0]!r} is not one of {', '.join(AXIS_ROLES)}")

    def __len__(self) -> int:
        return len(self.role)


VERTICAL_KINDS = ("floor", "drop")


@dataclass(frozen=True, eq=False)
class VerticalObservations:
    """Observations that set the world's vertical without an L-frame or axis points (as easyWand
    and Argus offer): points on the floor (``floor.csv``), or an object dropped or thrown through
    the volume (``drop.csv``), whose track's acceleration is gravity's.

    Args:
        kind: "floor" or "drop".
        key: (A,) int: the floor point each row sees (floor.csv's names, numbered in order of first
            appearance), or the frame of the dropped object (drop.csv's ``frame``).
        camera: (A,) int, index into ``Rig.cameras``.
        uv: (A, 2) raw pixel coordinates.
    """

    kind: str
    key: np.ndarray
    camera: np.ndarray
    uv: np.ndarray

    def __post_init__(self) -> None:
        if self.kind not in VERTICAL_KINDS:
            raise CalibrationError(f"vertical reference kind {self.kind!r} is not one of {', '.join(VERTICAL_KINDS)}")
        object.__setattr__(self, "key", np.asarray(self.key, dtype=np.int64).ravel())
        object.__setattr__(self, "camera", np.asarray(self.camera, dtype=np.int64).ravel())
        object.__setattr__(self, "uv", np.asarray(self.uv, dtype=float).reshape(-1, 2))
        if not (len(self.key) == len(self.camera) == len(self.uv)):
            raise CalibrationError(f"{self.kind} observations: key, camera and uv must have the same length")

    def __len__(self) -> int:
        return len(self.key)


# a message names at most this many cameras, then "and N more": six ids still read at a glance on
# one line (a 64-camera ring's 64 ids do not); the full list stays in each camera's own entry
LISTED_CAMERAS = 6


def camera_list(ids: list[str], rig_cameras: int) -> str:
    """Cameras named in a message, readable at any rig size: every id when there are at most
    :data:`LISTED_CAMERAS` ("cam1 and cam2"); "all 64 cameras" when they are the whole rig; else the
    first few and "and N more" ("cam1, ..., cam6 and 12 more"); the last two of a short list joined
    by "and" ("cam1 and cam3", "cam1, cam2 and cam3"). ids: in rig order; rig_cameras: how many
    cameras the rig has."""
    if len(ids) <= LISTED_CAMERAS:
        return " and ".join([", ".join(ids[:-1]), ids[-1]]) if len(ids) > 1 else ", ".join(ids)
    if len(ids) == rig_cameras:
        return f"all {rig_cameras} cameras"
    return f"{', '.join(ids[:LISTED_CAMERAS])} and {len(ids) - LISTED_CAMERAS} more"


def folded(lines: list[tuple[str, str | None, str]], folds: Callable[[list[str]], bool],
           render: Callable[[str, list[str]], str]) -> list[str]:
    """Messages about cameras with those that say the same of several folded into one line.
    lines: (text, key, camera id) in order, ``key`` the text with its camera left out (None: kept
    as it is). A key whose cameras (in order, repeats kept) ``folds`` is written once, as
    ``render(key, cameras)``, at its first line's place; every other line stays as it is."""
    cameras: dict[str, list[str]] = {}
    for _, key, cam_id in lines:
        if key is not None:
            cameras.setdefault(key, []).append(cam_id)
    out, done = [], set()
    for text, key, _ in lines:
        if key is None or not folds(cameras[key]):
            out.append(text)
        elif key not in done:
            done.add(key)
            out.append(render(key, cameras[key]))
    return out


def names_camera(text: str, camera_id: str) -> bool:
    """Whether a warning is about this camera: it starts with the camera's id, or quotes it
    ("cam3: ...", "cam3 saw ...", "camera 'cam3' ...")."""
    return text.startswith(camera_id + " ") or f"{camera_id}:" in text or f"'{camera_id}'" in text
