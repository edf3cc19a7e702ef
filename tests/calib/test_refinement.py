"""Refinement against seeded rigs; tolerances come from the Cramér-Rao bound of the injected noise."""

import numpy as np

from calib.ba import bundle_adjust
from calib.crb import gauge_errors, pose_crb
from calib.paper import algebraic_residuals, refine_paper
from calib.wandmodel import WandModel

from calib.scenes import prepared_scene as prepared

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
