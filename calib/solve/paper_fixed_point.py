"""The plain ``--method paper`` rounds' fixed point on one LP basis, found by Newton's method and
certified (decision 0052). Not used by :func:`wandcal.calib.solve.paper.refine_paper`: on small rigs it
finds the point the plain rounds lock in at; at 8 x 1500 the rounds still creep from basis to basis and
none is found. ``bench/bench_paper_speed.py`` measures each answer's distance to it."""

from __future__ import annotations

import numpy as np

from wandcal.calib.solve.paper import exp_turn, rotation_step
from wandcal.calib.solve.paper_lp import arrow_lp
from wandcal.calib.solve.wandmodel import WandProblem

FIXED_POINT_STEPS = 8  # Newton steps on one basis: 1-2 are taken from a state on it (decision 0052)
FIXED_POINT_TOL = 1e-12  # radians (rotations) and metres (the points' change): a fixed point to rounding
FIXED_POINT_EPS = 1e-7  # radians: the turn of each difference in the Jacobian


def fixed_point_on_basis(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem, fixed: np.ndarray,
                         up: np.ndarray, heights: tuple[np.ndarray, np.ndarray]):
    """The plain rounds' fixed point on the LP basis a round's answer names, certified, or None.

    Args:
        R: (N, 3, 3) the rotations a round's LP used; t (N, 3), X (P, 3): that LP's answer
            (metres); problem, fixed, up: as :func:`refine_paper`; heights: the run's eq. (extra)
            pairs (:func:`height_pairs` at its start).

    The basis is the n - 1 rows (t, X) holds nearest zero (n the unknowns; the wand row is the
    last). While it stays optimal a round is smooth in the rotations: R -> rotation_step(R,
    vertex(LP(R))), one sparse solve (:func:`wandcal.calib.solve.backend.arrowlp.vertex`).
    Newton's method on the free cameras' 3 G turns (the Jacobian by differences, one vertex
    each) finds where that map returns R. Returns (R, t, X (P, 3)) where the basis is still
    optimal there (its vertex is the LP's optimum) and a round moves the rotations and points by
    under ``FIXED_POINT_TOL``: a fixed point of the plain rounds, to rounding. None where the
    basis stops being optimal on the way: the state is still creeping from basis to basis
    (docs/decisions/0052-paper-fixed-point-on-a-basis.md)."""
    free = ~fixed
    basis = _basis_named(arrow_lp(R, t, X, problem, fixed, up, heights), np.r_[t[free].ravel(), X.ravel()])
    for _ in range(FIXED_POINT_STEPS):
        here = _on_basis(R, t, X, problem, fixed, up, heights, basis)
        if here is None:
            return None
        F0 = _round_turn(R, here[0], here[1], problem, fixed)
        if np.abs(F0).max() < FIXED_POINT_TOL and np.abs(here[1] - X).max() < FIXED_POINT_TOL:
            return R, here[0], here[1]
        J = np.empty((len(F0), len(F0)))
        for j in range(len(F0)):
            Rj = _turn_free(R, FIXED_POINT_EPS * np.eye(len(F0))[j], free)
            near = _on_basis(Rj, t, X, problem, fixed, up, heights, basis)
            if near is None:
                return None
            J[:, j] = (_round_turn(Rj, near[0], near[1], problem, fixed) - F0) / FIXED_POINT_EPS
        R, (t, X) = _turn_free(R, np.linalg.solve(J, -F0), free), here
    return None


def _basis_named(lp, v: np.ndarray):
    """The :class:`wandcal.calib.solve.backend.arrowlp.Basis` the unknowns ``v`` (n,) name: the
    n - 1 rows nearest zero residual basic (with the free wand column), every other row at the
    bound its residual's sign gives, the box inactive."""
    from wandcal.calib.solve.backend.arrowlp import Basis

    K, n = len(lp.point), lp.n
    reduced = lp.cost - lp.rows_times(v)
    basic = np.zeros(K + 2 * n, bool)
    basic[np.argsort(np.abs(reduced), kind="stable")[: n - (lp.link is not None)]] = True
    return Basis(basic, ~basic[:K] & (reduced < 0))


def _on_basis(R, t, X, problem: WandProblem, fixed, up, heights, basis) -> tuple[np.ndarray, np.ndarray] | None:
    """(t, X (P, 3)) at the vertex of ``basis`` in the anchored LP at rotations ``R`` (its wand
    row linearised about ``X``), or None where that basis is not optimal there."""
    from wandcal.calib.solve.backend.arrowlp import vertex

    v = vertex(arrow_lp(R, t, X, problem, fixed, up, heights), basis)
    if v is None:
        return None
    G = int((~fixed).sum())
    t_new = t.copy()
    t_new[~fixed] = v[: 3 * G].reshape(-1, 3)
    return t_new, v[3 * G :].reshape(-1, 3)


def _round_turn(R, t, X, problem: WandProblem, fixed) -> np.ndarray:
    """(3 G,) the turn (rotation vectors, radians) the rotation step gives each free camera from ``R``."""
    from scipy.spatial.transform import Rotation

    R_next = rotation_step(R, t, X, problem, fixed)
    return Rotation.from_matrix(R_next[~fixed] @ np.swapaxes(R[~fixed], -1, -2)).as_rotvec().ravel()


def _turn_free(R: np.ndarray, turns: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``R`` with each free camera's rotation turned by its 3 entries of ``turns`` (3 G,), radians."""
    R = R.copy()
    R[free] = exp_turn(turns.reshape(-1, 3)) @ R[free]
    return R
