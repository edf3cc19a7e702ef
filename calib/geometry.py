"""Rotations, projection and undistortion on NumPy arrays.

Poses are world->camera, ``x_cam = R @ x_world + t`` (metres). Normalised image coordinates
are ``(x/z, y/z)`` of ``x_cam``; pixels are ``K @ [x/z, y/z, 1]`` after distortion.
"""

from __future__ import annotations

import cv2
import numpy as np

from wandcal.calib.rig import FISHEYE, Camera


def euler_to_matrix(angles: np.ndarray) -> np.ndarray:
    """R = Rz(gamma) @ Ry(beta) @ Rx(alpha), the seed paper's Euler convention.

    Args:
        angles: (..., 3) ``(alpha, beta, gamma)`` in radians.

    Returns:
        (..., 3, 3) rotation matrices.
    """
    a = np.asarray(angles, dtype=float)
    ca, sa = np.cos(a[..., 0]), np.sin(a[..., 0])
    cb, sb = np.cos(a[..., 1]), np.sin(a[..., 1])
    cg, sg = np.cos(a[..., 2]), np.sin(a[..., 2])
    R = np.empty(a.shape[:-1] + (3, 3))
    R[..., 0, 0] = cg * cb
    R[..., 0, 1] = cg * sb * sa - sg * ca
    R[..., 0, 2] = cg * sb * ca + sg * sa
    R[..., 1, 0] = sg * cb
    R[..., 1, 1] = sg * sb * sa + cg * ca
    R[..., 1, 2] = sg * sb * ca - cg * sa
    R[..., 2, 0] = -sb
    R[..., 2, 1] = cb * sa
    R[..., 2, 2] = cb * ca
    return R


def euler_jacobian(angles: np.ndarray) -> np.ndarray:
    """Derivatives of :func:`euler_to_matrix`.

    Args:
        angles: (..., 3) radians.

    Returns:
        (..., 3, 3, 3): element ``[..., k, :, :]`` is dR/d(angle k).
    """
    a = np.asarray(angles, dtype=float)
    zero = np.zeros(a.shape[:-1])
    one = np.ones(a.shape[:-1])

    def rot(c, s, axis):
        m = np.zeros(a.shape[:-1] + (3, 3))
        i, j = [(1, 2), (0, 2), (0, 1)][axis]
        k = 3 - i - j
        m[..., k, k] = one
        m[..., i, i] = c
        m[..., j, j] = c
        sign = -1 if axis != 1 else 1
        m[..., i, j] = sign * s
        m[..., j, i] = -sign * s
        return m

    ca, sa = np.cos(a[..., 0]), np.sin(a[..., 0])
    cb, sb = np.cos(a[..., 1]), np.sin(a[..., 1])
    cg, sg = np.cos(a[..., 2]), np.sin(a[..., 2])
    Rx, Ry, Rz = rot(ca, sa, 0), rot(cb, sb, 1), rot(cg, sg, 2)
    dRx, dRy, dRz = rot(-sa, ca, 0), rot(-sb, cb, 1), rot(-sg, cg, 2)
    for d, axis in ((dRx, 0), (dRy, 1), (dRz, 2)):
        i, j = [(1, 2), (0, 2), (0, 1)][axis]
        d[..., 3 - i - j, 3 - i - j] = zero
    out = np.empty(a.shape[:-1] + (3, 3, 3))
    out[..., 0, :, :] = Rz @ Ry @ dRx
    out[..., 1, :, :] = Rz @ dRy @ Rx
    out[..., 2, :, :] = dRz @ Ry @ Rx
    return out


def euler_rates(angles: np.ndarray) -> np.ndarray:
    """The left rotation increments of :func:`euler_to_matrix`'s angles: (..., 3, 3) whose column k is
    the w with ``dE/d(angle k) = [w]x E`` (so a point ``E Y`` moves by ``w x (E Y)``): the
    skew-symmetric ``dE_k E^T`` read as a vector.

    Args:
        angles: (..., 3) radians.
    """
    A = euler_jacobian(angles) @ np.swapaxes(euler_to_matrix(angles), -1, -2)[..., None, :, :]  # (..., k, 3, 3)
    return np.stack([A[..., 2, 1], A[..., 0, 2], A[..., 1, 0]], axis=-2)


def matrix_to_euler(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix` (beta in [-pi/2, pi/2]).

    Args:
        R: (..., 3, 3) rotation matrices.

    Returns:
        (..., 3) ``(alpha, beta, gamma)`` radians.
    """
    R = np.asarray(R, dtype=float)
    beta = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    alpha = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    gamma = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([alpha, beta, gamma], axis=-1)


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """(3,) axis-angle (radians) -> (3, 3) rotation."""
    return cv2.Rodrigues(np.asarray(rotvec, dtype=float).reshape(3, 1))[0]


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (3,) axis-angle (radians)."""
    return cv2.Rodrigues(np.asarray(R, dtype=float))[0].ravel()


def rotation_angle(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle of ``R_a @ R_b.T`` in radians; shapes (..., 3, 3) -> (...)."""
    rel = np.asarray(R_a) @ np.swapaxes(np.asarray(R_b), -1, -2)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    # atan2 of sine and cosine stays accurate for tiny angles, where arccos loses half the digits
    axis = np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0], rel[..., 1, 0] - rel[..., 0, 1]], -1)
    return np.arctan2(np.linalg.norm(axis, axis=-1) / 2.0, cos)


def camera_centers(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera centres ``C = -R.T @ t``; (N, 3, 3), (N, 3) -> (N, 3) metres."""
    return -np.einsum("nji,nj->ni", R, t)


def project_normalized(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Pinhole projection to normalised coordinates.

    Args:
        R: (M, 3, 3) or (3, 3) world->camera rotations.
        t: (M, 3) or (3,) translations, metres.
        X: (M, 3) world points, metres.

    Returns:
        (M, 2) normalised image coordinates ``(x/z, y/z)``.
    """
    xc = np.einsum("...ij,...j->...i", R, X) + t
    return xc[..., :2] / xc[..., 2:3]


def depth(R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """z of ``R @ X + t``; same broadcasting as :func:`project_normalized`, returns (M,)."""
    return np.einsum("...j,...j->...", R[..., 2, :], X) + t[..., 2]


def row_norms(a: np.ndarray) -> np.ndarray:
    """(M,) the Euclidean norm of each row of a (M, k), k a few columns: ``np.linalg.norm(a,
    axis=1)`` bit for bit (its sum of squares runs left to right over so few columns too) at a
    tenth of its cost on (M, 2), where numpy's reduction over a short inner axis goes row by row."""
    total = a[:, 0] * a[:, 0]
    for j in range(1, a.shape[1]):
        total += a[:, j] * a[:, j]
    return np.sqrt(total)


def finite_rows(a: np.ndarray) -> np.ndarray:
    """(M,) bool: the rows of a (M, k) whose every entry is finite (``np.all(np.isfinite(a),
    axis=1)``, column by column: a twentieth of its cost on (M, 2))."""
    ok = np.isfinite(a[:, 0])
    for j in range(1, a.shape[1]):
        ok &= np.isfinite(a[:, j])
    return ok


def sum_by(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, ...) the sums of ``values`` (k, ...) by ``index`` (k,) in 0..size-1 (ufunc.at's result,
    by one sort and ``np.add.reduceat``: several times faster)."""
    out = np.zeros((size, *values.shape[1:]))
    if not len(index):
        return out
    order = np.argsort(index, kind="stable")
    idx = index[order]
    starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
    out[idx[starts]] = np.add.reduceat(values[order], starts, axis=0)
    return out


def projection_derivative(Xc: np.ndarray) -> np.ndarray:
    """(K, 2, 3) the derivative of the normalised projection (x/z, y/z) in the camera-frame point Xc (K, 3)."""
    z = Xc[:, 2]
    D = np.zeros((len(z), 2, 3))
    D[:, 0, 0] = D[:, 1, 1] = 1 / z
    D[:, 0, 2] = -Xc[:, 0] / z**2
    D[:, 1, 2] = -Xc[:, 1] / z**2
    return D


def turn_response(Xc: np.ndarray) -> np.ndarray:
    """(K, 3, 3) the derivative of the turned point exp(w) Xc in the turn w at w = 0, -[Xc]x, at the
    camera-frame points Xc (K, 3): with :func:`projection_derivative`, a camera's turn columns."""
    cross = np.zeros((len(Xc), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 0] = Xc[:, 2], -Xc[:, 1], -Xc[:, 2]
    cross[:, 1, 2], cross[:, 2, 0], cross[:, 2, 1] = Xc[:, 0], Xc[:, 1], -Xc[:, 0]
    return cross


def undistort_points(camera: Camera, uv: np.ndarray) -> np.ndarray:
    """Raw pixels -> normalised, undistorted image coordinates.

    Args:
        camera: intrinsics.
        uv: (M, 2) raw pixels, origin top-left, y down.

    Returns:
        (M, 2) normalised coordinates ``(x/z, y/z)``.
    """
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    if camera.model == FISHEYE:
        out = cv2.fisheye.undistortPoints(pts, camera.K, camera.dist)
    else:
        # the default 5 iterations leave ~0.01 px errors at the image corners; iterate to 1e-12
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-12)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
            out = cv2.undistortPointsIter(pts, camera.K, camera.dist, None, None, criteria)
        else:  # OpenCV 5 folded the criteria into undistortPoints
            out = cv2.undistortPoints(pts, camera.K, camera.dist, criteria=criteria)
    return out.reshape(-1, 2)


def undistort_by_camera(cameras, camera: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """:func:`undistort_points` for observations of several cameras.

    Args:
        cameras: the rig's cameras; camera: (M,) index of each observation's camera.
        uv: (M, 2) or (M, 2, 2) raw pixels (a wand pair's two blobs per row).

    Returns:
        normalised coordinates, the shape of ``uv``.
    """
    uv = np.asarray(uv, dtype=float)
    xy = np.empty_like(uv)
    # each camera's rows by one sort, not a mask over all rows per camera (cameras x rows: 0.28 s
    # of the grouping's 0.5 s at 128 cameras x 3000 frames)
    order = np.argsort(camera, kind="stable")
    bounds = np.searchsorted(camera[order], np.arange(len(cameras) + 1))
    for c, cam in enumerate(cameras):
        sel = order[bounds[c] : bounds[c + 1]]
        if len(sel):
            xy[sel] = undistort_points(cam, uv[sel].reshape(-1, 2)).reshape(uv[sel].shape)
    return xy


def distort_points(camera: Camera, xy: np.ndarray) -> np.ndarray:
    """Normalised coordinates -> raw pixels (applies the lens model).

    Args:
        camera: intrinsics.
        xy: (M, 2) normalised coordinates.

    Returns:
        (M, 2) raw pixels.
    """
    pts = np.asarray(xy, dtype=np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    if camera.model == FISHEYE:
        out = cv2.fisheye.distortPoints(pts, camera.K, camera.dist)
    else:
        obj = np.concatenate([pts, np.ones((len(pts), 1, 1))], axis=2)
        out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    return out.reshape(-1, 2)


def project_pixels(camera: Camera, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
    """World points -> raw pixels through one camera; (3,3), (3,), (M,3) -> (M,2)."""
    return distort_points(camera, project_normalized(R, t, X))


def kabsch(source: np.ndarray, target: np.ndarray, scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Best rigid (or similarity) map ``target ~ s * R @ source + t`` in least squares (Umeyama).

    Args:
        source, target: (M, 3) corresponding points, M >= 3 and not collinear.
        scale: also fit a uniform scale.

    Returns:
        R (3, 3), t (3,), s.
    """
    mu_s, mu_t = source.mean(0), target.mean(0)
    a, b = source - mu_s, target - mu_t
    U, S, Vt = np.linalg.svd(b.T @ a)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / np.sum(a * a)) if scale else 1.0
    return R, mu_t - s * R @ mu_s, s
