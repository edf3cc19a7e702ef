"""Refinement against seeded rigs; tolerances come from the Cramér-Rao bound of the injected noise."""

import numpy as np
import pytest

from wandcal.calib.geometry import camera_centers, kabsch
from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.sim.scenes import prepared_scene as prepared
from wandcal.calib.solve.ba import bundle_adjust
from wandcal.calib.solve.backend.arrowlp import ACCEPT_TOL, TOL
from wandcal.calib.solve.paper import (
    MAX_ROUNDS,
    WINDOW,
    algebraic_residuals,
    arrow_lp,
    height_pairs,
    lp_step,
    refine_paper,
    rotation_step,
    stop_tolerance,
)
from wandcal.calib.solve.paper_fixed_point import fixed_point_on_basis
from wandcal.calib.solve.wandmodel import WandModel

NOISE = 0.5


def test_jacobian_matches_finite_differences(small_rig):
    setup = small_rig.setup
    m = setup.model
    sub = WandModel(setup.problem.subset(setup.problem.frame < 3), m.R0, m.t0, m.wand(m.x0())[:3], m.fixed)
    sub.p = sub.p.__class__(sub.p.camera, sub.p.frame, sub.p.end, sub.p.xy, sub.p.focal, sub.p.length, 3)
    sub = WandModel(sub.p, m.R0, m.t0, m.wand(m.x0())[:3], m.fixed)
    x = sub.x0() + np.random.default_rng(0).normal(0, 1e-3, sub.n_params)
    J = sub.jacobian(x).toarray()
    num = np.zeros_like(J)
    for k in range(len(x)):
        d = np.zeros(len(x))
        d[k] = 1e-6
        num[:, k] = (sub.residuals(x + d) - sub.residuals(x - d)) / 2e-6
    assert np.abs(J - num).max() < 1e-5 * np.abs(J).max()


def test_ba_reaches_the_cramer_rao_bound():
    ratios = []
    for seed in range(3):
        sc = prepared(cameras=5, frames=300, noise_px=NOISE, seed=seed)
        sim, setup = sc.sim, sc.setup
        x, info = bundle_adjust(setup.model)
        assert info["status"] == "converged"
        R, t = setup.model.poses(x)
        T = sim.truth
        bound, _ = pose_crb(setup.problem, T.R, T.t, T.wand[setup.frames], 0, NOISE)
        err, _ = gauge_errors(R, t, T.R, T.t, 0)
        ratios += list(err[1:] / bound[1:])
    # an efficient estimator has RMS(error / sqrt(CRB)) ~ 1; 12 cameras make 1.6 a >99% bound
    assert np.sqrt(np.mean(np.square(ratios))) < 1.6


def test_literal_paper_lp_collapses_and_anchored_does_not():
    sc = prepared(cameras=4, frames=120, noise_px=NOISE, seed=1)
    sim, setup = sc.sim, sc.setup
    m = setup.model
    up = np.array([0.0, 0.0, 1.0])
    start = m.wand(m.x0())
    R, t, W, info = refine_paper(m.R0, m.t0, start, setup.problem, m.fixed, up, "literal", max_rounds=2)
    lengths = np.linalg.norm(W[:, 1] - W[:, 0], axis=1)
    # zero cost by collapse: every wand shrinks to a point and all cameras meet
    assert np.abs(algebraic_residuals(R, t, W.reshape(-1, 3), setup.problem)).sum() < 1e-6
    assert lengths.max() < 1e-6
    R, t, W, info = refine_paper(m.R0, m.t0, start, setup.problem, m.fixed, up, "anchored", max_rounds=8)
    lengths = np.linalg.norm(W[:, 1] - W[:, 0], axis=1)
    assert abs(lengths.mean() - sim.rig.wand_length) < 1e-6  # the anchoring equality holds
    T = sim.truth
    err, _ = gauge_errors(R, t, T.R, T.t, 0)
    start_err, _ = gauge_errors(m.R0, m.t0, T.R, T.t, 0)
    bound, _ = pose_crb(setup.problem, T.R, T.t, T.wand[setup.frames], 0, NOISE)
    assert err.max() < start_err.max()  # it refines rather than collapsing
    # an L1 estimator costs sqrt(pi/2) = 1.25x the bound on Gaussian noise; the depth weighting
    # of the algebraic error and the slow alternation cost more (docs/decisions/0002): allow 4x
    assert np.all(err[1:] < 4 * bound[1:])


def _first_paper_round():
    """A 4 x 120 rig's paper scheme after its first round: (setup, model, up, X (P, 3) the start's
    wand points, the height pairs, R1 the first rotation step, (t1, X1, the first LP's solve))."""
    sc = prepared(cameras=4, frames=120, noise_px=NOISE, seed=2)
    setup, m = sc.setup, sc.setup.model
    up = np.array([0.0, 0.0, 1.0])
    X = m.wand(m.x0()).reshape(-1, 3)
    heights = height_pairs(m.R0, m.t0, X, up)
    R1 = rotation_step(m.R0, m.t0, X, setup.problem, m.fixed)
    return setup, m, up, X, heights, R1, lp_step(R1, m.t0, X, setup.problem, m.fixed, up, heights=heights)


def test_paper_lp_warm_start_reaches_the_cold_optimum(monkeypatch):
    from wandcal.calib.solve import paper_lp

    # the interior point to its own tolerance (the paper's rounds stop it at LP_TOL, looser)
    monkeypatch.setattr(paper_lp, "LP_TOL", TOL)
    setup, m, up, X, heights, R1, (t1, X1, first) = _first_paper_round()
    assert first.status == "optimal" and first.basis is not None
    # the next round: new rotations change the LP's coefficients, not its shape
    R2 = rotation_step(R1, t1, X1, setup.problem, m.fixed)
    _, _, cold = lp_step(R2, t1, X1, setup.problem, m.fixed, up, heights=heights, solver="simplex")
    _, _, cold_ipm = lp_step(R2, t1, X1, setup.problem, m.fixed, up, heights=heights)
    t_w, X_w, warm = lp_step(R2, t1, X1, setup.problem, m.fixed, up, heights=heights, basis=first.basis)
    assert warm.status == cold.status == cold_ipm.status == "optimal"
    # the block-arrow interior point reaches HiGHS's simplex optimum, to the relative residuals
    # and gap it stops at (TOL, or ACCEPT_TOL where rounding stalls it first)
    assert abs(cold_ipm.objective - cold.objective) <= ACCEPT_TOL * cold.objective
    assert abs(warm.objective - cold.objective) <= ACCEPT_TOL * cold.objective
    # from the last round's basis where it is still optimal, else from its centred iterate
    assert warm.iterations < cold_ipm.iterations
    # the warm solve's point attains that optimum
    assert np.isclose(np.abs(algebraic_residuals(R2, t_w, X_w, setup.problem)).sum(), cold.objective, rtol=1e-6)


def test_paper_lp_carries_its_structure_from_round_to_round_without_changing_the_answer():
    """A round's warm start carries the sparse sums the last solve built (they depend only on which
    point and camera each row touches); the next round's answer is the one a fresh build gives,
    and the carried sums are refused for an LP whose rows touch other points."""
    from dataclasses import replace

    from wandcal.calib.solve.backend.arrowlp import solve

    setup, m, up, X, heights, R1, (t1, X1, first) = _first_paper_round()
    assert first.basis.sums is not None and first.basis.sums.fits(arrow_lp(R1, m.t0, X, setup.problem, m.fixed, up,
                                                                          heights))
    R2 = rotation_step(R1, t1, X1, setup.problem, m.fixed)
    lp2 = arrow_lp(R2, t1, X1, setup.problem, m.fixed, up, heights)
    carried = solve(lp2, first.basis)
    fresh = solve(arrow_lp(R2, t1, X1, setup.problem, m.fixed, up, heights), replace(first.basis, sums=None))
    assert carried.status == fresh.status == "optimal"
    assert carried.iterations == fresh.iterations and np.array_equal(carried.v, fresh.v)
    # with the rows' points permuted, the carried sums do not fit and are built afresh
    other = replace(lp2, point=lp2.point[::-1].copy())
    assert not first.basis.sums.fits(other)


def test_paper_method_runs_to_a_fixed_point():
    sc = prepared(cameras=4, frames=300, noise_px=NOISE, seed=1)
    setup, m = sc.setup, sc.setup.model
    up = np.array([0.0, 0.0, 1.0])
    R, t, W, info = refine_paper(m.R0, m.t0, m.wand(m.x0()), setup.problem, m.fixed, up)
    assert info["status"] == "converged" and info["iterations"] < MAX_ROUNDS, info
    lengths = np.linalg.norm(W[:, 1] - W[:, 0], axis=1)
    assert abs(lengths.mean() - sc.sim.rig.wand_length) < 1e-6
    # a window more of rounds (rotations, then the LP) leaves every camera within the stop's
    # tolerance, twice (a fraction of its standard error; measured 91 um against 97 um)
    tol = stop_tolerance(m.R0, m.t0, m.wand(m.x0()), setup.problem, m.fixed)
    R2, t2, _, _ = refine_paper(R, t, W, setup.problem, m.fixed, up, max_rounds=WINDOW)
    assert np.linalg.norm(camera_centers(R2, t2) - camera_centers(R, t), axis=1).max() < 2 * tol
    # No bound on the error is asserted here: the scheme's fixed point is not an efficient
    # estimate. The rotation step minimises squared and the LP absolute algebraic error, so the
    # rounds settle where the two balance, not at a minimum of either: 2-6x the bound on rigs
    # this small, further from the truth than the start on some (decision 0005).
    # bench/bench_acceptance.py measures it at 8 x 1500.


@pytest.mark.long
def test_paper_stops_within_a_fraction_of_sigma_of_the_plain_rounds_fixed_point(monkeypatch):
    """The default rounds (jumps along the tail, each LP to LP_TOL) stop where they estimate the
    cameras within STOP_SIGMA of their smallest standard error from the fixed point (decision 0060).
    The estimate is a geometric tail's, not a bound, and on a rig this small it falls short:
    measured, the stop lands 1.02 sigma (994 um) from the fixed point the exact plain rounds lock in
    at, found and certified on its LP basis (decision 0052), after 32 rounds (the 5 um stop before:
    365 um, after 190), and the rig's aligned RMS error against the truth is 0.17 sigma below that
    point's. Asserted: 1.5 sigma, and 0.3 of one."""
    from wandcal.calib.solve import paper, paper_lp

    sc = prepared(cameras=4, frames=300, noise_px=NOISE, seed=1)
    p, m = sc.setup.problem, sc.setup.model
    up = np.array([0.0, 0.0, 1.0])
    start = m.wand(m.x0())
    sigma = paper.stop_tolerance(m.R0, m.t0, start, p, m.fixed) / paper.STOP_SIGMA
    R, t, _, info = refine_paper(m.R0, m.t0, start, p, m.fixed, up)
    assert info["status"] == "converged", info
    # the exact plain rounds, run on to their lock-in (decision 0052)
    for name, value in (("JUMP_CAP", 0.0), ("ROUND_TOL", 0.0), ("STOP_SIGMA", 0.0)):
        monkeypatch.setattr(paper, name, value)
    monkeypatch.setattr(paper_lp, "LP_TOL", TOL)
    # The rounds' path from basis to basis turns on a float's last bits: numpy 1.x locked in by round
    # 205, numpy 2.4 by 260. So they run on in steps until a fixed point is found on their basis.
    heights = height_pairs(m.R0, m.t0, start.reshape(-1, 3), up)
    R_p, t_p, W_p, found = m.R0, m.t0, start, None
    for rounds in (220, 60, 60, 60):
        R_p, t_p, W_p, _ = refine_paper(R_p, t_p, W_p, p, m.fixed, up, max_rounds=rounds)
        found = fixed_point_on_basis(R_p, t_p, W_p.reshape(-1, 3), p, m.fixed, up, heights)
        if found is not None:
            break
    assert found is not None
    assert np.linalg.norm(camera_centers(R, t) - camera_centers(found[0], found[1]), axis=1).max() < 1.5 * sigma
    # the rig's error against the truth: the RMS of the centres' after the best rigid alignment
    # (bench_acceptance.py's "aligned")
    C_true = camera_centers(sc.sim.truth.R, sc.sim.truth.t)

    def aligned_rms(C):
        Q, s, _ = kabsch(C, C_true)
        return np.sqrt(np.mean(np.sum((C @ Q.T + s - C_true) ** 2, axis=1)))

    assert abs(aligned_rms(camera_centers(R, t)) - aligned_rms(camera_centers(found[0], found[1]))) < 0.3 * sigma


def test_the_fixed_point_on_a_basis_is_where_the_plain_rounds_stay(monkeypatch):
    """Where the plain rounds' LP basis has settled (the "lock-in" of decision 0045), Newton's
    method on that basis finds the rounds' fixed point: rounds started there stay there, to the
    interior point's accuracy. While the basis still changes from round to round, it finds none."""
    from wandcal.calib.solve import paper, paper_lp

    sc = prepared(cameras=3, frames=100, noise_px=NOISE, seed=1)
    p, m = sc.setup.problem, sc.setup.model
    up = np.array([0.0, 0.0, 1.0])
    monkeypatch.setattr(paper, "JUMP_CAP", 0.0)
    monkeypatch.setattr(paper, "ROUND_TOL", 0.0)  # the plain rounds, run on
    monkeypatch.setattr(paper, "STOP_SIGMA", 0.0)
    monkeypatch.setattr(paper_lp, "LP_TOL", TOL)  # each LP to the interior point's own tolerance, as measured
    start = m.wand(m.x0())
    heights = height_pairs(m.R0, m.t0, start.reshape(-1, 3), up)
    R, t, W, _ = refine_paper(m.R0, m.t0, start, p, m.fixed, up, max_rounds=30)
    assert fixed_point_on_basis(R, t, W.reshape(-1, 3), p, m.fixed, up, heights) is None  # still creeping
    R, t, W, _ = refine_paper(m.R0, m.t0, start, p, m.fixed, up, max_rounds=150)  # locked in by 140 (measured)
    found = fixed_point_on_basis(R, t, W.reshape(-1, 3), p, m.fixed, up, heights)
    assert found is not None
    R_f, t_f, X_f = found
    assert abs(np.linalg.norm(X_f[1::2] - X_f[::2], axis=1).mean() - sc.sim.rig.wand_length) < 1e-9
    R2, t2, _, _ = refine_paper(R_f, t_f, X_f.reshape(-1, 2, 3), p, m.fixed, up, max_rounds=WINDOW)
    # each round's LP is solved to a relative 1e-9 (arrowlp.TOL): 5.6 nm over the 10 rounds
    # measured, against 6.6 um from round 150's cameras to the point found
    assert np.linalg.norm(camera_centers(R2, t2) - camera_centers(R_f, t_f), axis=1).max() < 1e-7
