"""Damped normal equations of a bundle adjustment, solved by the Schur complement.

The unknowns are camera blocks (``c`` parameters each) and, in one or more *terms*, point-like
blocks (a wand frame: 5 parameters; a free 3D point: 3). Every observation (2 residual rows)
touches one camera and one block of one term, so the normal matrix is

    [ U   W ]      U: block diagonal over cameras (c x c),
    [ W^T V ]      V: block diagonal over points (p x p), W: one c x p block per camera-point pair.

Eliminating the points leaves the dense reduced camera system ``S = U - W V^-1 W^T`` (Triggs et
al., *Bundle Adjustment: A Modern Synthesis*, sec. 6.1; Ceres's ``DENSE_SCHUR``), of size 6N,
solved by Cholesky; the points follow by back-substitution. Everything is batched over blocks:
per-observation products are summed into blocks by sparse incidence matrices built once per
problem, and ``W V^-1 W^T`` is one dense matrix product per chunk of points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp

CHUNK_ENTRIES = 2_000_000  # doubles per dense chunk of the reduction (16 MB): bounds memory at any rig size
CHUNK_GROUPS = 32_768  # observation groups whose products are formed at once: 32 MB at 11 parameters
MIN_DIAGONAL = 1e-9  # floor of the damping's diagonal, as Ceres's min_lm_diagonal: a parameter no
# residual touches would otherwise make the damped system singular


def _incidence(rows: np.ndarray, n_rows: int) -> sp.csr_matrix:
    """(n_rows, len(rows)) 0/1 matrix summing observations into their row; rows < 0 are left out."""
    keep = np.flatnonzero(rows >= 0)
    return sp.csr_matrix((np.ones(len(keep)), (rows[keep], keep)), shape=(n_rows, len(rows)))


class TermStructure:
    """Who sees what in one term, fixed for a problem.

    Observations of the same camera and block that sit next to each other form a *group* (the
    two ends of a wand seen by one camera in one frame): their products are summed in one
    batched product before the blocks are summed.

    Args:
        cam: (M,) free-camera index of each observation, or -1 for a camera held fixed.
        cam_all: (M,) camera index, fixed cameras included.
        pt: (M,) block index in [0, n_pts).
        n_cams: number of free cameras; n_pts: number of blocks; size: parameters per block.
    """

    def __init__(self, cam: np.ndarray, cam_all: np.ndarray, pt: np.ndarray, n_cams: int, n_pts: int, size: int):
        self.cam, self.pt, self.n_cams, self.n_pts, self.size = cam, pt, n_cams, n_pts, size
        M = len(cam)
        run_start = np.flatnonzero(np.r_[True, (cam_all[1:] != cam_all[:-1]) | (pt[1:] != pt[:-1])]) if M else np.zeros(0, int)
        lengths = np.diff(np.r_[run_start, M])
        self.group = int(lengths[0]) if M and np.all(lengths == lengths[0]) else 1
        first = np.arange(0, M, self.group)
        g_cam, g_pt = cam[first], pt[first]
        free = g_cam >= 0
        key = np.where(free, g_pt.astype(np.int64) * max(n_cams, 1) + g_cam, -1)
        pairs, pair_of = np.unique(key[free], return_inverse=True)
        self.pair_cam = pairs % max(n_cams, 1)
        self.pair_pt = pairs // max(n_cams, 1)
        g_pair = np.full(len(first), -1)
        g_pair[free] = pair_of
        # per chunk of groups: (start, stop, sums into cameras, into blocks, into camera-block pairs)
        self.chunks = [
            (a, a + CHUNK_GROUPS, _incidence(g_cam[a : a + CHUNK_GROUPS], n_cams), _incidence(g_pt[a : a + CHUNK_GROUPS], n_pts),
             _incidence(g_pair[a : a + CHUNK_GROUPS], len(pairs)))
            for a in range(0, len(first), CHUNK_GROUPS)
        ]
        self.n_pairs = len(pairs)
        self.pair_to_cam = _incidence(self.pair_cam, n_cams)
        self.pair_to_pt = _incidence(self.pair_pt, n_pts)


@dataclass(eq=False)
class TermBlocks:
    """One term's normal-equation blocks: V (P, p, p), gp (P, p), W (pairs, c, p)."""

    structure: TermStructure
    V: np.ndarray
    gp: np.ndarray
    W: np.ndarray


@dataclass(eq=False)
class Normal:
    """The undamped normal equations: U (N, c, c), gc (N, c), and the terms' blocks."""

    U: np.ndarray
    gc: np.ndarray
    terms: list[TermBlocks]


def normal_equations(cam_size: int, n_cams: int, parts) -> Normal:
    """Sum the per-observation products into blocks.

    Args:
        cam_size: c; n_cams: free cameras.
        parts: list of (structure, r (M, 2), J (M, 2, c + p)): residuals and Jacobians (camera
            columns first), already multiplied by the square roots of their weights.
    """
    c = cam_size
    U = np.zeros((n_cams, c, c))
    gc = np.zeros((n_cams, c))
    terms = []
    for s, r, J in parts:
        k = J.shape[2]
        p = k - c
        Jg = J.reshape(-1, 2 * s.group, k)
        rg = r.reshape(len(Jg), -1)
        V = np.zeros((s.n_pts, p * p))
        gp = np.zeros((s.n_pts, p))
        W = np.zeros((s.n_pairs, c * p))
        for a, b, to_cam, to_pt, to_pair in s.chunks:
            Jc, Jp, rc = Jg[a:b, :, :c], Jg[a:b, :, c:], rg[a:b]
            U += (to_cam @ np.einsum("gri,grj->gij", Jc, Jc, optimize=True).reshape(len(rc), -1)).reshape(n_cams, c, c)
            gc += to_cam @ np.einsum("gri,gr->gi", Jc, rc)
            V += to_pt @ np.einsum("gri,grj->gij", Jp, Jp, optimize=True).reshape(len(rc), -1)
            gp += to_pt @ np.einsum("gri,gr->gi", Jp, rc)
            W += to_pair @ np.einsum("gri,grj->gij", Jc, Jp, optimize=True).reshape(len(rc), -1)
        terms.append(TermBlocks(s, V.reshape(-1, p, p), gp, W.reshape(-1, c, p)))
    return Normal(U, gc, terms)


def _damped(blocks: np.ndarray, lam: float) -> np.ndarray:
    """blocks + lam * diag(blocks), Marquardt's scaling, with the diagonal floored."""
    diag = np.maximum(np.einsum("...ii->...i", blocks), MIN_DIAGONAL)
    out = blocks.copy()
    idx = np.arange(blocks.shape[-1])
    out[..., idx, idx] += lam * diag
    return out


@dataclass(eq=False)
class Step:
    """A solved step: dc (N, c) for the cameras, dp per term (P, p), and, for standard errors,
    the diagonal of the reduced camera system's inverse (N, c) and of each V^-1 (P, p)."""

    dc: np.ndarray
    dp: list[np.ndarray]
    cam_var: np.ndarray
    pt_var: list[np.ndarray]


def solve(normal: Normal, lam: float) -> Step | None:
    """Solve the damped system (U + lam D) for the step; None when it is not positive definite.

    With V = L L^T per block and Z = W L^-T per camera-block pair, the reduction W V^-1 W^T is
    the Gram matrix Z Z^T: one dense symmetric product per chunk of blocks."""
    n, c = normal.gc.shape
    S = _damped(normal.U, lam)
    S = scipy.linalg.block_diag(*S) if n else np.zeros((0, 0))
    b = normal.gc.copy()
    solved = []
    for t in normal.terms:
        s = t.structure
        try:
            L = np.linalg.cholesky(_damped(t.V, lam))
        except np.linalg.LinAlgError:
            return None
        Linv = np.linalg.inv(L)  # lower triangular, (P, p, p)
        Z = t.W @ np.swapaxes(Linv, 1, 2)[s.pair_pt]  # (pairs, c, p)
        h = np.einsum("pij,pj->pi", Linv, t.gp)
        b -= s.pair_to_cam @ np.einsum("kij,kj->ki", Z, h[s.pair_pt])
        _subtract_gram(S, Z, s)
        solved.append(np.swapaxes(Linv, 1, 2) @ Linv)  # V^-1
    try:
        factor = scipy.linalg.cho_factor(S, check_finite=False) if n else None
    except np.linalg.LinAlgError:
        return None
    dc = -scipy.linalg.cho_solve(factor, b.ravel(), check_finite=False).reshape(n, c) if n else np.zeros((0, c))
    cam_var = np.diag(scipy.linalg.cho_solve(factor, np.eye(n * c), check_finite=False)).reshape(n, c) if n else dc
    dp, pt_var = [], []
    for t, Vinv in zip(normal.terms, solved):
        s = t.structure
        rhs = -t.gp - s.pair_to_pt @ np.einsum("kji,kj->ki", t.W, dc[s.pair_cam])
        dp.append(np.einsum("pij,pj->pi", Vinv, rhs))
        pt_var.append(np.einsum("pii->pi", Vinv))
    return Step(dc, dp, cam_var, pt_var)


def _subtract_gram(S: np.ndarray, Z: np.ndarray, s: TermStructure) -> None:
    """S -= sum over blocks of Z_a Z_b^T for every two cameras a, b that saw the block.

    The pairs (sorted by block) are laid out as a dense (cameras * c) x (blocks * p) matrix, a
    chunk of blocks at a time, so the sum is one symmetric matrix product per chunk."""
    n, c, p = s.n_cams, Z.shape[1], Z.shape[2]
    if n == 0 or len(Z) == 0:
        return
    chunk = max(1, CHUNK_ENTRIES // (n * c * p))
    bounds = np.searchsorted(s.pair_pt, np.arange(0, s.n_pts + chunk, chunk))
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]
        if a == b:
            continue
        first = k * chunk
        Zd = np.zeros((n, c, min(chunk, s.n_pts - first), p))
        Zd[s.pair_cam[a:b], :, s.pair_pt[a:b] - first] = Z[a:b]
        Zm = Zd.reshape(n * c, -1)
        S -= Zm @ Zm.T
