"""The Levenberg–Marquardt loop of ``ba`` (calib/solve/ba/adjust.py): damped Schur-complement
steps (:mod:`wandcal.calib.solve.backend.schur`) on the terms' normal equations, with a robust loss.

Robust loss: Cauchy, ``rho(z) = s^2 log(1 + z / s^2)`` on each blob's squared pixel error ``z``
(one 2D residual block, as in Ceres), applied by iteratively reweighted least squares: each
iteration solves the least squares problem weighted by ``rho'(z)`` at the current residuals,
whose fixed point is the robust optimum. The scale ``s`` is ``CAUCHY_SIGMAS`` robust sigmas of the
current residuals, so it shrinks as the start's error is removed and a gross outlier (tens of
pixels) ends with a weight of ~1e-3. ``loss="linear"`` is plain least squares.

Stop: when every parameter is estimated to lie within ``STOP_SE`` of its standard error of the
optimum, from the last step and the rate at which steps shrink, so the remaining error is
statistically invisible; not on a tolerance in cost that keeps a solver crawling near it. With
``judge_frames=False`` (the pipeline's stages) only the cameras' parameters and the point tracks'
count, not the wand frames': a frame two cameras see, with its wand nearly across both rays, is
held along one direction by the wand's foreshortening alone, a curvature that Gauss-Newton's
normal equations leave out, so it converges linearly (0.93 a step) for tens of iterations after
the cameras have settled; the cameras' own steps carry what its remaining motion still does to
them (decision 0032). Such a stage ends by settling, the cameras held, the frames that its rule,
applied frame by frame, still counts as moving (:mod:`wandcal.calib.solve.ba.frames`): relabelling
and the outlier pass judge frames by their residuals. The frames it counts as settled are left as
they are (on the 8-camera acceptance rig none is left moving: the digits of the stop on every
parameter, which ends there at the same step).

Least squares (the polish of a robust solution) tries Gauss-Newton's undamped step first, and
follows an accepted undamped step with the chord method's: the new point's gradient through the
inverse just computed, which proves convergence without building and reducing the normal
equations again; the standard errors reuse that inverse (docs/decisions/0026).
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.observations import robust_sigma
from wandcal.calib.solve.ba.frames import frames_at_optimum
from wandcal.calib.solve.backend import schur
from wandcal.calib.solve.reprojection import (
    CAM_PARAMS,
    INTRINSICS,
    TIME_PARAMS,
    BundleState,
    PointTerm,
    WandTerm,
    exp_so3,
    moved_intrinsics,
)
from wandcal.calib.solve.uncertainty import fitted_sigma, pose_covariance

# Cauchy scale in robust sigmas: at 4 sigma the estimate is 98.6% efficient on 2D Gaussian noise
# (Monte Carlo of (E psi')^2 / E psi^2), while a 20 px outlier at 0.3 px noise gets weight 0.004
CAUCHY_SIGMAS = 4.0
# stop when every parameter is estimated to lie within this fraction of its standard error of the
# optimum: the variance that remains is then 0.25% of the noise's
STOP_SE = 0.05
MAX_RATE = 0.9  # the ratio of successive steps is taken as at most this when estimating what is left
LAMBDA0 = 1e-4  # Marquardt's damping, relative to the normal matrix's diagonal
LAMBDA_MAX = 1e16  # beyond this no step lowers the cost: the state is a minimum to working precision
MIN_RELATIVE_GAIN = 1e-15  # an accepted step gaining less than this share of the cost is rounding


class LevenbergMarquardt:
    """Levenberg–Marquardt with Nielsen's damping update and iteratively reweighted loss."""

    def __init__(self, terms: list, free: np.ndarray, loss: str, frozen: list[tuple[int, int]], refine: tuple[str, ...],
                 stop_se: float = STOP_SE, timed: bool = False, *, judge_frames: bool = True):
        self.terms = terms
        self.stop_se = stop_se
        # the terms whose blocks the stop judges: every one, or the point tracks' alone (with no
        # free camera the frames are all there is to judge)
        self.judged = [judge_frames or not len(free) or isinstance(t, PointTerm) for t in terms]
        self.free = free
        self.n_free = len(free)
        self.loss = loss
        self.frozen = frozen
        self.refine = refine
        self.intr_size = sum(INTRINSICS[name] for name in refine)
        self.timed = timed
        self.cam_size = CAM_PARAMS + self.intr_size + (TIME_PARAMS if timed else 0)
        self.scale = np.inf
        self.split = np.cumsum([len(t.structure.cam) for t in terms])[:-1]
        # what run leaves for standard_errors: the final state with its squared errors, the last
        # normal matrix built, and the last undamped solve (the matrix and its step)
        self.last: tuple[BundleState, np.ndarray] | None = None
        self.recent: schur.Normal | None = None
        self.undamped: tuple[schur.Normal, schur.Step] | None = None

    def _cost(self, z: np.ndarray) -> float:
        if self.loss == "linear":
            return 0.5 * float(z.sum())
        s2 = self.scale**2
        return 0.5 * s2 * float(np.log1p(z / s2).sum())

    def _weights(self, z: np.ndarray) -> np.ndarray:
        return np.ones_like(z) if self.loss == "linear" else 1.0 / (1.0 + z / self.scale**2)

    def _rescale(self, z: np.ndarray) -> None:
        if self.loss == "cauchy":
            self.scale = min(self.scale, max(CAUCHY_SIGMAS * _robust_sigma(z), 1e-6))

    def _squared_errors(self, state: BundleState) -> np.ndarray:
        return np.concatenate([np.einsum("mk,mk->m", r, r) for r in (term.residuals(state) for term in self.terms)])

    def _moved(self, state: BundleState, step: schur.Step) -> BundleState:
        R, t = state.R.copy(), state.t.copy()
        R[self.free] = exp_so3(step.dc[:, :3]) @ state.R[self.free]
        t[self.free] += step.dc[:, 3:6]
        intr = state.intr
        if self.refine:
            intr = state.refined_intr().copy()
            intr[self.free] = moved_intrinsics(intr[self.free], step.dc[:, 6 : 6 + self.intr_size], self.refine)
        dt = state.dt
        if self.timed:
            dt = state.refined_dt().copy()
            dt[self.free] += step.dc[:, CAM_PARAMS + self.intr_size]
        state = BundleState(R, t, state.m, state.d, state.X, intr, state.Q, dt)
        for term, dp in zip(self.terms, step.dp):
            state = term.moved(state, dp)
        return state

    def _freeze(self, normal: schur.Normal) -> None:
        """Hold the frozen camera parameters: their rows of the system become the identity's."""
        for k, j in self.frozen:
            normal.U[k, j, :] = 0.0
            normal.U[k, :, j] = 0.0
            normal.U[k, j, j] = 1.0
            normal.gc[k, j] = 0.0
            for t in normal.terms:
                t.W[t.structure.pair_cam == k, j, :] = 0.0

    def _normal(self, state: BundleState, z: np.ndarray, like: schur.Normal | None = None) -> schur.Normal:
        """The weighted normal equations at ``state`` (``z``: its squared errors, for the
        weights), linearised a chunk at a time inside the sums; with ``like``, only the gradient
        is new and the matrix blocks are ``like``'s (the chord method's system)."""
        sw = np.split(np.sqrt(self._weights(z)), self.split)
        parts = []
        for term, w in zip(self.terms, sw):
            def rows(lo, hi, term=term, w=w):
                r, J = term.linearise_rows(state, slice(lo, hi))
                r *= w[lo:hi, None]
                J *= w[lo:hi, None, None]
                return r, J
            parts.append((term.structure, rows))
        normal = schur.normal_equations(self.cam_size, self.n_free, parts, like)
        self._freeze(normal)
        return normal

    def run(self, state: BundleState, progress, max_iter: int):
        z = self._squared_errors(state)
        self._rescale(z)
        cost = self._cost(z)
        # least squares tries Gauss-Newton's undamped step first: near the optimum (the polish of
        # a robust solution) it is Newton's step up to the residuals' curvature, and Marquardt's
        # damping would shrink it along the rig's weakly determined directions (the polish's second
        # step at 64 x 3000: 0.076 SE after a first step damped by LAMBDA0, 0.0006 after an undamped one)
        lam, nu = (0.0 if self.loss == "linear" else LAMBDA0), 2.0
        status, message, iterations, evaluations = "iteration_limit", "most iterations reached", 0, 1
        last_ratio = np.inf
        chord: tuple[schur.Normal, schur.Step] | None = None
        self.undamped = None
        unsettled = _Unsettled(self.judged)
        for it in range(max_iter):
            accepted = None
            if chord is not None:
                accepted = self._chord_step(state, z, cost, *chord)
                evaluations += 1
                if accepted is not None:
                    # the chord method's rate is unmeasured (its Jacobian's products are a step
                    # old): what is left is estimated at MAX_RATE, as after a first step
                    last_ratio = np.inf
            if accepted is None:
                self.recent = self.undamped = chord = None  # one normal matrix alive at a time
                normal = self.recent = self._normal(state, z)
                accepted, lam, nu, tried = self._damped_step(normal, state, cost, lam, nu)
                evaluations += tried
            if accepted is None:
                status, message = "converged", "no step lowers the cost further"
                break
            state, step, new_cost, z = accepted
            # after an undamped step of least squares, the next is the chord method's: the same
            # inverse with the new point's gradient (one linearisation, no products, no Gram)
            chord = self.undamped if self.loss == "linear" and self.undamped is not None and step is self.undamped[1] else None
            iterations = it + 1
            relative_gain = (cost - new_cost) / max(cost, 1e-300)
            self._rescale(z)
            cost = self._cost(z)
            if progress is not None:
                progress({"stage": "refine", "iteration": iterations, "cost": cost, "message": "bundle adjustment"})
            ratio = _step_in_standard_errors(step, z, self.judged)
            unsettled.update(step, z, rate_known=bool(np.isfinite(last_ratio)))
            # steps shrink at least geometrically near the optimum (quadratically for least
            # squares, linearly for the reweighted loss): the distance left is about
            # step * q / (1 - q), with q the last ratio of successive steps
            q = min(ratio / last_ratio, MAX_RATE) if np.isfinite(last_ratio) else MAX_RATE
            remaining = ratio * q / (1 - q)
            last_ratio = ratio
            if remaining < self.stop_se or relative_gain < MIN_RELATIVE_GAIN:
                status, message = "converged", f"the estimated distance to the optimum is under {self.stop_se} standard errors"
                break
        if not all(self.judged):
            state, z, cost = self._frames_at_optimum(state, z, unsettled)
        info = {
            "iterations": iterations,
            "evaluations": evaluations,
            "cost": cost,
            "status": status,
            "message": message,
            "loss": self.loss,
            "loss_scale_px": None if self.loss == "linear" else float(self.scale),
        }
        self.last = (state, z)  # the final state's squared errors, for standard_errors
        return state, info

    def _frames_at_optimum(self, state: BundleState, z: np.ndarray, unsettled: _Unsettled):
        """(state, z, cost) with the blocks the stop did not judge (the wand frames) that its rule
        leaves over ``stop_se`` from their optimum (``unsettled``) brought within it, the cameras
        held, under the stage's loss and scale (:mod:`wandcal.calib.solve.ba.frames`): relabelling
        and the outlier pass judge each frame by its residuals, and the result reports the frames.
        The frames the stage's rule already counts as settled are left as they are."""
        moving = [unsettled.moving(k, self.stop_se) for k in range(len(self.terms))]
        if not any(m is not None and m.any() for m in moving):
            return state, z, self._cost(z)
        sigma = max(_robust_sigma(z), 1e-12)
        for term, active in zip(self.terms, moving):
            if active is not None and active.any():
                state, _ = frames_at_optimum(term, state, self._rho, self._weights, sigma, self.stop_se, active=active)
        z = self._squared_errors(state)
        return state, z, self._cost(z)

    def _rho(self, z: np.ndarray) -> np.ndarray:
        """Each observation's share of :meth:`_cost` (K,) from its squared pixel error z (K,)."""
        if self.loss == "linear":
            return 0.5 * z
        s2 = self.scale**2
        return 0.5 * s2 * np.log1p(z / s2)

    def _damped_step(self, normal: schur.Normal, state: BundleState, cost: float, lam: float, nu: float):
        """Levenberg–Marquardt's step at ``normal``, raising the damping until the cost falls
        (Nielsen's update): (accepted (state, step, cost, z) or None, lam, nu, evaluations)."""
        evaluations = 0
        while lam < LAMBDA_MAX:
            step = schur.solve(normal, lam)
            if step is not None and lam == 0.0:
                self.undamped = (normal, step)  # what the standard errors need, if it is the last
            if step is None:
                lam, nu = (lam * nu if lam else LAMBDA0), 2 * nu
                continue
            new = self._moved(state, step)
            z_new = self._squared_errors(new)
            new_cost = self._cost(z_new)
            evaluations += 1
            pred = schur.predicted_gain(normal, step)
            gain = (cost - new_cost) / pred if pred > 0 else -1.0
            if np.isfinite(new_cost) and gain > 0:
                lam *= max(1 / 3, 1 - (2 * gain - 1) ** 3)
                return (new, step, new_cost, z_new), lam, 2.0, evaluations
            lam, nu = (lam * nu if lam else LAMBDA0), 2 * nu
        return None, lam, nu, evaluations

    def _chord_step(self, state: BundleState, z: np.ndarray, cost: float, normal0: schur.Normal, step0: schur.Step):
        """The chord method's step (Newton's with the Jacobian's products of the last point): the
        gradient at ``state`` through the inverses of the undamped solve ``step0`` of ``normal0``.
        One step from the optimum's neighbourhood, the products change by a fraction of the
        step's relative size, and so does this step from Gauss-Newton's. None when the cost does
        not fall: the caller then builds the normal equations here."""
        normal = self._normal(state, z, like=normal0)
        step = schur.solve_again(normal, step0)
        new = self._moved(state, step)
        z_new = self._squared_errors(new)
        new_cost = self._cost(z_new)
        if np.isfinite(new_cost) and schur.predicted_gain(normal, step) > 0 and new_cost < cost:
            return new, step, new_cost, z_new
        return None

    def standard_errors(self, state: BundleState) -> np.ndarray:
        """(n_free, c) standard errors of the cameras' parameters at the solution: sigma times the
        root diagonal of the undamped reduced system's inverse (0 for held parameters)."""
        if self.last is not None and self.last[0] is state:
            z, recent = self.last[1], self.recent
        else:
            z, recent = self._squared_errors(state), None
        undamped = self.undamped
        self.recent = self.undamped = None
        if not self.n_free:
            return np.full((0, self.cam_size), np.inf)
        # the last normal matrix built, at this state or up to two steps before it (a step and the
        # chord step after it): the run stopped when what was left fell under stop_se standard
        # errors, and its last steps were of a few standard errors at most, far below what moves
        # a covariance (3e-5 of the standard errors at 64 x 3000, docs/decisions/0026)
        normal = recent if recent is not None else self._normal(state, z)
        # the run solved this very matrix undamped: the same inverse
        step: schur.Step | None = undamped[1] if undamped is not None and undamped[0] is normal else schur.solve(normal, 0.0)
        if step is None:
            return np.full((self.n_free, self.cam_size), np.inf)
        n_par = self.n_free * self.cam_size - len(self.frozen) + sum(t.structure.n_pts * t.structure.size for t in self.terms)
        sigma = fitted_sigma(np.sqrt(z), n_par)
        wand = next((k for k, term in enumerate(self.terms) if isinstance(term, WandTerm)), None)
        self.covariance = pose_covariance(normal, step, sigma, self.free, self.frozen, wand)
        std = sigma * np.sqrt(np.maximum(step.cam_var, 0.0))
        for k, j in self.frozen:
            std[k, j] = 0.0
        return std


class _Unsettled:
    """Which blocks of the terms the stop does not judge (the wand frames) its rule would still
    count as moving: each block's last step in standard errors and the rate of its last two, the
    rule of :meth:`LevenbergMarquardt.run` applied block by block."""

    def __init__(self, judged: list[bool]):
        self.judged = judged
        self.last: list[np.ndarray | None] = [None] * len(judged)
        self.remaining: list[np.ndarray | None] = [None] * len(judged)

    def update(self, step: schur.Step, z: np.ndarray, *, rate_known: bool) -> None:
        """Take an accepted step (``rate_known``: the step before it was solved from its own
        linearisation, not a chord step); ``z`` the squared errors after it, for the noise."""
        sigma = max(_robust_sigma(z), 1e-12)
        for k, judged in enumerate(self.judged):
            d, var = step.dp[k], step.pt_var[k]
            if judged or not d.size:
                continue
            ratio = np.max(np.abs(d) / (sigma * np.sqrt(np.maximum(var, 1e-300))), axis=1)
            previous = self.last[k]
            q = np.full(len(ratio), MAX_RATE)
            if rate_known and previous is not None:
                q = np.where(previous > 0, np.minimum(ratio / np.maximum(previous, 1e-300), MAX_RATE), MAX_RATE)
            self.remaining[k] = ratio * q / (1 - q)
            self.last[k] = ratio

    def moving(self, k: int, stop_se: float) -> np.ndarray | None:
        """(P,) bool: term ``k``'s blocks estimated ``stop_se`` or more from their optimum; None
        for a judged term, and when no step was taken (the stage's start is then its end)."""
        if self.judged[k]:
            return None
        remaining = self.remaining[k]
        return None if remaining is None else remaining >= stop_se


def _robust_sigma(z: np.ndarray) -> float:
    """Per-axis noise from squared 2D errors: the median radius of a 2D Gaussian is sigma sqrt(2 ln 2)."""
    return robust_sigma(np.sqrt(z))


def _step_in_standard_errors(step: schur.Step, z: np.ndarray, judged: list[bool]) -> float:
    """Largest |step| / standard error over the cameras' parameters and the blocks of the terms
    ``judged`` marks. The noise is estimated robustly from the residuals; the blocks' errors use
    their conditional variance (smaller, so stricter)."""
    sigma = max(_robust_sigma(z), 1e-12)
    worst = 0.0
    blocks = [(d, var) for d, var, j in zip(step.dp, step.pt_var, judged) if j]
    for d, var in [(step.dc, step.cam_var)] + blocks:
        if d.size:
            worst = max(worst, float(np.max(np.abs(d) / (sigma * np.sqrt(np.maximum(var, 1e-300))))))
    return worst
