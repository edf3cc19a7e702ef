"""How certain each camera's pose is, in the world frame the user gets.

``ba`` ends with the inverse of its reduced camera system: the covariance of the free cameras'
pose increments in the refinement's gauge (the first camera fixed, the scale set by the wand),
``sigma^2 (J^T J)^-1`` with the frames eliminated (:func:`pose_covariance`). The user's world
frame is itself estimated, from the same cameras (the static object or the axis points are
triangulated with them, the wand volume's centroid moves with them) and from its own markers,
whose positions carry their own noise. :func:`world_uncertainty` propagates both to first order:
a world pose moves with its own camera (in closed form) and with the world frame, whose six
degrees of freedom are differentiated through the very function that builds it (numerically, or
by the frame's own ``jacobian`` when it has one), and the frame's own noise is added.

``center_std`` is the 3D RMS, sqrt(trace) of the centre's covariance; ``rotation_std`` the RMS
angle, sqrt(trace) of the covariance of the rotation's small-angle vector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers, rotvec_to_matrix
from wandcal.calib.observations import robust_sigma

POSE_PARAMS = 6  # rotation increment (3), translation (3)
STEP_RAD = 1e-7  # finite-difference steps: far above rounding (1e-16 / 1e-7 ~ 1e-9 relative),
STEP_M = 1e-7  # far below the curvature of a rig's geometry over metres
# the static fit's RMS agrees with the static blobs' noise up to the 99th percentile of its
# chi-square: the standard normal's 99th percentile, for the Wilson-Hilferty approximation
FIT_AGREES_Z = 2.3263


@dataclass(frozen=True, eq=False)
class PoseCovariance:
    """The free cameras' pose covariance in the refinement's gauge.

    free: (K,) camera indices; cov: (6K, 6K) covariance of their increments (w, t): radians for
    the left rotation increment ``R <- exp([w]) R``, metres for t. centroid_response: (3, 6K)
    how the centroid of the wand midpoints follows those increments (the frames' own best
    response, -V^-1 W^T, averaged), and centroid_cov: (3, 3) its variance with the cameras held
    (both zero without a wand).
    """

    free: np.ndarray
    cov: np.ndarray
    centroid_response: np.ndarray
    centroid_cov: np.ndarray
    point_sigma_m: float = 0.0  # a single point's typical 1-sigma position error per axis with the cameras held


def fitted_sigma(radius_px: np.ndarray, n_par: int) -> float:
    """The residuals' noise per axis, pixels, from their 2D radii (M,) at a fit of ``n_par``
    parameters: the median radius of a 2D Gaussian is sigma sqrt(2 ln 2), and the residuals are
    smaller than the noise by the parameters fitted to them, so sigma^2 is RSS / (n - p), not
    RSS / n (n = 2M; at 6 x 600 the difference is 12% in every standard error)."""
    n_res = 2 * len(radius_px)
    return robust_sigma(radius_px) * np.sqrt(n_res / max(n_res - n_par, 1))


def pose_covariance(normal, step, sigma: float, free: np.ndarray, frozen: list[tuple[int, int]],
                    wand_term: int | None) -> PoseCovariance:
    """Assemble :class:`PoseCovariance` from an undamped solve of the normal equations.

    Args:
        normal, step: :class:`wandcal.calib.solve.backend.schur.Normal` and the :class:`wandcal.calib.solve.backend.schur.Step` solved from it
            with no damping.
        sigma: the residuals' noise per axis, pixels (the Jacobian's rows are in pixels).
        free: (K,) the cameras in the system; frozen: (k, j) parameters held by the gauge.
        wand_term: index of the wand term among ``normal.terms``, or None.
    """
    K, c = step.dc.shape
    full = (sigma**2 * step.cam_cov).reshape(K, c, K, c)
    for k, j in frozen:
        full[k, j, :, :] = 0.0
        full[:, :, k, j] = 0.0
    cov = full[:, :POSE_PARAMS, :, :POSE_PARAMS].reshape(K * POSE_PARAMS, K * POSE_PARAMS)
    response = np.zeros((3, K, c))
    centroid_cov = np.zeros((3, 3))
    F = 0
    if wand_term is not None:
        blocks, Vinv = normal.terms[wand_term], step.pt_inv[wand_term]
        s = blocks.structure
        F = len(Vinv)
        if F:
            # each frame's midpoint follows the cameras by -V^-1 W^T dc; the centroid by their mean
            per_pair = -np.einsum("kij,klj->kil", Vinv[s.pair_pt][:, :3, :], blocks.W) / F  # (pairs, 3, c)
            for j in range(3):
                for i in range(c):
                    response[j, :, i] = np.bincount(s.pair_cam, per_pair[:, j, i], minlength=K)
            centroid_cov = sigma**2 * Vinv[:, :3, :3].sum(0) / F**2
            # a wand midpoint averages two ends: a single point seen as often is sqrt(2) worse
            point_sigma = np.sqrt(2.0) * sigma * float(np.median(np.sqrt(np.einsum("fii->f", Vinv[:, :3, :3]) / 3)))
    response = response[:, :, :POSE_PARAMS].reshape(3, K * POSE_PARAMS)
    return PoseCovariance(np.asarray(free), cov, response, centroid_cov, point_sigma if wand_term is not None and F else 0.0)


def world_uncertainty(R: np.ndarray, t: np.ndarray, pc: PoseCovariance, frame, frame_cov: np.ndarray | None = None,
                      frame_origin: np.ndarray | None = None, full: bool = False):
    """Per-camera centre and rotation uncertainty in the world frame.

    Args:
        R, t: (N, 3, 3), (N, 3) refined poses in the gauge frame.
        pc: their covariance.
        frame: callable(R, t, centroid_shift (3,)) -> (Rw (3, 3), tw (3,)), the map
            ``x_world = Rw x + tw`` built from those poses (and the wand centroid moved by the
            shift), exactly as the result's world frame is built. It may carry ``jacobian(R, t)``
            -> (6, N, 6), the frame's small rotation (``Rw <- exp([phi]) Rw``) and translation per
            camera's (w, t) increment; without one, the frame is rebuilt once per free camera
            parameter.
        frame_cov: (6, 6) covariance of the world frame's own small rotation (radians, about the
            world axes at ``frame_origin``) and translation (metres), from its markers' noise; see
            :func:`registration_covariance`. None when the frame has no noise of its own.
        frame_origin: (3,) the world point that rotation is about (the markers' centroid).

    Returns:
        (center_std (N,) metres, rotation_std (N,) radians); with ``full``, also the whole
        (N, 6, N, 6) covariance of every camera's world centre (metres) and small rotation
        (radians, camera side), the frame's own noise included, for the geometry/placement split.
    """
    n = len(R)
    free = np.asarray(pc.free)
    K = len(free)
    Rw, tw = frame(R, t, np.zeros(3))
    base_C = camera_centers(R, t) @ Rw.T + tw
    base_R = R @ Rw.T  # the world-frame rotations
    # a world pose moves with its own camera (a block per free camera) and with the frame, which
    # follows every camera and the wand's centroid: G = direct + A F, the frame's 6 DOF between
    Aw = _world_response(R, Rw, base_C - tw)  # (6N, 6)
    Fm = np.stack([_frame_change(frame(R, t, STEP_M * e), Rw, tw) / STEP_M for e in np.eye(3)], axis=1)  # (6, 3)
    F = _frame_jacobian(frame, R, t, free, Rw, tw) + Fm @ pc.centroid_response  # (6, 6K)
    # G = Aw F + D (D: a 6 x 6 block per free camera) taken apart, so that G C G^T costs O(N^2)
    # and not the dense (6N)^3 products (0.2 s at 128 cameras)
    D = _direct_blocks(R[free], t[free], Rw)  # (K, 6, 6)
    DC = np.einsum("kab,kbm->kam", D, pc.cov.reshape(K, POSE_PARAMS, -1)).reshape(K * 6, -1)  # D C, (6K, 6K)
    DCD = np.einsum("kalc,ldc->kald", DC.reshape(K, 6, K, POSE_PARAMS), D)  # D C D^T, (K, 6, K, 6)
    FC = F @ pc.cov  # (6, 6K)
    AwFCD = Aw @ np.einsum("alc,ldc->ald", FC.reshape(6, K, POSE_PARAMS), D).reshape(6, K * 6)  # Aw F C D^T, (6N, 6K)
    cov = Aw @ (FC @ F.T) @ Aw.T  # (6N, 6N)
    cov4 = cov.reshape(n, 6, n, 6)
    cross = AwFCD.reshape(n, 6, K, 6)
    cov4[:, :, free, :] += cross
    cov4[free, :, :, :] += cross.transpose(2, 3, 0, 1)
    cov4[np.ix_(free, np.arange(6), free, np.arange(6))] += DCD
    if np.any(pc.centroid_cov):
        Gm = Aw @ Fm
        cov += Gm @ pc.centroid_cov @ Gm.T
    if frame_cov is not None:
        # the frame's own error moves every camera together: fully correlated between them
        A = frame_response(base_C, base_R, frame_origin).reshape(n * 6, 6)
        cov += A @ frame_cov @ A.T
    cov = cov.reshape(n, 6, n, 6)
    blocks = cov[np.arange(n), :, np.arange(n), :]  # (N, 6, 6)
    center = np.sqrt(np.maximum(np.einsum("nii->n", blocks[:, :3, :3]), 0.0))
    rotation = np.sqrt(np.maximum(np.einsum("nii->n", blocks[:, 3:, 3:]), 0.0))
    return (center, rotation, cov) if full else (center, rotation)


def _frame_change(frame_value, Rw: np.ndarray, tw: np.ndarray) -> np.ndarray:
    """(6,) a moved frame ``(Rw', tw')`` against ``(Rw, tw)``: the small angle phi of
    ``Rw' = exp([phi]) Rw`` (the skew part, exact to second order) and ``tw' - tw``."""
    Rn, tn = frame_value
    dR = Rn @ Rw.T
    return np.r_[0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]), tn - tw]


def _frame_jacobian(frame, R: np.ndarray, t: np.ndarray, free: np.ndarray, Rw: np.ndarray, tw: np.ndarray) -> np.ndarray:
    """(6, 6K) the frame's (phi, tau) per free camera's increment (w, t): the frame's own
    ``jacobian(R, t)`` (6, N, 6) when it has one, else a forward difference per parameter (6K
    rebuilds of the frame)."""
    jacobian = getattr(frame, "jacobian", None)
    if jacobian is not None:
        return np.asarray(jacobian(R, t))[:, free].reshape(6, -1)
    F = np.zeros((6, len(free) * POSE_PARAMS))
    for k, cam in enumerate(free):
        for j in range(POSE_PARAMS):
            h = STEP_RAD if j < 3 else STEP_M
            Rp, tp = R.copy(), t.copy()
            if j < 3:
                Rp[cam] = rotvec_to_matrix(h * np.eye(3)[j]) @ R[cam]
            else:
                tp[cam, j - 3] += h
            F[:, k * POSE_PARAMS + j] = _frame_change(frame(Rp, tp, np.zeros(3)), Rw, tw) / h
    return F


def _world_response(R: np.ndarray, Rw: np.ndarray, turned_C: np.ndarray) -> np.ndarray:
    """(6N, 6) what the frame's (phi, tau) does to each camera's world centre and rotation:
    dC = -[Rw C]x phi + tau (``turned_C``: (N, 3) Rw C); the camera's world rotation R Rw^T turns by
    -R Rw^T phi."""
    out = np.zeros((len(R), 6, 6))
    out[:, :3, :3] = -_skew(turned_C)
    out[:, :3, 3:] = np.eye(3)
    out[:, 3:, :3] = -(R @ Rw.T)
    return out.reshape(-1, 6)


def _direct_blocks(R: np.ndarray, t: np.ndarray, Rw: np.ndarray) -> np.ndarray:
    """(K, 6, 6) each camera's world centre and rotation per its own increment (w, t), the frame
    held: C = -R^T t moves by -R^T [t]x w - R^T dt (times Rw), the rotation by w."""
    RwRt = Rw @ np.swapaxes(R, 1, 2)
    out = np.zeros((len(R), 6, 6))
    out[:, :3, :3] = -RwRt @ _skew(t)
    out[:, :3, 3:] = -RwRt
    out[:, 3:, :3] = np.eye(3)
    return out


def _skew(v: np.ndarray) -> np.ndarray:
    """(K, 3, 3) cross-product matrices of (K, 3) vectors."""
    out = np.zeros((len(v), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def registration_covariance(points: np.ndarray, sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Covariance of a rigid fit to ``points`` (M, 3) with isotropic noise ``sigma_m`` per
    coordinate: the small rotation about their centroid (3, 3), radians, and the centroid's
    translation (3, 3), metres, which are uncorrelated (Kanatani; Horn's closed form, linearised).
    Returns (frame_cov (6, 6) in the order rotation, translation, centroid (3,))."""
    centroid = points.mean(0)
    q = points - centroid
    inertia = np.einsum("mi,mi->", q, q) * np.eye(3) - q.T @ q
    cov = np.zeros((6, 6))
    # pinv: with two points the turn about their line is not set by them (the caller's frame
    # takes it from elsewhere, a camera, and its part is in the numerical derivative)
    cov[:3, :3] = sigma_m**2 * np.linalg.pinv(inertia)
    cov[3:, 3:] = sigma_m**2 / len(points) * np.eye(3)
    return cov, centroid


def frame_response(centers: np.ndarray, R: np.ndarray, origin: np.ndarray | None = None) -> np.ndarray:
    """(N, 6, 6) what a small error of the world frame itself (rotation phi about ``origin``,
    translation tau) does to each camera's world centre and its rotation, camera side like every
    rotation here (``R <- exp([w]) R``): dC = -[C - origin]x phi + tau (the frame turns, the camera
    appears turned the other way), w = -R phi. R: (N, 3, 3) the cameras' world rotations. The same
    map is the rig's rigid gauge freedom (:mod:`wandcal.calib.solve.gauge_free`)."""
    d = centers - (np.zeros(3) if origin is None else origin)
    out = np.zeros((len(centers), 6, 6))
    out[:, 0, 1], out[:, 0, 2] = d[:, 2], -d[:, 1]  # -[d]x
    out[:, 1, 0], out[:, 1, 2] = -d[:, 2], d[:, 0]
    out[:, 2, 0], out[:, 2, 1] = d[:, 1], -d[:, 0]
    out[:, :3, 3:] = np.eye(3)
    out[:, 3:, :3] = -R
    return out


def chi2_quantile(dof: int, z: float = FIT_AGREES_Z) -> float:
    """The chi-square quantile of ``dof`` degrees of freedom at the normal quantile ``z``, by
    Wilson and Hilferty's cube-root approximation (16.84 for the 99th percentile at 6 degrees of
    freedom, exactly 16.81): a calibration loads no scipy."""
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * np.sqrt(a)) ** 3


def frame_noise(world: dict, rig, points_world: np.ndarray | None, pc: PoseCovariance):
    """The world frame's own noise: (frame_cov (6, 6), origin (3,)), or (None, None).

    - static object: a rigid fit to its markers, each coordinate off by the fit's residual spread
      (a 3D RMS, times sqrt(M / (3M - 6)) for the six fitted degrees of freedom). That spread is
      ``expected_fit_rms_m`` (wandcal.calib.start.world.static_fit_expectation: the static blobs' own noise,
      known from ~50 degrees of freedom) when the fit's own ``fit_rms_m`` agrees with it (at most
      its 99th percentile); otherwise the markers sit off their given coordinates too, and the
      fit's own RMS, which holds the blobs' noise and the placement errors alike, is used;
    - axis points: a fit to the triangulated points, each as uncertain as a single triangulated
      point (``pc.point_sigma_m``);
    - a frame built from the cameras and the wand alone has no noise of its own beyond theirs.

    points_world: (M, 3) the static markers or axis points in the world frame, or None.
    """
    if world.get("frame") == "static_object" and points_world is not None:
        M = len(points_world)
        dof = max(3 * M - 6, 1)
        # fit_rms is a 3D RMS over M markers: E[fit_rms^2] = sigma^2 (3M - 6) / M per coordinate
        rms = float(world.get("fit_rms_m", 0.0))
        expected = world.get("expected_fit_rms_m")
        if expected and rms**2 <= expected**2 * chi2_quantile(dof) / dof:
            rms = float(expected)  # the same noise, known from ~50 degrees of freedom instead of 6
        return registration_covariance(points_world, rms * np.sqrt(M / dof))
    if world.get("frame") == "axis" and points_world is not None and pc.point_sigma_m > 0:
        return registration_covariance(points_world, pc.point_sigma_m)
    return None, None
