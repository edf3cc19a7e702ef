"""Identify the static object's unlabeled markers in each camera and take its pose by PnP.

The blobs carry no labels. Every injective assignment of blobs to markers is tried; each gets a
PnP pose (SQPnP and P3P: IPPE would need a homography, which an L-frame's three collinear
markers do not determine) and its reprojection error. For a planar object the camera must be on
its +z side (above the floor), which removes the mirror-image pose. The assignment is accepted when its error is small and clearly below the next best.
For the common L-frame (three collinear markers with unequal spacing on the long arm, one on
the short arm) only one assignment fits a rigid pose.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from wandcal.calib.errors import Failure
from wandcal.calib.geometry import depth, kabsch, project_normalized, rotvec_to_matrix, undistort_points
from wandcal.calib.rig import Rig, StaticObservations
from wandcal.calib.triangulate import triangulate_points

MAX_ASSIGNMENTS = 50_000  # 8 markers seen by 5 blobs is 6720; beyond this the search is pointless
ACCEPT_RMS_PX = 3.0  # averaged static blobs are far better than this; a wrong labelling is far worse
AMBIGUITY_RATIO = 4.0  # a different pose fitting within this factor of the best is a real rival
MIN_RMS_PX = 0.05  # floor under the best fit's RMS when judging rivals (noise-free input fits to ~0)
SAME_POSE = 0.05  # camera centres closer than this fraction of the viewing distance are one pose
MIN_MARKERS = 4  # PnP with fewer points has several exact solutions
PLANAR_TOLERANCE = 1e-6  # relative thickness below which a marker set counts as planar
# Only labellings whose SQPnP pose fits within this factor of the best (or this many pixels) are
# refined: refining moves a start's error down, never up, and a rival must end within
# AMBIGUITY_RATIO of the best, while a wrong labelling starts hundreds of pixels off (16 cameras:
# 0.41 s -> 0.25 s)
SCREEN_RATIO = 30.0
SCREEN_PX = 30.0
# Markers on one line stay on one line in the image, in the same order (perspective keeps
# betweenness for points in front of the camera): a labelling that puts a collinear triple's
# blobs off a line, or its middle marker's blob outside the other two, is impossible and not
# tried. An L-frame's 24 labellings become 2 (16 cameras: 0.32 s -> 0.09 s; the same poses and
# labels on 640 simulated camera views). The 3D test is tight (a marker within 1 % of the triple's
# span from the line through the other two); the image test is loose, so that distortion left in
# the blobs or a grazing view never rejects the right labelling: it only spares the search
# labellings no pose can explain.
COLLINEAR_3D = 0.01
COLLINEAR_IMAGE = 0.05


@dataclass(frozen=True, eq=False)
class StaticPose:
    """One camera's pose from the static object.

    R: (3, 3), t: (3,) world->camera in the static object's frame (metres);
    labels: (k,) marker index of each blob (in the order of the camera's blobs);
    rms_px: reprojection RMS in pixels; runner_up_px: RMS of the best clearly different pose;
    alternatives: ((R, t), ...) different poses that fit within ``AMBIGUITY_RATIO`` of the best.
    """

    R: np.ndarray
    t: np.ndarray
    labels: np.ndarray
    rms_px: float
    runner_up_px: float
    alternatives: tuple = ()

    def __bool__(self) -> bool:
        return True

    @property
    def unique(self) -> bool:
        """False when another pose (the planar flip) fits nearly as well: use the wand to decide."""
        return not self.alternatives


def solve_static(rig: Rig, static: StaticObservations) -> list[StaticPose | Failure]:
    """PnP of every camera on the static object.

    Args:
        rig: must have ``static_markers``.
        static: unlabeled static blobs.

    Returns:
        One entry per camera: a :class:`StaticPose`, or a falsy :class:`Failure` saying why.
    """
    if rig.static_markers is None:
        return [Failure("the rig has no static object") for _ in rig.cameras]
    out: list[StaticPose | Failure] = []
    for c, cam in enumerate(rig.cameras):
        uv = static.for_camera(c)
        if len(uv) == 0:
            out.append(Failure(f"camera {cam.id!r} has no static-object blobs; make sure it sees the L-frame"))
            continue
        xy = undistort_points(cam, uv)
        out.append(identify_and_solve(rig.static_markers, xy, float(np.mean(cam.focal)), cam.id))
    return out


def identify_and_solve(markers: np.ndarray, xy: np.ndarray, focal_px: float, camera_id: str = "?") -> StaticPose | Failure:
    """Label the blobs and solve PnP.

    Args:
        markers: (M, 3) marker coordinates, metres.
        xy: (k, 2) normalised, undistorted blob coordinates.
        focal_px: focal length, to express the error in pixels.
        camera_id: for messages.
    """
    k, m = len(xy), len(markers)
    where = f"camera {camera_id!r}"
    if k < MIN_MARKERS:
        return Failure(f"{where} sees {k} static-object blob(s); at least {MIN_MARKERS} are needed for PnP")
    if k > m:
        return Failure(
            f"{where} sees {k} static-object blobs but the object has {m} markers; "
            "mask reflections or remove other bright objects and record the static object again"
        )
    n_assign = int(np.prod(range(m - k + 1, m + 1)))
    if n_assign > MAX_ASSIGNMENTS:
        return Failure(f"{where}: {n_assign} possible labellings of {k} blobs to {m} markers are too many to try")
    normal, lines = _object_shape(np.ascontiguousarray(markers, dtype=np.float64).tobytes(), m)
    # SQPnP on every possible labelling screens them; the survivors also get every P3P start (a
    # planar object's mirror pose, which SQPnP does not return)
    screened: list[tuple[float, np.ndarray, list]] = []  # (best SQPnP rms in pixels, labels, SQPnP's poses)
    for perm in itertools.permutations(range(m), k):
        labels = np.array(perm)
        if lines and not _keeps_lines(labels, xy, lines):
            continue
        sqpnp = _pnp_starts(markers[labels], xy, p3p=False)
        rms_each = [_rms_px(markers[labels], xy, R, t, focal_px) for R, t in sqpnp]
        screened.append((min(rms_each, default=np.inf), labels, sqpnp))
    if not screened:
        return Failure(
            f"{where}: the static-object markers cannot be identified: no labelling of its blobs puts the "
            "object's collinear markers on one line in the image; check static_object.markers_m in rig.json and "
            "that only its markers are visible"
        )
    screen = max(SCREEN_RATIO * min((f[0] for f in screened), default=0.0), SCREEN_PX)
    starts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (R, t, labels)
    for screened_rms, labels, sqpnp in screened:
        if screened_rms <= screen:  # the screen's SQPnP poses, then P3P's (not SQPnP again)
            starts += [(R, t, labels) for R, t in sqpnp + _pnp_starts(markers[labels], xy, sqpnp=False)]
    fits = []
    for R0, t0, labels in starts:
        R, t = _refined(markers[labels], xy, R0, t0)
        if np.any(depth(R, t, markers[labels]) <= 0):
            continue
        # cameras look down on a floor-mounted object: a pose below its plane is the mirror image
        if normal is not None and normal @ (-R.T @ t - markers[0]) <= 0:
            continue
        err = project_normalized(R, t, markers[labels]) - xy
        fits.append((float(np.sqrt(np.mean(np.sum(err**2, 1)))) * focal_px, R, t, labels))
    if not fits:
        return Failure(f"{where}: no labelling of the static-object blobs gives a pose in front of the camera")
    fits.sort(key=lambda f: f[0])
    rms, R, t, labels = fits[0]
    if rms > ACCEPT_RMS_PX:
        return Failure(
            f"{where}: the static-object markers cannot be identified (best fit {rms:.1f} px); "
            "check static_object.markers_m in rig.json and that only its markers are visible"
        )
    center = -R.T @ t
    scale = np.linalg.norm(center - markers.mean(0))
    distinct = [f for f in fits[1:] if np.linalg.norm(-f[1].T @ f[2] - center) > SAME_POSE * scale]
    runner = distinct[0][0] if distinct else np.inf
    close = tuple((f[1], f[2]) for f in distinct if f[0] < AMBIGUITY_RATIO * max(rms, MIN_RMS_PX))
    return StaticPose(R=R, t=t, labels=labels, rms_px=rms, runner_up_px=float(runner), alternatives=close)


@functools.lru_cache(maxsize=16)
def _object_shape(markers: bytes, m: int) -> tuple[np.ndarray | None, list[tuple[int, int, int]]]:
    """The static object's plane normal (:func:`_plane_normal`) and collinear triples
    (:func:`_collinear_triples`) of its ``m`` markers (float64 bytes), worked out once for every
    camera (0.04 s at 64 cameras)."""
    points = np.frombuffer(markers).reshape(m, 3)
    return _plane_normal(points), _collinear_triples(points)


def _collinear_triples(markers: np.ndarray) -> list[tuple[int, int, int]]:
    """(end, middle, end) marker indices of every triple on one line (:data:`COLLINEAR_3D`)."""
    out = []
    for tri in itertools.combinations(range(len(markers)), 3):
        p = markers[list(tri)]
        for mid in range(3):
            a, b = p[[i for i in range(3) if i != mid]]
            span = np.linalg.norm(b - a)
            s = (p[mid] - a) @ (b - a) / span**2 if span > 0 else -1.0
            if 0 < s < 1 and np.linalg.norm(a + s * (b - a) - p[mid]) <= COLLINEAR_3D * span:
                ends = [tri[i] for i in range(3) if i != mid]
                out.append((ends[0], tri[mid], ends[1]))
    return out


def _keeps_lines(labels: np.ndarray, xy: np.ndarray, lines: list[tuple[int, int, int]]) -> bool:
    """Whether the labelling ``labels`` (blob -> marker) puts every collinear triple it covers on
    an image line, its middle marker between the other two (:data:`COLLINEAR_IMAGE`)."""
    blob = {int(mk): b for b, mk in enumerate(labels)}
    for a, mid, c in lines:
        if a in blob and mid in blob and c in blob:
            pa, pm, pc = xy[blob[a]], xy[blob[mid]], xy[blob[c]]
            d = pc - pa
            span2 = float(d @ d)
            if span2 == 0:
                continue
            s = float((pm - pa) @ d) / span2
            off = abs(float(d[0] * (pm - pa)[1] - d[1] * (pm - pa)[0])) / span2  # distance / span
            if not (-COLLINEAR_IMAGE < s < 1 + COLLINEAR_IMAGE) or off > COLLINEAR_IMAGE:
                return False
    return True


def _rms_px(obj: np.ndarray, xy: np.ndarray, R: np.ndarray, t: np.ndarray, focal_px: float) -> float:
    if np.any(depth(R, t, obj) <= 0):
        return np.inf
    err = project_normalized(R, t, obj) - xy
    return float(np.sqrt(np.mean(np.sum(err**2, 1)))) * focal_px


def _pnp_starts(obj: np.ndarray, xy: np.ndarray, p3p: bool = True, sqpnp: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """Poses that may explain ``xy`` (k, 2) from ``obj`` (k, 3): SQPnP's (with ``sqpnp``), and every
    P3P solution on the least collinear triple (with ``p3p``; a planar object has two nearly equal
    poses, and SQPnP returns one)."""
    obj = np.ascontiguousarray(obj, dtype=np.float64)
    img = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 1, 2)
    K = np.eye(3)
    starts = []
    try:
        if sqpnp:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
            starts += list(zip(rvecs, tvecs))[:n]
    except cv2.error:
        pass
    if p3p:
        tri = _least_collinear_triple(obj)
        try:
            n, rvecs, tvecs = cv2.solveP3P(obj[tri], img[tri], K, None, flags=cv2.SOLVEPNP_P3P)
            starts += list(zip(rvecs, tvecs))[:n]
        except cv2.error:
            pass
    return [(rotvec_to_matrix(np.asarray(r, float)), np.asarray(t, dtype=float).ravel()) for r, t in starts]


def _refined(obj: np.ndarray, xy: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose refined by Levenberg-Marquardt on all points."""
    rvec, tvec = cv2.solvePnPRefineLM(np.ascontiguousarray(obj, dtype=np.float64),
                                      np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 1, 2),
                                      np.eye(3), None, cv2.Rodrigues(R)[0], t.reshape(3, 1).copy())
    return rotvec_to_matrix(rvec), np.asarray(tvec, dtype=float).ravel()


def _least_collinear_triple(obj: np.ndarray) -> list[int]:
    """The indices of the three points of ``obj`` (k, 3) that span the largest triangle."""
    obj = np.ascontiguousarray(obj, dtype=np.float64)
    return list(_largest_triangle(obj.tobytes(), len(obj)))


@functools.lru_cache(maxsize=256)
def _largest_triangle(obj: bytes, k: int) -> tuple[int, ...]:
    # every camera asks about the same few orderings of the static object's markers: 0.09 s of
    # np.cross at 64 cameras, answered once each
    points = np.frombuffer(obj).reshape(k, 3)
    best, area = (0, 1, 2), -1.0
    for tri in itertools.combinations(range(k), 3):
        a = float(np.linalg.norm(np.cross(points[tri[1]] - points[tri[0]], points[tri[2]] - points[tri[0]])))
        if a > area:
            best, area = tri, a
    return best


def _plane_normal(markers: np.ndarray) -> np.ndarray | None:
    """Unit normal (pointing to +z) of a planar marker set, or None when it is not planar."""
    centred = markers - markers.mean(0)
    _, s, vt = np.linalg.svd(centred)
    if s[2] > PLANAR_TOLERANCE * max(s[0], 1e-12):
        return None
    n = vt[2]
    return n if n[2] >= 0 else -n


KABSCH_STEP_M = 1e-7  # forward-difference step of the rigid fit in a marker's coordinates: far above
# rounding over metres, far below the markers' spacing


def static_frame_jacobian(R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray,
                          markers: np.ndarray) -> np.ndarray:
    """How the static object's frame follows each camera's pose: (6, N, 6).

    The frame is the rigid fit ``x_world = Rw x + tw`` of the markers triangulated from the
    static blobs (wandcal.calib.start.world's static fit). Rows: its small rotation phi
    (``Rw <- exp([phi]) Rw``, radians) and its translation (metres); columns: each camera's left
    rotation increment w (``R <- exp([w]) R``) and translation. Chained in closed form: a marker
    triangulated at its reprojection optimum moves by ``-H^-1 J_X^T J_c`` per camera increment
    (Gauss-Newton, H = sum J_X^T J_X over its views); the fit is differentiated numerically in
    the markers' 3M coordinates. Replaces 6N rebuilds of the frame by one triangulation.

    Args:
        R, t: (N, 3, 3), (N, 3) poses; point (K,), camera (K,), xy (K, 2): the identified static
            blobs' marker, camera and normalised coordinates; markers: (M, 3) the object's
            coordinates, metres.
    """
    M = len(markers)
    X = triangulate_points(R, t, point, camera, xy, M)
    ok = np.all(np.isfinite(X), axis=1)
    use = ok[point]
    point, camera = point[use], camera[use]
    Y = np.einsum("kij,kj->ki", R[camera], X[point])
    xc = Y + t[camera]
    iz = 1.0 / xc[:, 2]
    D = np.zeros((len(xc), 2, 3))  # d(x/z, y/z)/d(x_cam)
    D[:, 0, 0] = D[:, 1, 1] = iz
    D[:, :, 2] = -xc[:, :2] * (iz**2)[:, None]
    JX = D @ R[camera]  # (K, 2, 3)
    Yx = np.stack([np.cross(Y, e) for e in np.eye(3)], axis=2)  # [Y]x, column j = Y x e_j
    Jc = np.concatenate([-D @ Yx, D], axis=2)  # (K, 2, 6): x_cam moves by w x Y + dt
    H = np.zeros((M, 3, 3))
    np.add.at(H, point, np.swapaxes(JX, 1, 2) @ JX)
    H[~ok] = np.eye(3)
    dX = -np.linalg.solve(H[point], np.swapaxes(JX, 1, 2) @ Jc)  # (K, 3, 6): marker per camera increment
    Rw, tw, _ = kabsch(X[ok], markers[ok])
    dfit = np.zeros((6, M, 3))  # the frame per marker coordinate
    for m in np.flatnonzero(ok):
        for i in range(3):
            Xp = X.copy()
            Xp[m, i] += KABSCH_STEP_M
            Rn, tn, _ = kabsch(Xp[ok], markers[ok])
            dR = Rn @ Rw.T
            phi = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
            dfit[:, m, i] = np.r_[phi, tn - tw] / KABSCH_STEP_M
    out = np.zeros((6, len(R), 6))
    per_view = np.einsum("avk,vkj->vaj", dfit[:, point, :], dX)  # (K, 6, 6)
    for a in range(6):
        for j in range(6):
            out[a, :, j] = np.bincount(camera, per_view[:, a, j], minlength=len(R))
    return out

