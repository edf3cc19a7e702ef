"""The LP method (``--method lp``) on seeded rigs; tolerances come from the Cramér-Rao bound."""

import numpy as np
import pytest
import scipy.sparse as sp

from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene
from wandcal.calib.solve import lp as slp
from wandcal.calib.solve.ba import bundle_adjust
from wandcal.calib.solve.backend.highs import solve_lp
from wandcal.calib.solve.lp import step as lpstep
from wandcal.calib.solve.reduced import ReducedSystem
from wandcal.calib.solve.robustloss import EFFICIENT

NOISE = 0.5


def _crb_ratio(scene, model, x):
    T = scene.sim.truth
    R, t = model.poses(x)
    err, _ = gauge_errors(R, t, T.R, T.t, 0)
    bound, _ = pose_crb(model.p, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
    return err[1:] / bound[1:]


def test_working_set_lp_is_the_full_lp():
    """The step from the small, exact working set equals the step of the LP with every row and
    every breakpoint (the claim in calib/solve/lp/'s docstring)."""
    scene = prepared_scene(cameras=4, frames=60, noise_px=NOISE, seed=11)
    model = scene.setup.model
    system = ReducedSystem(model, model.x0())
    rho = np.tile([0.01, 0.01, 0.01, 0.02, 0.02, 0.02], model.frame_col0 // 6)
    d, info = lpstep.solve_step(system, rho, None, EFFICIENT, lpstep.GUARD_SE)
    # the same LP written about another point (as after IRLS) has the same optimum
    d_about, _ = lpstep.solve_step(system, rho, None, EFFICIENT, 0.25, d_pred=0.5 * d, near=0.003)
    # the full LP, written out directly: every row with every breakpoint
    P, S = EFFICIENT[0] * system.scale, EFFICIENT[1]
    kept = system.kept.ravel()
    rows = np.flatnonzero(kept)
    A = system.rows(rows // 2, rows % 2)
    b = system.b.ravel()[rows]
    n, k, q = len(rho), len(rows), len(P)
    # d, then e_{i,q} >= A_i d + b_i - P_q with cost (S[q+1] - S[q]), plus the linear S[0] z
    A_big = sp.hstack([sp.csr_matrix(np.repeat(A, q, axis=0)), -sp.identity(k * q)]).tocsc()
    rhs = (np.tile(P, k) - np.repeat(b, q))
    cost = np.r_[S[0] * A.sum(axis=0), np.tile(np.diff(S), k)]
    full = solve_lp(cost, A_big, np.full(k * q, -np.inf), rhs, np.r_[-rho, np.zeros(k * q)], np.r_[rho, np.full(k * q, np.inf)])
    assert full.status == "optimal"
    d_full = full.x[:n]
    model_cost = lambda step: system.model_cost(step, EFFICIENT)  # noqa: E731
    assert model_cost(d) == pytest.approx(model_cost(d_full), rel=1e-9, abs=1e-7)
    assert model_cost(d_about) == pytest.approx(model_cost(d_full), rel=1e-9, abs=1e-7)
    assert info["rows"] < len(rows) * len(P)


def test_converges_from_a_perturbed_start_to_the_bound():
    ratios = []
    for seed in range(3):
        scene = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=seed)
        model = perturbed_model(scene, degrees=2.0, metres=0.05, seed=seed)
        x, info = slp.refine_lp(model)
        assert info["status"] == "converged"
        ratios += list(_crb_ratio(scene, model, x))
    # the LP's M-estimator is 96.5% efficient: RMS(error / sqrt(CRB)) ~ 1.02; 15 cameras make
    # 1.6 a >99% bound (as for bundle adjustment in test_refinement.py)
    assert np.sqrt(np.mean(np.square(ratios))) < 1.6


def test_first_phase_on_a_frame_subset_converges_from_a_perturbed_start():
    ratios = []
    for seed in range(2):
        scene = prepared_scene(cameras=5, frames=slp.SUBSET_ONLY_ABOVE * slp.SUBSET_FRAMES + 100, noise_px=NOISE,
                               seed=seed)
        model = perturbed_model(scene, degrees=2.0, metres=0.05, seed=seed)
        x, info = slp.refine_lp(model)
        assert info["status"] == "converged" and info["subset"]["frames"] == slp.SUBSET_FRAMES
        ratios += list(_crb_ratio(scene, model, x))
    assert np.sqrt(np.mean(np.square(ratios))) < 1.6  # as above; over 8 cameras still a >99.9% bound


def test_survives_gross_outliers_without_filtering():
    clean = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=7)
    dirty = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=7, outliers=0.08)
    x_clean, _ = bundle_adjust(clean.setup.model)
    T = clean.sim.truth
    e_clean, _ = gauge_errors(*clean.setup.model.poses(x_clean), T.R, T.t, 0)
    x_lp, _ = slp.refine_lp(dirty.setup.model)
    e_lp, _ = gauge_errors(*dirty.setup.model.poses(x_lp), T.R, T.t, 0)
    x_ba, _ = bundle_adjust(dirty.setup.model, loss="linear")  # plain least squares: the robust loss would not be dragged
    e_ba, _ = gauge_errors(*dirty.setup.model.poses(x_ba), T.R, T.t, 0)
    rms = lambda e: np.sqrt(np.mean(e[1:] ** 2))  # noqa: E731
    assert rms(e_lp) < 2 * rms(e_clean)  # the robustness goal
    assert rms(e_ba) > 3 * rms(e_clean)  # the outliers do matter: least squares is dragged off


def test_a_solve_that_hits_its_time_limit_returns_the_best_state_marked():
    scene = prepared_scene(cameras=3, frames=80, noise_px=NOISE, seed=5)
    model = scene.setup.model
    x, info = slp.refine_lp(model, time_limit=1e-9)
    assert info["status"] == "time_limit"
    # the best state so far: the Gauss-Newton predictor's, or the start, never a half-solved LP
    start = ReducedSystem(model, model.x0())
    got = ReducedSystem(model, x, start.scale)
    assert got.cost(start.scale, EFFICIENT) <= start.cost(start.scale, EFFICIENT) + 1e-9


def test_weighted_normal_equations_are_those_of_the_reduced_rows():
    """``normal_equations`` (formed per frame, never from the dense rows) equals A^T W A, A^T W b."""
    scene = prepared_scene(cameras=4, frames=60, noise_px=NOISE, seed=3)
    system = ReducedSystem(scene.setup.model, scene.setup.model.x0())
    obs = np.repeat(np.arange(len(system.r)), 2)
    comp = np.tile([0, 1], len(system.r))
    A = system.rows(obs, comp)
    w = np.random.default_rng(0).uniform(0.1, 2.0, system.r.shape)
    H, g = system.normal_equations(w)
    np.testing.assert_allclose(H, A.T @ (w.ravel()[:, None] * A), rtol=1e-9, atol=1e-9 * np.abs(H).max())
    np.testing.assert_allclose(g, A.T @ (w.ravel() * system.b.ravel()), rtol=1e-9, atol=1e-9 * np.abs(g).max())


@pytest.mark.parametrize("seed", [0, 1])
def test_irls_scheme_reaches_the_lp_schemes_optimum(seed):
    """The default scheme (IRLS steps, then LP steps written about the IRLS point) lands on the
    optimum the LP-only scheme reaches: the same cost to a tight tolerance and the same poses to a
    small fraction of their standard errors. A clean rig with under ``SUBSET_ONLY_ABOVE *
    SUBSET_FRAMES`` frames, so both run one phase from one start and take the same robust scale."""
    scene = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=seed)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=seed)
    x_lp, info_lp = slp.refine_lp(model, scheme="lp")
    x_irls, info_irls = slp.refine_lp(model, scheme="irls")
    assert info_lp["status"] == info_irls["status"] == "converged"
    assert info_irls["irls_steps"] > 0
    scale = info_lp["robust_scale_px"]
    assert info_irls["robust_scale_px"] == pytest.approx(scale, rel=1e-12)
    at_lp, at_irls = ReducedSystem(model, x_lp, scale), ReducedSystem(model, x_irls, scale)
    # the stop allows CONVERGED_GAIN per parameter; both land on an LP optimum, far closer
    assert at_irls.cost(scale, EFFICIENT) == pytest.approx(at_lp.cost(scale, EFFICIENT), rel=1e-6)
    n = model.frame_col0
    assert np.max(np.abs(x_irls[:n] - x_lp[:n]) / at_lp.standard_errors()) < 0.05


def test_gauss_newton_step_is_that_of_the_reduced_rows():
    """The Gauss-Newton step (its Schur complement formed per frame with the elimination's own
    weights) is the least-squares step of the dense reduced rows with the kept rows."""
    scene = prepared_scene(cameras=4, frames=60, noise_px=NOISE, seed=3)
    model = perturbed_model(scene, degrees=0.5, metres=0.01, seed=3)
    system = ReducedSystem(model, model.x0())
    obs = np.repeat(np.arange(len(system.r)), 2)
    comp = np.tile([0, 1], len(system.r))
    A = system.rows(obs, comp)
    w = system.kept.ravel().astype(float)
    expected = -np.linalg.solve(A.T @ (w[:, None] * A), A.T @ (w * system.b.ravel()))
    np.testing.assert_allclose(system.gauss_newton_step(), expected, rtol=1e-6, atol=1e-6 * np.abs(expected).max())


@pytest.mark.parametrize("seed", [0, 1])
def test_the_answer_is_a_fixed_point_of_the_lp_step(seed):
    """The LP's point is accepted without linearising there when the linear model predicted its
    merit; one more exact LP step, linearised at the answer, then moves no parameter by as much
    as the stop's own ``CONVERGED_SE`` standard errors. A clean rig: no row sits at the rejection
    point, whose crossing would change the estimator's rows."""
    scene = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=seed)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=seed)
    x, info = slp.refine_lp(model)
    assert info["status"] == "converged"
    system = ReducedSystem(model, x, info["robust_scale_px"])
    rho = np.tile(np.repeat([slp.ROT_RADIUS, slp.T_RADIUS], 3), model.frame_col0 // 6)
    d, step = lpstep.solve_step(system, rho, None, EFFICIENT, lpstep.GUARD_SE)
    assert step["status"] == "optimal"
    assert np.max(np.abs(d) / system.standard_errors()) < slp.CONVERGED_SE


def test_lp_covariance_is_the_information_matrix_at_its_solution():
    """``lp``'s pose covariance comes from the reduced system its last step was taken on; it is
    ``ba``'s information matrix at lp's solution (calib/run/refine/methods.py's `paper_covariance`, which cost one
    more linearisation). The two linearisations lie the LP's last steps apart (a few standard
    errors, ~1e-4 of the rig's depth), and the reduced system leaves out only rows beyond
    REJECT_SIGMAS (6 sigma: a Gaussian share of 2e-9), so on a capture without gross outliers (the
    pipeline drops them before lp's final solve) they agree to 1e-3."""
    from wandcal.calib.solve.ba import bundle_adjust_points
    from wandcal.calib.solve.wandmodel import WandModel

    scene = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=4)
    model = scene.setup.model
    x, info, cov = slp.refine_lp_covariance(model, model.p.n_frames)
    assert info["status"] == "converged"
    R, t = model.poses(x)
    ref = bundle_adjust_points(WandModel(model.p, R, t, model.wand(x), model.fixed), None, None, loss="linear",
                               max_iter=0).covariance
    assert np.array_equal(cov.free, ref.free)
    np.testing.assert_allclose(np.sqrt(np.diag(cov.cov)), np.sqrt(np.diag(ref.cov)), rtol=1e-3)
    assert np.linalg.norm(cov.cov - ref.cov) <= 1e-3 * np.linalg.norm(ref.cov)
    assert np.linalg.norm(cov.centroid_response - ref.centroid_response) <= 1e-3 * np.linalg.norm(ref.centroid_response)
    np.testing.assert_allclose(cov.centroid_cov, ref.centroid_cov, rtol=1e-3, atol=1e-3 * np.abs(ref.centroid_cov).max())
    assert cov.point_sigma_m == pytest.approx(ref.point_sigma_m, rel=1e-3)
