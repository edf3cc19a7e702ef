"""The wand problem's pixel residuals with every frame's parameters projected out.

At one state of a :class:`wandcal.calib.solve.wandmodel.WandModel`, each frame's 5 wand parameters are fitted
by least squares on its kept rows (points are independent once the cameras are known), which
leaves each residual row an affine function of the free cameras' parameters only:
``z_i(d) = a_i . d + b_i``, d (6 per free camera: 3 rotation increments, 3 translations). Row i
touches every camera that sees its frame. The LP method (calib/solve/lp/) steps on these rows.
"""

from __future__ import annotations

import copy

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from wandcal.calib.geometry import euler_rates
from wandcal.calib.observations import robust_sigma
from wandcal.calib.solve.robustloss import REJECT_SIGMAS, capped_loss
from wandcal.calib.solve.uncertainty import POSE_PARAMS, PoseCovariance
from wandcal.calib.solve.wandmodel import CAM_PARAMS, FRAME_PARAMS, WandModel

FRAME_RIDGE = 1e-9  # added to each frame's normal matrix (pixels^2 per unit^2), which is singular where
# its kept rows fix fewer than its 5 parameters (a frame seen by one camera, or its rows rejected)
SCHUR_RIDGE = 1e-9  # times the mean diagonal, added to the cameras' Schur complement before it is
# factorised: a camera no kept row constrains would leave it singular


def robust_scale(r: np.ndarray) -> float:
    """Per-axis noise from (M, 2) residuals: the median radius of a 2D Gaussian is sigma sqrt(2 ln 2)."""
    return max(robust_sigma(np.linalg.norm(r, axis=1)), 1e-9)


def residual_cost(r: np.ndarray, scale: float, loss) -> float:
    """The merit of residuals r (pixels, any shape): the loss in units of ``scale``, capped at the
    rejection point. Of raw residuals at a state whose frames were just moved by the elimination
    (:meth:`ReducedSystem.apply`), it is the projected merit to second order in the step, with no
    relinearisation (a Jacobian and elimination cost ~0.2 s at 32 x 2000, residuals ~0.01 s)."""
    z = np.ravel(r) / scale
    return float(capped_loss(z, np.abs(z) <= REJECT_SIGMAS, loss).sum())


def outer(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(M, k, i), (M, k, j) -> (M, i, j): sum_k A[:, k, i] B[:, k, j] (matmul is ~8x einsum here)."""
    return np.matmul(A.swapaxes(1, 2), B)


def apply(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, k, j), (M, j) -> (M, k) (einsum is ~3x a batched matmul of matrix-vector products)."""
    return np.einsum("mkj,mj->mk", A, v)


def apply_t(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, k, i), (M, k) -> (M, i): A^T v per observation."""
    return np.einsum("mki,mk->mi", A, v)


def _incidence(model: WandModel) -> dict:
    """Sparse sums over observations by frame, camera and (frame, camera), cached on the model
    (np.add.at is several times slower at these sizes)."""
    cache = getattr(model, "_slp_incidence", None)
    if cache is None:
        p = model.p
        M = len(p.camera)
        ones = np.ones(M)
        obs = np.arange(M)
        cache = {
            "frame": sp.csr_matrix((ones, (p.frame, obs)), shape=(p.n_frames, M)),
            "camera": sp.csr_matrix((ones, (p.camera, obs)), shape=(p.n_cams, M)),
            "frame_camera": sp.csr_matrix((ones, (p.frame * p.n_cams + p.camera, obs)), shape=(p.n_frames * p.n_cams, M)),
            "by_camera": np.argsort(p.camera, kind="stable"),
        }
        cache["camera_bounds"] = np.searchsorted(p.camera[cache["by_camera"]], np.arange(p.n_cams + 1))
        model._slp_incidence = cache
    return cache


def camera_grams(model: WandModel, C: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(N, 6, 6) each camera's sum of C^T diag(w) C over its observations' blocks C (M, 2, 6),
    weights w (M, 2) >= 0: one small product per camera over its rows gathered together (0.06 s at
    128 x 3000 against 0.12-0.20 s for per-observation outer products summed by camera)."""
    inc = _incidence(model)
    rows = (C * np.sqrt(w)[:, :, None])[inc["by_camera"]].reshape(-1, C.shape[2])
    bounds = 2 * inc["camera_bounds"]
    return np.stack([rows[a:b].T @ rows[a:b] for a, b in zip(bounds[:-1], bounds[1:])])


def sum_by(model: WandModel, key: str, values: np.ndarray) -> np.ndarray:
    """Sum (M, ...) per-observation values by frame, camera or (frame, camera)."""
    M = values.shape[0]
    out = _incidence(model)[key] @ values.reshape(M, -1)
    return np.asarray(out)


class ReducedSystem:
    """Residuals with each frame's parameters eliminated, at one state of a WandModel.

    Args:
        model: the wand problem.
        x: (n_params,) state.
        scale: robust scale (pixels) that decides which rows are kept; the residuals' own when None.
    """

    def __init__(self, model: WandModel, x: np.ndarray, scale: float | None = None):
        self.model, self.x = model, x
        self.r, blocks, cols = model.linearised(x)
        self.own = cols[:, 0] >= 0  # the observation's camera is free
        self.cam_cols = cols[:, :CAM_PARAMS]
        self.C = blocks[:, :, :CAM_PARAMS]  # (M, 2, 6)
        self.F = blocks[:, :, CAM_PARAMS:]  # (M, 2, 5)
        self.free_cols = (model.free[:, None] * CAM_PARAMS + np.arange(CAM_PARAMS)).ravel()
        self._set_scale(robust_scale(self.r) if scale is None else scale)

    def _set_scale(self, scale: float, by: np.ndarray | None = None) -> None:
        self.scale = scale
        self.kept = np.abs(self.r if by is None else by) <= REJECT_SIGMAS * self.scale  # (M, 2)
        self._schur_cache: tuple[np.ndarray, np.ndarray] | None = None  # (S, its right-hand side)
        self._se_cache: np.ndarray | None = None
        self._factor_cache: tuple[np.ndarray, bool] | None = None  # sla.cho_factor's (factor, lower)
        self._inv_cache: np.ndarray | None = None
        self._eliminate()

    def rescaled(self, scale: float, by: np.ndarray | None = None) -> ReducedSystem:
        """The same state with another robust scale (other kept rows), without relinearising.

        Args:
            scale: robust scale, pixels.
            by: (M, 2) residuals that decide which rows are kept, the state's own when None; the
                projected residuals ``b`` where the frames are far from fitted to the cameras
                (their raw residuals would keep gross outliers, or drop good rows).
        """
        out = copy.copy(self)
        out._set_scale(scale, by)
        return out

    def cost(self, scale: float, loss) -> float:
        """The merit of these cameras: the loss (capped at the rejection point) of the residuals
        with every frame re-fitted to them. The frames are projected out (variable projection),
        so this is what the LP's model predicts at d = 0."""
        return residual_cost(self.b, scale, loss)

    def model_cost(self, d: np.ndarray, loss) -> float:
        """The LP's model at step d: kept rows linearised, rejected rows at their cap."""
        return self.model_loss(self.b + self.change(d), loss)

    def model_loss(self, z: np.ndarray, loss) -> float:
        """The LP's model at linearised residuals z (M, 2) pixels, ``b + change(d)`` for a step
        d (change is linear, so a caller that has it for two steps has it for their mean)."""
        return float(capped_loss(z.ravel() / self.scale, self.kept.ravel(), loss).sum())

    def standard_errors(self) -> np.ndarray:
        """(n_cam_params,) standard errors of the camera parameters from the reduced normal
        equations and the robust scale (valid near the optimum). Cached."""
        if self._se_cache is None:
            self._se_cache = self.scale * np.sqrt(np.maximum(np.diag(self._schur_inverse()), 0.0))
        return self._se_cache

    def _schur_inverse(self) -> np.ndarray:
        """S^-1 of the free cameras (the reduced normal matrix's inverse), cached."""
        if self._inv_cache is None:
            self._inv_cache = np.linalg.inv(self._schur()[0])
        return self._inv_cache

    def pose_covariance(self, sigma: float, n_wand_frames: int) -> PoseCovariance:
        """The free cameras' pose covariance from this linearisation, as ``ba``'s information
        matrix gives it (calib/solve/uncertainty.py): sigma^2 S^-1, S the kept rows' Gauss-Newton
        Schur complement of the frames (the one the steps and standard errors already use: no
        other linearisation), taken from this model's Euler increments about R0 to ba's left
        rotation increments (w = B d, B from geometry.euler_rates). The first ``n_wand_frames``
        frames are the wand's (the rest are point tracks, calib/refine.with_tracks): the
        centroid's response and variance and a point's sigma are theirs.

        Args:
            sigma: the residuals' noise per axis, pixels.
            n_wand_frames: how many of the model's frames are wand frames.
        """
        m = self.model
        free, K = m.free, len(m.free)
        B = np.zeros((K, CAM_PARAMS, CAM_PARAMS))
        B[:, :3, :3] = euler_rates(m.unpack(self.x)[0][free])  # w_i per d(delta_k)
        B[:, 3:, 3:] = np.eye(3)
        cov_d = (sigma**2 * self._schur_inverse()).reshape(K, CAM_PARAMS, K, CAM_PARAMS)
        cov = np.einsum("kab,kblc,ldc->kald", B, cov_d, B).reshape(K * POSE_PARAMS, K * POSE_PARAMS)
        F = n_wand_frames
        response, centroid_cov, point_sigma = np.zeros((3, K * POSE_PARAMS)), np.zeros((3, 3)), 0.0
        if F:
            # each frame's midpoint follows the cameras by -H_f^-1 G_f d (calib/solve/reduced.apply)
            G = self.Gf[: F * FRAME_PARAMS].reshape(F, FRAME_PARAMS, -1)
            per_d = -np.einsum("fij,fjc->ic", self.Hinv[:F, :3, :], G)[:, self.free_cols] / F  # (3, 6K)
            Binv = np.linalg.inv(B)
            response = np.einsum("ikb,kba->ika", per_d.reshape(3, K, CAM_PARAMS), Binv).reshape(3, -1)
            mid = self.Hinv[:F, :3, :3]
            centroid_cov = sigma**2 * mid.sum(0) / F**2
            # a wand midpoint averages two ends: a single point seen as often is sqrt(2) worse
            point_sigma = np.sqrt(2.0) * sigma * float(np.median(np.sqrt(np.einsum("fii->f", mid) / 3)))
        return PoseCovariance(free.copy(), cov, response, centroid_cov, point_sigma)

    def _eliminate(self) -> None:
        """Per-frame elimination: K (M,2,5), g (F,5), Hinv (F,5,5), b (M,2); Gf on first use."""
        p = self.model.p
        # plain least squares on the kept rows: weights that moved with the residuals would make
        # the frames' fit an iteration of its own, and the projected merit would drift under it
        Wt = self.kept.astype(float)
        self.Wt = Wt
        FW = self.F * Wt[:, :, None]
        m = self.model
        H = sum_by(m, "frame", outer(FW, self.F)).reshape(-1, FRAME_PARAMS, FRAME_PARAMS)
        g = sum_by(m, "frame", apply_t(FW, self.r))
        Hinv = np.linalg.inv(H + FRAME_RIDGE * np.eye(FRAME_PARAMS))
        self.K = np.matmul(self.F, Hinv[p.frame])
        self.Hf, self.Hinv, self.g = H, Hinv, g
        self.b = self.r - apply(self.K, g[p.frame])
        self._Gf: np.ndarray | None = None

    @property
    def Gf(self) -> np.ndarray:
        """(F*5, N*6) each frame's camera coupling ``sum F^T W C`` with its rows stacked, the operand
        of the normal equations' products. Formed on first use: a system only rescaled (the start
        of an lp phase, which needs its projected residuals b alone) never forms it (~350 MB of
        temporaries at 128 x 3000, decision 0024)."""
        if self._Gf is None:
            p, m = self.model.p, self.model
            G = sum_by(m, "frame_camera", outer(self.F * self.Wt[:, :, None], self.C))
            G = G.reshape(p.n_frames, p.n_cams, FRAME_PARAMS, CAM_PARAMS)
            self._Gf = np.ascontiguousarray(G.transpose(0, 2, 1, 3)).reshape(-1, p.n_cams * CAM_PARAMS)
        return self._Gf

    def gauss_newton_step(self) -> np.ndarray:
        """The weighted least-squares step of the reduced system, (n_cam_params,)."""
        return -self.schur_solve(self._schur()[1])

    def schur_solve(self, g: np.ndarray) -> np.ndarray:
        """S^-1 g, (n_cam_params,), with S the Schur complement of the frames (the Gauss-Newton
        normal matrix, plus ``SCHUR_RIDGE``); its Cholesky factor is cached."""
        if self._factor_cache is None:
            S = self._schur()[0]
            self._factor_cache = sla.cho_factor(S + SCHUR_RIDGE * np.trace(S) / len(S) * np.eye(len(S)), lower=True,
                                                check_finite=False)
        # two triangular solves (np.linalg.solve on the factor took an LU of it: 20 ms at 762 unknowns)
        return sla.cho_solve(self._factor_cache, g, check_finite=False)

    def _schur(self) -> tuple[np.ndarray, np.ndarray]:
        """Reduced normal matrix and gradient of the free cameras: the Schur complement of the
        frames, :meth:`normal_equations` with the elimination's own weights. Cached.

        With those weights X_f = R^-1 G_f and Q_f = R^-1 H_f R^-1 (R = H_f + eps I, the
        elimination's regularised frame matrix), so the frame terms are -G_f^T M_f G_f with
        M_f = 2 R^-1 - Q_f = R^-1 (H_f + 2 eps I) R^-1: one symmetric product Z^T Z, Z_f = D V^T G_f
        from H_f = V diag(l) V^T, D = sqrt(l + 2 eps) / (l + eps) (positive definite also where a
        frame's rows leave it singular), and two of the three per-observation products of the
        general weights are not needed."""
        if self._schur_cache is None:
            m, p = self.model, self.model.p
            free = self.free_cols
            CC = camera_grams(m, self.C, self.Wt * self.own[:, None])[m.free]
            lam, V = np.linalg.eigh(self.Hf)
            lam = np.maximum(lam, 0.0)
            D = np.sqrt(lam + 2 * FRAME_RIDGE) / (lam + FRAME_RIDGE)
            # on every camera's columns, the fixed ones' dropped from the product: no (F*5, n) copy of
            # the free columns (0.07 s at 128 x 3000) for 1% more of the product
            Z = np.matmul(V.swapaxes(1, 2), self.Gf.reshape(p.n_frames, FRAME_PARAMS, -1))
            Z *= D[:, :, None]  # in place: one (F*5, n) array fewer (91 MB at 128 x 3000)
            Z = Z.reshape(-1, self.Gf.shape[1])
            S = -(Z.T @ Z)[np.ix_(free, free)]
            idx = np.arange(len(m.free))
            S.reshape(len(idx), CAM_PARAMS, len(idx), CAM_PARAMS)[idx, :, idx, :] += CC
            self._schur_cache = S, self.folded_cost(self.Wt * self.b)
        return self._schur_cache

    def normal_equations(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``A^T W A`` (n_cam_params, n_cam_params) and ``A^T W b`` (n_cam_params,) of the
        reduced rows with row weights w (M, 2), the frames still eliminated with the kept rows'
        least squares. With a_i = C_i P - K_i G_f (P: the row's own camera), per frame
            A^T W A = sum C^T W C - X_f^T G_f - G_f^T X_f + G_f^T Q_f G_f,
        X_f = sum K^T W C by (frame, camera), Q_f = sum K^T W K; the three frame terms are one
        product G_f^T Y_f + its transpose with Y_f = Q_f G_f / 2 - X_f. With w = kept this is
        the Schur complement of the frames."""
        m, p = self.model, self.model.p
        N = p.n_cams
        n = N * CAM_PARAMS
        CC = camera_grams(m, self.C, w * self.own[:, None])
        WK = self.K * w[:, :, None]
        X = sum_by(m, "frame_camera", outer(WK, self.C) * self.own[:, None, None])
        X = X.reshape(p.n_frames, N, FRAME_PARAMS, CAM_PARAMS).transpose(0, 2, 1, 3).reshape(-1, n)
        Q = sum_by(m, "frame", outer(WK, self.K)).reshape(-1, FRAME_PARAMS, FRAME_PARAMS)
        Y = 0.5 * np.matmul(Q, self.Gf.reshape(p.n_frames, FRAME_PARAMS, n)).reshape(-1, n) - X
        GY = self.Gf.T @ Y
        H = GY + GY.T
        idx = np.arange(N)
        H.reshape(N, CAM_PARAMS, N, CAM_PARAMS)[idx, :, idx, :] += CC
        free = self.free_cols
        return H[np.ix_(free, free)], self.folded_cost(w * self.b)

    def rows(self, obs: np.ndarray, comp: np.ndarray) -> np.ndarray:
        """Dense reduced rows a_i, (k, n_cam_params), for observation ``obs`` component ``comp``."""
        p, m = self.model.p, self.model
        k = len(obs)
        # K_i G_f as one sparse (k, F*5) times Gf: no (k, N, 5, 6) copy of the frames' blocks
        # (460 MB for 15k rows at 128 cameras; 15k rows at 64 took 0.47 s that way, 0.05 s this one)
        at = (FRAME_PARAMS * p.frame[obs])[:, None] + np.arange(FRAME_PARAMS)
        Ks = sp.csr_matrix((self.K[obs, comp].ravel(), (np.repeat(np.arange(k), FRAME_PARAMS), at.ravel())),
                           shape=(k, self.Gf.shape[0]))
        KG = np.asarray(Ks @ self.Gf).reshape(k, p.n_cams, CAM_PARAMS)
        out = -KG[:, m.free].reshape(k, -1)
        own = np.flatnonzero(self.own[obs])
        cols = self.cam_cols[obs[own]]
        np.add.at(out, (own[:, None], cols), self.C[obs[own], comp[own]])
        return out

    def change(self, d: np.ndarray) -> np.ndarray:
        """(M, 2) a_i . d for every row, without forming the rows."""
        p, m = self.model.p, self.model
        dc = np.zeros((p.n_cams, CAM_PARAMS))
        dc[m.free] = d.reshape(-1, CAM_PARAMS)
        own = apply(self.C, dc[p.camera]) * self.own[:, None]
        Gd = (self.Gf @ dc.ravel()).reshape(p.n_frames, FRAME_PARAMS)
        return own - apply(self.K, Gd[p.frame])

    def folded_cost(self, coef: np.ndarray) -> np.ndarray:
        """sum_i coef_i a_i over all rows, (n_cam_params,), for coef (M, 2)."""
        m = self.model
        cam = np.einsum("mk,mkj->mj", coef, self.C) * self.own[:, None]
        out = sum_by(m, "camera", cam).ravel()
        u = sum_by(m, "frame", np.einsum("mk,mkj->mj", coef, self.K))
        out -= self.Gf.T @ u.ravel()
        return out[self.free_cols]

    def apply(self, d: np.ndarray) -> np.ndarray:
        """New state: cameras += d and each frame += its eliminated step."""
        m, p = self.model, self.model.p
        x = self.x.copy()
        x[: m.frame_col0] += d
        dc = np.zeros((p.n_cams, CAM_PARAMS))
        dc[m.free] = d.reshape(-1, CAM_PARAMS)
        Gd = (self.Gf @ dc.ravel()).reshape(p.n_frames, FRAME_PARAMS)
        df = -np.einsum("fij,fj->fi", self.Hinv, self.g + Gd)
        x[m.frame_col0 :] += df.ravel()
        return x
