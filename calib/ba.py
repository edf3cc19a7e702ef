"""Bundle adjustment with the wand length built in (``--method ba``): a Schur-complement
Levenberg–Marquardt with a robust loss.

The unknowns are those of :class:`calib.wandmodel.WandModel` (free camera poses; per wand frame
a midpoint and a direction, the ends ``m -/+ L/2 d``), re-linearised about the current state at
every iteration: a camera's rotation moves by a left increment ``R <- exp([w]) R``, a direction
by ``d <- normalize(d + a u1 + b u2)`` in its tangent plane. The Jacobian is analytic and lean
(batched 2x3 products, no sparse matrix per iteration); the damped normal equations are solved by
eliminating the frames' 5x5 blocks (:mod:`calib.schur`).

Robust loss: Cauchy, ``rho(z) = s^2 log(1 + z / s^2)`` on each blob's squared pixel error ``z``
(one 2D residual block, as in Ceres), applied by iteratively reweighted least squares: each
iteration solves the least squares problem weighted by ``rho'(z)`` at the current residuals,
whose fixed point is the robust optimum. The scale ``s`` is ``CAUCHY_SIGMAS`` robust sigmas of the
current residuals, so it shrinks as the start's error is removed and a gross outlier (tens of
pixels) ends with a weight of ~1e-3. ``loss="linear"`` is plain least squares.

Stop: when every parameter is estimated to lie within ``STOP_SE`` of its standard error of the
optimum, from the last step and the rate at which steps shrink, so the remaining error is
statistically invisible; not on a tolerance in cost that keeps a solver crawling near it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from calib import schur
from calib.geometry import matrix_to_euler
from calib.wandmodel import CAM_PARAMS, FRAME_PARAMS, WandModel

LOSSES = ("cauchy", "linear")
DEFAULT_LOSS = "cauchy"
# Cauchy scale in robust sigmas: 4 sigma keeps the estimate ~99% efficient on Gaussian noise
# (docs/decisions/0007-schur-ba.md), while a 20 px outlier at 0.3 px noise gets weight 0.003
CAUCHY_SIGMAS = 4.0
# stop when every parameter is estimated to lie within this fraction of its standard error of the
# optimum: the variance that remains is then 0.25% of the noise's
STOP_SE = 0.05
MAX_RATE = 0.9  # the ratio of successive steps is taken as at most this when estimating what is left
MAX_ITER = 100
LAMBDA0 = 1e-4  # Marquardt's damping, relative to the normal matrix's diagonal
LAMBDA_MAX = 1e16  # beyond this no step lowers the cost: the state is a minimum to working precision
MIN_RELATIVE_GAIN = 1e-15  # an accepted step gaining less than this share of the cost is rounding


@dataclass(eq=False)
class _State:
    """R (N, 3, 3), t (N, 3) world->camera; m (F, 3) wand midpoints; d (F, 3) unit directions."""

    R: np.ndarray
    t: np.ndarray
    m: np.ndarray
    d: np.ndarray


def bundle_adjust(
    model: WandModel, x0: np.ndarray | None = None, progress=None, loss: str = DEFAULT_LOSS, max_iter: int = MAX_ITER
):
    """Minimise the (robust) pixel reprojection error over all free cameras and wand frames.

    Args:
        model: the problem about its start state.
        x0: (n_params,) start in the model's parameters; ``model.x0()`` when None.
        progress: optional callable(dict) told about each iteration.
        loss: "cauchy" (default) or "linear" (plain least squares).
        max_iter: most Levenberg–Marquardt iterations.

    Returns:
        (x, info): x in the model's parameters; info = {"iterations", "cost", "seconds", "status",
        "message", "loss", "loss_scale_px", "evaluations"}.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    start = time.perf_counter()
    x0 = model.x0() if x0 is None else x0
    problem = _WandTerm(model)
    R, t = model.poses(x0)
    wand = model.wand(x0)
    d = wand[:, 1] - wand[:, 0]
    state = _State(R, t, wand.mean(axis=1), d / np.linalg.norm(d, axis=1, keepdims=True))
    solver = _LevenbergMarquardt(problem, loss)
    # the dense products here are small: a second BLAS thread costs more in hand-offs than it
    # gains (0.26 s against 0.42 s at 8 x 1500 on 2 cores, and no gain at 32 x 2000)
    with threadpool_limits(limits=1, user_api="blas"):
        state, info = solver.run(state, progress, max_iter)
    info |= {"seconds": time.perf_counter() - start}
    return _pack(model, state), info


class _WandTerm:
    """Residuals and Jacobian blocks of the wand observations at a state."""

    def __init__(self, model: WandModel):
        p = model.p
        self.free = model.free
        self.n_free = len(model.free)
        self.fixed = model.fixed
        cam_free = np.full(p.n_cams, -1)
        cam_free[model.free] = np.arange(self.n_free)
        self.camera, self.frame, self.xy = p.camera, p.frame, p.xy
        self.focal = p.focal[p.camera]
        self.half = np.where(p.end == 1, 0.5, -0.5) * p.length
        self.structure = schur.TermStructure(cam_free[p.camera], p.camera, p.frame, self.n_free, p.n_frames, FRAME_PARAMS)
        self.n_obs = len(p.camera)
        self.n_params = CAM_PARAMS * self.n_free + FRAME_PARAMS * p.n_frames

    def residuals(self, s: _State) -> np.ndarray:
        """(M, 2) pixel residuals."""
        X = s.m[self.frame] + self.half[:, None] * s.d[self.frame]
        xc = np.einsum("mij,mj->mi", s.R[self.camera], X) + s.t[self.camera]
        return (xc[:, :2] / xc[:, 2:3] - self.xy) * self.focal

    def linearise(self, s: _State):
        """(r (M, 2), J (M, 2, 11)) at ``s``: the camera's (w, t), then the frame's (m, a, b)."""
        u1, u2 = _tangent_basis(s.d)
        X = s.m[self.frame] + self.half[:, None] * s.d[self.frame]
        Rc = s.R[self.camera]
        Y = np.einsum("mij,mj->mi", Rc, X)
        J = np.empty((len(X), 2, CAM_PARAMS + FRAME_PARAMS))
        r = _project_into(J, Y, s.t[self.camera], Rc, self.xy, self.focal)
        basis = np.stack([u1[self.frame], u2[self.frame]], axis=2) * self.half[:, None, None]
        J[:, :, 9:] = J[:, :, 6:9] @ basis
        return r, J

    def moved(self, s: _State, step: schur.Step) -> _State:
        R, t = s.R.copy(), s.t.copy()
        R[self.free] = _exp_so3(step.dc[:, :3]) @ s.R[self.free]
        t[self.free] += step.dc[:, 3:]
        dp = step.dp[0]
        u1, u2 = _tangent_basis(s.d)
        d = s.d + dp[:, 3:4] * u1 + dp[:, 4:5] * u2
        return _State(R, t, s.m + dp[:, :3], d / np.linalg.norm(d, axis=1, keepdims=True))


class _LevenbergMarquardt:
    """Levenberg–Marquardt with Nielsen's damping update and iteratively reweighted loss."""

    def __init__(self, problem: _WandTerm, loss: str):
        self.p = problem
        self.loss = loss
        self.scale = np.inf

    def _cost(self, z: np.ndarray) -> float:
        if self.loss == "linear":
            return 0.5 * float(z.sum())
        s2 = self.scale**2
        return 0.5 * s2 * float(np.log1p(z / s2).sum())

    def _weights(self, z: np.ndarray) -> np.ndarray:
        return np.ones_like(z) if self.loss == "linear" else 1.0 / (1.0 + z / self.scale**2)

    def _rescale(self, z: np.ndarray) -> None:
        if self.loss == "cauchy":
            # the median radius of a 2D Gaussian is sigma sqrt(2 ln 2)
            sigma = float(np.median(np.sqrt(z))) / np.sqrt(2 * np.log(2))
            self.scale = min(self.scale, max(CAUCHY_SIGMAS * sigma, 1e-6))

    def run(self, state: _State, progress, max_iter: int):
        p = self.p
        r, J = p.linearise(state)
        z = np.einsum("mk,mk->m", r, r)
        self._rescale(z)
        cost = self._cost(z)
        lam, nu = LAMBDA0, 2.0
        status, message, iterations, evaluations = "iteration_limit", "most iterations reached", 0, 1
        last_ratio = np.inf
        for it in range(max_iter):
            sw = np.sqrt(self._weights(z))
            Jw = J * sw[:, None, None]
            normal = schur.normal_equations(CAM_PARAMS, p.n_free, [(p.structure, r * sw[:, None], Jw)])
            accepted = None
            while lam < LAMBDA_MAX:
                step = schur.solve(normal, lam)
                if step is None:
                    lam, nu = lam * nu, 2 * nu
                    continue
                new = p.moved(state, step)
                z_new = np.einsum("mk,mk->m", *(2 * [p.residuals(new)]))
                evaluations += 1
                new_cost = self._cost(z_new)
                pred = _predicted_gain(normal, step, p.structure, Jw)
                gain = (cost - new_cost) / pred if pred > 0 else -1.0
                if np.isfinite(new_cost) and gain > 0:
                    lam *= max(1 / 3, 1 - (2 * gain - 1) ** 3)
                    nu = 2.0
                    accepted = (new, step, new_cost)
                    break
                lam, nu = lam * nu, 2 * nu
            if accepted is None:
                status, message = "converged", "no step lowers the cost further"
                break
            state, step, new_cost = accepted
            iterations = it + 1
            relative_gain = (cost - new_cost) / max(cost, 1e-300)
            r, J = p.linearise(state)
            z = np.einsum("mk,mk->m", r, r)
            self._rescale(z)
            cost = self._cost(z)
            if progress is not None:
                progress({"stage": "refine", "iteration": iterations, "cost": cost, "message": "bundle adjustment"})
            ratio = _step_in_standard_errors(step, z, p)
            # steps shrink at least geometrically near the optimum (quadratically for least
            # squares, linearly for the reweighted loss): the distance left is about
            # step * q / (1 - q), with q the last ratio of successive steps
            q = min(ratio / last_ratio, MAX_RATE) if np.isfinite(last_ratio) else MAX_RATE
            remaining = ratio * q / (1 - q)
            last_ratio = ratio
            if remaining < STOP_SE or relative_gain < MIN_RELATIVE_GAIN:
                status, message = "converged", f"the estimated distance to the optimum is under {STOP_SE} standard errors"
                break
        info = {
            "iterations": iterations,
            "evaluations": evaluations,
            "cost": cost,
            "status": status,
            "message": message,
            "loss": self.loss,
            "loss_scale_px": None if self.loss == "linear" else float(self.scale),
        }
        return state, info


def _predicted_gain(normal: schur.Normal, step: schur.Step, s: schur.TermStructure, Jw: np.ndarray) -> float:
    """Decrease of the weighted least squares model: -(g . dx) - |J dx|^2 / 2."""
    g_dx = float(np.sum(normal.gc * step.dc)) + sum(float(np.sum(t.gp * dp)) for t, dp in zip(normal.terms, step.dp))
    c = step.dc.shape[1]
    dx = np.zeros((len(s.cam), Jw.shape[2]))
    free = s.cam >= 0
    dx[free, :c] = step.dc[s.cam[free]]
    dx[:, c:] = step.dp[0][s.pt]
    Jdx = np.einsum("mki,mi->mk", Jw, dx)
    return -g_dx - 0.5 * float(np.sum(Jdx * Jdx))


def _step_in_standard_errors(step: schur.Step, z: np.ndarray, p: _WandTerm) -> float:
    """Largest |step| / standard error over all parameters. The noise is estimated robustly from
    the residuals; the frames' errors use their conditional variance (smaller, so stricter)."""
    sigma = float(np.median(np.sqrt(z))) / np.sqrt(2 * np.log(2))
    worst = 0.0
    for d, var in [(step.dc, step.cam_var)] + list(zip(step.dp, step.pt_var)):
        if d.size:
            worst = max(worst, float(np.max(np.abs(d) / (sigma * np.sqrt(np.maximum(var, 1e-300))))))
    return worst


def _project_into(J: np.ndarray, Y: np.ndarray, t: np.ndarray, R: np.ndarray, xy: np.ndarray, focal: np.ndarray):
    """Pixel residuals (M, 2) of points ``R X + t`` with ``Y = R X`` (M, 3), against normalised
    ``xy`` (M, 2) scaled by ``focal`` (M, 2); writes into ``J[:, :, :9]`` the derivatives w.r.t.
    the camera's rotation increment w (``R <- exp([w]) R``), its translation, and the point X.

    With p = (x/z, y/z) of x_cam = Y + t, dp/dx_cam = [[1, 0, -px], [0, 1, -py]] / z; dx_cam/dw
    = -[Y]x, so row k of dp/dw is Y x (row k of dp/dx_cam); dx_cam/dX = R."""
    xc = Y + t
    iz = 1.0 / xc[:, 2]
    proj = xc[:, :2] * iz[:, None]
    r = (proj - xy) * focal
    fz = focal * iz[:, None]  # (M, 2)
    px, py = proj[:, 0], proj[:, 1]
    Yx, Yy, Yz = Y[:, 0], Y[:, 1], Y[:, 2]
    J[:, 0, 0] = -px * Yy
    J[:, 0, 1] = Yz + px * Yx
    J[:, 0, 2] = -Yy
    J[:, 1, 0] = -py * Yy - Yz
    J[:, 1, 1] = py * Yx
    J[:, 1, 2] = Yx
    J[:, 0, 3], J[:, 0, 4], J[:, 0, 5] = 1.0, 0.0, -px
    J[:, 1, 3], J[:, 1, 4], J[:, 1, 5] = 0.0, 1.0, -py
    J[:, :, 6:9] = R[:, :2, :] - proj[:, :, None] * R[:, 2:3, :]
    J[:, :, :9] *= fz[:, :, None]
    return r


def _tangent_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (F, 3) orthogonal to each unit direction (F, 3) and to each other."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u1 = np.cross(d, helper)
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    return u1, np.cross(d, u1)


def _exp_so3(w: np.ndarray) -> np.ndarray:
    """(K, 3) rotation vectors -> (K, 3, 3) matrices (Rodrigues' formula, batched)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * K + c * (K @ K)


def _pack(model: WandModel, s: _State) -> np.ndarray:
    """The state in the model's parameters: Euler increments about R0, t, and per frame the
    midpoint and the direction's coordinates (a, b) with d parallel to d0 + a e1 + b e2."""
    x = np.zeros(model.n_params)
    cams = x[: model.frame_col0].reshape(-1, CAM_PARAMS)
    f = model.free
    cams[:, :3] = matrix_to_euler(s.R[f] @ np.swapaxes(model.R0[f], 1, 2))
    cams[:, 3:] = s.t[f]
    fr = x[model.frame_col0 :].reshape(-1, FRAME_PARAMS)
    fr[:, :3] = s.m
    along = np.einsum("fi,fi->f", s.d, model.d0)
    fr[:, 3] = np.einsum("fi,fi->f", s.d, model.e1) / along
    fr[:, 4] = np.einsum("fi,fi->f", s.d, model.e2) / along
    return x
