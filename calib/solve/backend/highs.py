"""A thin, bounded wrapper around HiGHS (highspy) for the LP steps.

Statuses map to a small set of words the pipeline reports; a solve that hits its time limit
returns HiGHS's best point, marked ``time_limit``.
"""

from __future__ import annotations

import ctypes
import dataclasses
import os
import sys
import threading
import time
from dataclasses import dataclass

import highspy
import numpy as np
import scipy.sparse as sp

INF = highspy.kHighsInf
# HiGHS prints its banner ("Running HiGHS 1.16.0 ... Copyright") to the process's stdout from the
# first Highs() of a process, before any option can be set; new_highs() hides that one call.
_banner_lock = threading.Lock()
_banner_done = threading.Event()


def new_highs() -> highspy.Highs:
    """A silent ``highspy.Highs``: no banner on stdout, ``output_flag`` off (a command's stdout
    carries its result, and ``--quiet`` means quiet)."""
    with _banner_lock:
        if _banner_done.is_set():
            h = highspy.Highs()
        else:
            h = _without_stdout(highspy.Highs)
            _banner_done.set()
    h.setOptionValue("output_flag", False)
    return h


def _without_stdout(make):
    """``make()`` with file descriptor 1 pointed at /dev/null: the banner is written by C++ code,
    past Python's ``sys.stdout``. C's buffer is flushed before fd 1 comes back, or the banner
    would reach it at exit. Where fd 1 cannot be moved (closed, no libc), ``make()`` as is."""
    try:
        libc = ctypes.CDLL(None)
        sys.stdout.flush()
        libc.fflush(None)
        saved = os.dup(1)
    except (OSError, AttributeError, ValueError):
        return make()
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        made = make()
        libc.fflush(None)
        return made
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


@dataclass(frozen=True, eq=False)
class LpResult:
    """x: (n,) primal values (None when there is none); status: "optimal", "time_limit",
    "infeasible", "unbounded" or "error"; duals: (m,) row duals when available; basis (from
    :func:`solve_lp`): the optimal simplex basis, to warm-start a later solve of a like-shaped LP."""

    x: np.ndarray | None
    status: str
    objective: float
    seconds: float
    iterations: int
    message: str
    row_duals: np.ndarray | None = None
    basis: highspy.HighsBasis | None = None

    def __bool__(self) -> bool:
        return self.x is not None and self.status in ("optimal", "time_limit")


def solve_lp(
    c: np.ndarray,
    A: sp.spmatrix,
    row_lo: np.ndarray,
    row_hi: np.ndarray,
    col_lo: np.ndarray,
    col_hi: np.ndarray,
    time_limit: float | None = None,
    solver: str = "choose",
    options: dict | None = None,
    basis: highspy.HighsBasis | None = None,
) -> LpResult:
    """Minimise ``c @ x`` subject to ``row_lo <= A @ x <= row_hi`` and ``col_lo <= x <= col_hi``.

    Args:
        c: (n,) costs. A: (m, n) sparse constraint matrix. Bounds may be +-np.inf.
        time_limit: seconds, or None for no limit.
        solver: HiGHS's "choose", "simplex" or "ipm".
        options: extra HiGHS options.
        basis: a basis from an earlier :class:`LpResult` of an LP with the same rows and
            columns (coefficients may differ); the solve then starts from it with the simplex
            method. After a small change of coefficients this is tens of times faster than a
            cold solve (docs/decisions/0005-paper-warm-start.md).
    """
    start = time.perf_counter()
    A = sp.csc_matrix(A)
    h = new_highs()
    h.setOptionValue("solver", solver)
    if time_limit is not None:
        h.setOptionValue("time_limit", float(time_limit))
    for key, value in (options or {}).items():
        h.setOptionValue(key, value)
    lp = highspy.HighsLp()
    lp.num_col_ = A.shape[1]
    lp.num_row_ = A.shape[0]
    lp.col_cost_ = np.asarray(c, float)
    lp.col_lower_ = _inf(col_lo)
    lp.col_upper_ = _inf(col_hi)
    lp.row_lower_ = _inf(row_lo)
    lp.row_upper_ = _inf(row_hi)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = A.indptr.astype(np.int32)
    lp.a_matrix_.index_ = A.indices.astype(np.int32)
    lp.a_matrix_.value_ = A.data.astype(float)
    lp.a_matrix_.num_col_ = A.shape[1]
    lp.a_matrix_.num_row_ = A.shape[0]
    h.passModel(lp)
    if basis is not None and len(basis.col_status) == lp.num_col_ and len(basis.row_status) == lp.num_row_:
        h.setOptionValue("solver", "simplex")
        h.setBasis(basis)
    h.run()
    res = _result(h, time.perf_counter() - start)
    if res.status == "optimal" and h.getInfo().basis_validity:
        res = dataclasses.replace(res, basis=h.getBasis())
    return res


def _result(h, seconds: float) -> LpResult:
    status = h.getModelStatus()
    text = h.modelStatusToString(status)
    info = h.getInfo()
    iterations = int(max(info.simplex_iteration_count, 0) + max(info.ipm_iteration_count, 0))
    word = {
        highspy.HighsModelStatus.kOptimal: "optimal",
        highspy.HighsModelStatus.kTimeLimit: "time_limit",
        highspy.HighsModelStatus.kIterationLimit: "time_limit",
        highspy.HighsModelStatus.kInfeasible: "infeasible",
        highspy.HighsModelStatus.kUnbounded: "unbounded",
        highspy.HighsModelStatus.kUnboundedOrInfeasible: "infeasible",
    }.get(status, "error")
    x = duals = None
    if word in ("optimal", "time_limit"):
        sol = h.getSolution()
        if sol.value_valid:
            x = np.array(sol.col_value)
            if sol.dual_valid:
                duals = np.array(sol.row_dual)
        else:
            word = "error" if word == "optimal" else word
    objective = float(info.objective_function_value) if x is not None else float("nan")
    return LpResult(x=x, status=word, objective=objective, seconds=seconds, iterations=iterations, message=text,
                    row_duals=duals)


def _inf(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    return np.where(np.isposinf(v), INF, np.where(np.isneginf(v), -INF, v))


class IncrementalLp:
    """An equality-form LP ``min c.x, A x = rhs, lo <= x <= hi`` that grows by columns and
    changes its right-hand side between solves, each solve warm-started from the last basis.

    Args:
        rhs: (m,) right-hand side; the rows start empty.
        time_limit: seconds per solve, or None.
    """

    def __init__(self, rhs: np.ndarray, time_limit: float | None = None):
        self.h = new_highs()
        self.h.setOptionValue("solver", "simplex")
        # presolve finds nothing to remove in these LPs (few dense rows) and took a third of
        # the first solve's time at 16 cameras (0.2 of 0.6 s, HiGHS 1.15)
        self.h.setOptionValue("presolve", "off")
        # nor does scaling pay: the LP step's rows are camera parameters (radians, metres) whose
        # columns HiGHS's equilibration only reshuffles; off, its dual simplex took 10-35% fewer
        # iterations on 8 LP steps at 16 and 32 x 2000 (32 cameras: 0.56 s against 0.73 s on
        # average, the same steps; decision 0004, fourth session)
        self.h.setOptionValue("simplex_scale_strategy", 0)
        if time_limit is not None:
            self.h.setOptionValue("time_limit", float(time_limit))
        rhs = np.asarray(rhs, float)
        self.m = len(rhs)
        self.h.addRows(self.m, rhs, rhs, 0, np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0))
        self.n = 0

    def add_columns(self, cost: np.ndarray, lo: np.ndarray, hi: np.ndarray, A: sp.spmatrix | np.ndarray) -> None:
        """Append columns: costs (k,), bounds (k,), and their (m, k) coefficients, sparse or dense.

        Dense columns (the LP step's pairs) go to HiGHS as they are, every entry stored: a CSC
        copy scans them for zeros they hardly have (1.2 s against 0.3 s for 15k pairs at 128
        cameras)."""
        if isinstance(A, np.ndarray):
            m, k = A.shape
            start = np.arange(0, m * k, m, dtype=np.int32)
            index = np.tile(np.arange(m, dtype=np.int32), k)
            self.h.addCols(k, np.asarray(cost, float), _inf(lo), _inf(hi), m * k, start, index,
                           np.asarray(A, float).ravel(order="F"))
            self.n += k
            return
        A = sp.csc_matrix(A)
        self.h.addCols(
            A.shape[1], np.asarray(cost, float), _inf(lo), _inf(hi), A.nnz,
            A.indptr[:-1].astype(np.int32), A.indices.astype(np.int32), A.data.astype(float),
        )
        self.n += A.shape[1]

    def solve(self, strategy: int | None = None) -> LpResult:
        """Solve, from the last basis when there is one. ``strategy``: HiGHS's simplex_strategy
        (1 dual, 4 primal); primal suits a re-solve after adding columns, whose basis stays
        primal feasible."""
        start = time.perf_counter()
        if strategy is not None:
            self.h.setOptionValue("simplex_strategy", int(strategy))
        self.h.run()
        return _result(self.h, time.perf_counter() - start)

    def set_basis(self, basic: np.ndarray, at_upper: np.ndarray) -> None:
        """Start the next solve from a basis: ``basic`` (n_columns,) mask of the basic columns
        (as many as rows), the others at their upper bound where ``at_upper``, else at their
        lower; the rows' slacks are nonbasic (the rows are equalities)."""
        kind = highspy.HighsBasisStatus
        basis = self.h.getBasis()
        basis.col_status = [
            kind.kBasic if b else kind.kUpper if u else kind.kLower
            for b, u in zip(basic, at_upper)
        ]
        basis.row_status = [highspy.HighsBasisStatus.kLower] * self.m
        basis.valid = True
        self.h.setBasis(basis)
