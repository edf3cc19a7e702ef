"""The Schur-complement Levenberg–Marquardt of ``--method ba`` against a reference solver and the
Cramér–Rao bound of the injected noise."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene
from wandcal.calib.solve import ba
from wandcal.calib.solve.backend import schur
from wandcal.calib.solve.reprojection import BundleState, WandTerm

NOISE = 0.5


def test_reaches_the_optimum_of_a_reference_least_squares_solver():
    """Plain least squares: the same minimum as scipy's trust-region solver run to tight tolerances
    (the previous ``ba``), to a small fraction of the poses' standard errors."""
    scene = prepared_scene(cameras=5, frames=300, noise_px=NOISE, seed=3)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=3)
    ref = least_squares(model.residuals, model.x0(), jac=model.jacobian, method="trf", x_scale="jac",
                        ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=200, tr_solver="lsmr")
    x, info = ba.bundle_adjust(model, loss="linear")
    assert info["status"] == "converged" and info["iterations"] <= 8
    cost = 0.5 * float(model.residuals(x) @ model.residuals(x))
    # the stop leaves each parameter within STOP_SE standard errors of the optimum: the cost is
    # then above the minimum by about STOP_SE^2 / 2 per parameter, in units of sigma^2
    assert cost - ref.cost <= ba.STOP_SE**2 / 2 * model.n_params * NOISE**2 + 1e-9
    T = scene.sim.truth
    bound, _ = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
    R, t = model.poses(x)
    R_ref, t_ref = model.poses(ref.x)
    diff, _ = gauge_errors(R, t, R_ref, t_ref, 0)
    assert np.all(diff[1:] < 4 * ba.STOP_SE * bound[1:])


def test_a_stop_on_the_cameras_leaves_them_as_near_the_optimum():
    """The pipeline's stop judges the cameras, not the wand frames (decision 0032): the poses are
    still within a small fraction of their Cramér–Rao bound of the reference optimum, and the run
    takes no more iterations than the stop that waits for every frame."""
    scene = prepared_scene(cameras=5, frames=300, noise_px=NOISE, seed=3)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=3)
    ref = least_squares(model.residuals, model.x0(), jac=model.jacobian, method="trf", x_scale="jac",
                        ftol=1e-15, xtol=1e-15, gtol=1e-15, max_nfev=200, tr_solver="lsmr")
    every = ba.bundle_adjust_points(model, None, None, loss="linear", standard_errors=False)
    cameras = ba.bundle_adjust_points(model, None, None, loss="linear", standard_errors=False, judge_frames=False)
    assert cameras.info["status"] == "converged" and cameras.info["iterations"] <= every.info["iterations"]
    T = scene.sim.truth
    bound, _ = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
    diff, _ = gauge_errors(*model.poses(cameras.x), *model.poses(ref.x), 0)
    assert np.all(diff[1:] < 4 * ba.STOP_SE * bound[1:])


@pytest.mark.parametrize("loss", ba.LOSSES)
def test_reaches_the_cramer_rao_bound(loss):
    ratios = []
    for seed in range(3):
        scene = prepared_scene(cameras=5, frames=300, noise_px=NOISE, seed=seed)
        model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=seed)
        x, info = ba.bundle_adjust(model, loss=loss)
        assert info["status"] == "converged" and info["loss"] == loss
        T = scene.sim.truth
        bound, _ = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
        err, _ = gauge_errors(*model.poses(x), T.R, T.t, 0)
        ratios += list(err[1:] / bound[1:])
    # an efficient estimator has RMS(error / sqrt(CRB)) ~ 1; 12 cameras make 1.6 a >99% bound
    # (the Cauchy loss at 4 sigma is ~99% efficient on Gaussian noise)
    assert np.sqrt(np.mean(np.square(ratios))) < 1.6


def test_cauchy_loss_ignores_gross_outliers_without_a_re_solve():
    """8% of camera-frames carry a 20-60 px outlier: least squares is dragged off, the robust loss
    stays within the bound's reach of the clean data."""
    ratios, ls_ratios = [], []
    for seed in range(2):
        scene = prepared_scene(cameras=6, frames=400, noise_px=NOISE, seed=seed, outliers=0.08)
        model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=seed)
        T = scene.sim.truth
        bound, _ = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
        x, info = ba.bundle_adjust(model)
        assert info["status"] == "converged" and info["loss_scale_px"] < 4 * ba.CAUCHY_SIGMAS * NOISE
        ratios += list(gauge_errors(*model.poses(x), T.R, T.t, 0)[0][1:] / bound[1:])
        x_ls, _ = ba.bundle_adjust(model, loss="linear")
        ls_ratios += list(gauge_errors(*model.poses(x_ls), T.R, T.t, 0)[0][1:] / bound[1:])
    rms = lambda r: float(np.sqrt(np.mean(np.square(r))))  # noqa: E731
    assert rms(ratios) < 1.6  # as above: the outliers' remaining weight (~1e-3) costs almost nothing
    assert rms(ls_ratios) > 3 * rms(ratios)  # and they do matter to least squares


def test_returns_the_model_parameters_of_its_state():
    """x maps back through the model's own parametrisation (Euler increments, wand directions)."""
    scene = prepared_scene(cameras=4, frames=80, noise_px=NOISE, seed=2)
    model = perturbed_model(scene, degrees=0.5, metres=0.01, seed=2)
    x, _ = ba.bundle_adjust(model, max_iter=2)
    wand = model.wand(x)
    assert np.allclose(np.linalg.norm(wand[:, 1] - wand[:, 0], axis=1), model.p.length)
    r = model.residuals(x)
    x_again, info = ba.bundle_adjust(model, x0=x, loss="linear")
    assert 0.5 * float(model.residuals(x_again) @ model.residuals(x_again)) <= 0.5 * float(r @ r) + 1e-9
    R, _ = model.poses(x)
    assert np.allclose(R[0], model.R0[0]) and np.allclose(np.einsum("nij,nkj->nik", R, R), np.eye(3))


def test_rejects_an_unknown_loss():
    scene = prepared_scene(cameras=3, frames=40, noise_px=NOISE, seed=1)
    with pytest.raises(ValueError, match="loss"):
        ba.bundle_adjust(scene.setup.model, loss="huber")


def test_polish_takes_an_undamped_step_then_a_chord_step_and_reuses_its_inverse(monkeypatch):
    """The least-squares polish of a robust solution (the pipeline's second ``ba`` run): one
    normal matrix solved once, undamped; the step after it is the chord method's (the same
    inverse, the new gradient), and the standard errors come from that same solve. They agree
    with a fresh solve at the final point, two steps of under a few standard errors away."""
    scene = prepared_scene(cameras=5, frames=300, noise_px=NOISE, seed=4)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=4)
    robust = ba.bundle_adjust_points(model, None, None, stop_se=0.5, standard_errors=False)
    solves = []
    solve = schur.solve
    monkeypatch.setattr(schur, "solve", lambda normal, lam: solves.append(lam) or solve(normal, lam))
    polish = ba.bundle_adjust_points(model, None, None, x0=robust.x, loss="linear")
    assert polish.info["status"] == "converged" and polish.info["iterations"] == 2
    assert solves == [0.0]  # no damping, no second Gram, no solve for the standard errors
    monkeypatch.setattr(schur, "solve", solve)
    fresh = ba.bundle_adjust_points(model, None, None, x0=polish.x, loss="linear", max_iter=0)
    free = ~model.fixed
    # the inverse is taken one step (< 2 SE) before the end: the Jacobian there differs by about
    # that step over the cameras' distance (1e-3 m over metres), and so do the standard errors
    assert np.allclose(polish.camera_std[free], fresh.camera_std[free], rtol=1e-3)
    # the chord step leaves the polish at least as close to the optimum as STOP_SE says
    x_more = ba.bundle_adjust_points(model, None, None, x0=polish.x, loss="linear", stop_se=1e-6,
                                     standard_errors=False).x
    diff, _ = gauge_errors(*model.poses(polish.x), *model.poses(x_more), 0)
    T = scene.sim.truth
    bound, _ = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
    assert np.all(diff[1:] < 4 * ba.STOP_SE * bound[1:])


def _wand_normal_equations():
    """The normal equations of a 4-camera, 120-frame wand problem (seed 5) at a start 0.5 deg / 1 cm
    off its truth: the system a solve and its reuse are compared on."""
    scene = prepared_scene(cameras=4, frames=120, noise_px=NOISE, seed=5)
    model = perturbed_model(scene, degrees=0.5, metres=0.01, seed=5)
    p = model.p
    R, t = model.poses(model.x0())
    wand = model.wand(model.x0())
    d = wand[:, 1] - wand[:, 0]
    state = BundleState(R, t, wand.mean(axis=1), d / np.linalg.norm(d, axis=1, keepdims=True), np.zeros((0, 3)), None, None, None)
    term = WandTerm(p.camera, p.frame, p.end, p.xy, p.focal[p.camera], p.length, p.n_frames, model.free, p.n_cams)
    return schur.normal_equations(6, len(model.free), [(term.structure, lambda lo, hi: term.linearise_rows(state, slice(lo, hi)))])


def test_solve_again_with_the_same_gradient_is_the_same_step():
    """``solve_again`` reuses a solve's inverses: on that solve's own system it gives its step."""
    normal = _wand_normal_equations()
    step = schur.solve(normal, 0.0)
    again = schur.solve_again(normal, step)
    assert np.allclose(again.dc, step.dc, rtol=1e-9, atol=1e-12 * np.abs(step.dc).max())
    assert np.allclose(again.dp[0], step.dp[0], rtol=1e-9, atol=1e-12 * np.abs(step.dp[0]).max())


@pytest.mark.parametrize("cameras", [12, 64])
def test_the_reduction_by_each_frames_own_cameras_is_the_dense_one(cameras):
    """A rig whose frames each 2-4 of its cameras see (calib/sim/shapes.py) is reduced by each
    frame's own camera pairs: the same reduced camera system as the dense product, to rounding."""
    rng = np.random.default_rng(7)
    frames, c, p = 400, 6, 5
    seen = [np.sort(rng.choice(cameras, rng.integers(2, 5), replace=False)) for _ in range(frames)]
    cam = np.concatenate(seen)
    pt = np.repeat(np.arange(frames), [len(s) for s in seen])
    structure = schur.TermStructure(cam, cam, pt, cameras, frames, p)
    W = rng.normal(size=(len(structure.pair_cam), c, p))
    LinvT = np.triu(rng.normal(size=(frames, p, p)))
    per_block = np.bincount(structure.pair_pt, minlength=frames)
    sparse, dense = np.zeros((cameras * c, cameras * c)), np.zeros((cameras * c, cameras * c))
    schur._subtract_gram_sparse(sparse, W, LinvT, structure, per_block)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(schur, "SPARSE_GRAM_FILL", 0.0)  # the dense product whatever the rig
        schur._subtract_gram(dense, W, LinvT, structure)
    assert np.abs(dense).max() > 0
    assert np.allclose(sparse, dense, rtol=0, atol=1e-12 * np.abs(dense).max())


def test_a_wide_reduced_system_is_solved_by_lapacks_cholesky_inverse_as_by_numpys(monkeypatch):
    """A reduced camera system from :data:`schur.LAPACK_INVERSE_WIDTH` wide is inverted from its
    Cholesky factor (LAPACK's potrf, potri): the same step and standard errors as NumPy's LU
    inverse, to rounding; a system damped below positive definiteness gives no step either way."""
    normal = _wand_normal_equations()
    narrow = schur.solve(normal, 1e-3)
    monkeypatch.setattr(schur, "LAPACK_INVERSE_WIDTH", 1)
    wide = schur.solve(normal, 1e-3)
    assert narrow is not None and wide is not None
    assert np.array_equal(wide.cam_cov, wide.cam_cov.T)
    assert np.allclose(wide.cam_cov, narrow.cam_cov, rtol=0, atol=1e-12 * np.abs(narrow.cam_cov).max())
    assert np.allclose(wide.dc, narrow.dc, rtol=0, atol=1e-12 * np.abs(narrow.dc).max())
    assert np.allclose(wide.cam_var, narrow.cam_var, rtol=1e-10)
    indefinite = np.eye(3)
    indefinite[2, 2] = -1.0
    assert schur._spd_inverse(indefinite) is None
    monkeypatch.setattr(schur, "LAPACK_INVERSE_WIDTH", 1024)
    assert schur._spd_inverse(indefinite) is None


def test_the_reduced_systems_inverse_from_its_cholesky_factor_is_the_inverse():
    """Below :data:`schur.LAPACK_INVERSE_WIDTH` the reduced system's inverse is kept as the inverse
    of its Cholesky factor, that inverse taken by halves (:func:`schur._lower_inverse`) once wider
    than :data:`schur.TRIANGULAR_BLOCK`: S^-1 b, diag(S^-1) and S^-1 itself are the inverse's to
    rounding. A backward-stable inverse is off by at most about n eps cond(S) relative; the bound
    asserted is ten times that."""
    rng = np.random.default_rng(3)
    n = 2 * schur.TRIANGULAR_BLOCK + 37  # two levels of halves, odd widths
    A = rng.normal(size=(n, n))
    S = A @ A.T + n * np.diag(rng.uniform(0.5, 2.0, n))
    b = rng.normal(size=n)
    inverse = schur._spd_inverse(S)
    assert inverse is not None and inverse._factor is not None  # kept as the factor's inverse
    truth = np.linalg.inv(S)
    bound = 10 * n * np.finfo(float).eps * np.linalg.cond(S)
    assert np.allclose(inverse.times(b), truth @ b, rtol=0, atol=bound * np.abs(truth @ b).max())
    assert np.allclose(inverse.diagonal(), np.diag(truth), rtol=bound)
    assert np.allclose(inverse.full(), truth, rtol=0, atol=bound * np.abs(truth).max())
    assert np.allclose(np.tril(inverse._factor), inverse._factor)  # lower triangular, as L^-1 is
