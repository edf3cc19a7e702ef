"""The interior-point method of the LP step's dual form, against HiGHS's simplex on the same LP."""

import numpy as np
import pytest
import scipy.sparse as sp

from wandcal.calib.solve.backend import ipm as ipm_module
from wandcal.calib.solve.backend.highs import IncrementalLp
from wandcal.calib.solve.backend.ipm import certified_duals, solve_dual_form


def _dual_form(seed, n=12, k=200):
    """A random LP of the step's shape: k dense pair columns of n rows, bounded by jumps, and a box."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(k, n))
    c = rng.normal(scale=0.1, size=k)
    jump = rng.uniform(0.2, 1.0, k)
    c_lo, c_hi = rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 2.0, n)
    r = rng.normal(scale=5.0, size=n)
    return A, c, jump, c_lo, c_hi, r


def _lp(A, c, jump, c_lo, c_hi, r):
    k, n = A.shape
    lp = IncrementalLp(r)
    eye = sp.identity(n, format="csc")
    lp.add_columns(np.r_[c_lo, c_hi], np.zeros(2 * n), np.full(2 * n, np.inf), sp.hstack([-eye, eye]))
    lp.add_columns(c, np.zeros(k), jump, A.T)
    return lp


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_interior_point_names_the_simplex_optimum(seed):
    """Its duals are the simplex's step, and its basis is optimal: HiGHS confirms it without a pivot."""
    problem = _dual_form(seed)
    cold = _lp(*problem).solve(1)
    ipm = solve_dual_form(*problem)
    assert cold.status == "optimal" and ipm.status == "optimal" and ipm.certified
    # the duals of a certified basis are its vertex's: the simplex's to rounding
    np.testing.assert_allclose(ipm.duals, cold.row_duals, rtol=1e-9, atol=1e-9 * np.abs(cold.row_duals).max())
    assert ipm.basic.sum() == len(problem[-1])
    warm = _lp(*problem)
    warm.set_basis(ipm.basic, ipm.at_upper)
    res = warm.solve(1)
    assert res.status == "optimal" and res.iterations == 0
    np.testing.assert_allclose(res.row_duals, cold.row_duals, rtol=1e-9, atol=1e-9 * np.abs(cold.row_duals).max())


def test_no_pairs_leaves_the_box():
    """With no pair columns the step sits on the box: d_j = c_hi_j where r_j > 0, -c_lo_j where r_j < 0."""
    c_lo, c_hi, r = np.array([1.0, 1.0, 1.0]), np.array([2.0, 2.0, 2.0]), np.array([1.0, -2.0, 0.5])
    ipm = solve_dual_form(np.zeros((0, 3)), np.zeros(0), np.zeros(0), c_lo, c_hi, r)
    assert ipm.status == "optimal"
    np.testing.assert_allclose(ipm.duals, [2.0, -1.0, 2.0], atol=1e-7)


def test_a_deadline_in_the_past_stops_it():
    ipm = solve_dual_form(*_dual_form(0), deadline=0.0)
    assert ipm.status == "time_limit"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_certificate_gives_the_simplex_vertex_and_refuses_a_wrong_basis(seed):
    """The interior point's basis, checked by one LU factor, gives HiGHS's row duals; a basis
    with one column swapped for another is not certified (it is not the optimal one)."""
    problem = _dual_form(seed)
    cold = _lp(*problem).solve(1)
    ipm = solve_dual_form(*problem)
    duals = certified_duals(*problem, ipm.basic, ipm.at_upper)
    assert duals is not None
    np.testing.assert_allclose(duals, cold.row_duals, rtol=1e-9, atol=1e-9 * np.abs(cold.row_duals).max())
    wrong = ipm.basic.copy()
    wrong[np.flatnonzero(wrong)[-1]] = False
    wrong[np.flatnonzero(~ipm.basic)[0]] = True
    assert certified_duals(*problem, wrong, ipm.at_upper & ~wrong) is None
    assert certified_duals(*problem, np.zeros_like(ipm.basic), ipm.at_upper) is None  # too few basic columns


def test_the_correctors_and_the_certificate_save_iterations():
    """Gondzio's correctors and the certificate tried near the end (decision 0029) take fewer
    iterations than Mehrotra's method alone to TOL, to the same vertex."""
    for seed in range(3):
        problem = _dual_form(seed, n=30, k=600)
        fast = solve_dual_form(*problem)
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(ipm_module, "CORRECTORS", 0)
            mp.setattr(ipm_module, "CERTIFY_TOL", 0.0)
            plain = solve_dual_form(*problem)
        assert fast.certified and plain.status == "optimal"
        assert fast.iterations < plain.iterations
        vertex = certified_duals(*problem, plain.basic, plain.at_upper)
        np.testing.assert_allclose(fast.duals, vertex, rtol=1e-9, atol=1e-9 * np.abs(vertex).max())


def test_a_normal_matrix_singular_without_its_light_pairs_is_factored_with_them():
    """Pairs far lighter than the heaviest are left out of the normal matrix, unless that leaves it
    singular: here only the light pair spans the third row."""
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    Dy = np.array([1.0, 1.0, 1e-10])
    factor = ipm_module._factor(ipm_module._NormalMatrix(A), Dy, np.zeros(3))
    assert factor is not None
    L = np.triu(factor[0])
    np.testing.assert_allclose(L.T @ L, A.T @ (Dy[:, None] * A), rtol=1e-6)  # the light pair in single precision


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_a_stalled_iterate_brings_the_light_pairs_back(seed, monkeypatch):
    """Normal matrices that leave out far too many pairs (all below 1e-3 of the heaviest) stop
    steering the iterate; once it stalls they keep every pair, and the method still ends at a
    certified vertex. Without the guard it runs to its iteration limit."""
    problem = _dual_form(seed, n=30, k=600)
    monkeypatch.setattr(ipm_module, "NEGLIGIBLE_WEIGHT", 1e-3)
    guarded = solve_dual_form(*problem)
    assert guarded.certified
    monkeypatch.setattr(ipm_module, "STALL", np.inf)
    assert solve_dual_form(*problem).status == "iteration_limit"
