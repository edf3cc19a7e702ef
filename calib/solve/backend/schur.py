"""Damped normal equations of a bundle adjustment, solved by the Schur complement.

The unknowns are camera blocks (``c`` parameters each) and, in one or more *terms*, point-like
blocks (a wand frame: 5 parameters; a free 3D point: 3). Every observation (2 residual rows)
touches one camera and one block of one term, so the normal matrix is

    [ U   W ]      U: block diagonal over cameras (c x c),
    [ W^T V ]      V: block diagonal over points (p x p), W: one c x p block per camera-point pair.

Eliminating the points leaves the dense reduced camera system ``S = U - W V^-1 W^T`` (Triggs et
al., *Bundle Adjustment: A Modern Synthesis*, sec. 6.1; Ceres's ``DENSE_SCHUR``), of size 6N,
solved directly; the points follow by back-substitution. Everything is batched over blocks:
per-observation products are summed into blocks by segment sums planned once per problem (no
sparse matrices: scipy.sparse alone costs 0.15 s of start-up), and ``W V^-1 W^T`` is one dense
matrix product per chunk of points.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

CHUNK_ENTRIES = 2_000_000  # doubles per dense chunk of the reduction (16 MB): bounds memory at any rig size
# the Gram by each block's camera pairs when the sum over blocks of their cameras squared is below
# this share of cameras^2 x blocks, the dense product's work. Each frame in 2-4 cameras
# (calib/sim/shapes.py, 3000 frames, random W, CPU s on the loaded machine): at 64 cameras (share
# 0.0024) 0.07 s against the dense 0.29; at 256 (0.00015) 0.07 against 1.28; every camera seeing
# every frame (the default 8-camera ring, share 1) 0.20 against 0.007. Dense BLAS gets cheaper per
# entry as the rig grows: the share where the two cost the same fell from 0.01 (64) to 0.003 (256)
SPARSE_GRAM_FILL = 0.005
SPARSE_GRAM_PRODUCTS = 65_536  # block-pair products (c x c each) at a time: ~20 MB of temporaries at c = 6
CHUNK_GROUPS = 16_384  # observation groups linearised and summed at once: ~30 MB of temporaries
MIN_DIAGONAL = 1e-9  # floor of the damping's diagonal, as Ceres's min_lm_diagonal: a parameter no
# residual touches would otherwise make the damped system singular
# the reduced camera system's width (6 x cameras) from which its inverse comes from LAPACK's Cholesky
# routines (potrf, potri: n^3 flops), whose import of scipy.linalg (0.2 CPU s) it then pays for
# (docs/decisions/0059-wide-inverse.md: 1536 wide, 256 cameras, 0.43 against 0.18 CPU s a solve for
# NumPy's Cholesky test and LU inverse). Narrower systems (every rig up to 170 cameras) keep NumPy:
# its Cholesky factor and the factor's inverse by halves in matrix products (n^3 flops with the
# test), the whole inverse formed only for the covariance (decision 0088: 768 wide, 0.024 against
# the LU inverse's 0.068 CPU s a solve)
LAPACK_INVERSE_WIDTH = 1024


DENSE_SUM_ROWS = 64  # sums into at most this many rows (cameras) go through a one-hot matrix product
# ... of at most this many entries (a chunk of groups into 64 cameras, 8 MB): the camera-block
# pairs' sums into cameras (174k pairs at 64 x 3000) would need an 88 MB matrix held all along
DENSE_SUM_ENTRIES = DENSE_SUM_ROWS * CHUNK_GROUPS


class _Sum:
    """Sums the rows of (G, ...) arrays into ``n_out`` rows by ``index`` (G,) (-1: left out).

    Calling it returns (targets (T,) or a slice, sums (T, ...)): the rows that receive something,
    each once.
    A sorted index sums contiguous runs (``np.add.reduceat``); a few output rows (cameras) take
    a one-hot matrix product; anything else is sorted first."""

    def __init__(self, index: np.ndarray, n_out: int):
        keep = index >= 0
        self.keep = None if keep.all() else np.flatnonzero(keep)
        idx = index[keep]
        self.onehot = self.order = None
        self.targets: np.ndarray | slice
        if len(idx) and n_out <= DENSE_SUM_ROWS and n_out * len(index) <= DENSE_SUM_ENTRIES and np.any(np.diff(idx) < 0):
            # a row left out is a zero column of the one-hot matrix: no copy of the kept rows
            self.targets, self.keep = slice(None), None
            self.onehot = (index[None, :] == np.arange(n_out)[:, None]).astype(float)
            return
        if np.any(np.diff(idx) < 0):
            self.order = np.argsort(idx, kind="stable")
            idx = idx[self.order]
        self.starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]]) if len(idx) else np.zeros(0, int)
        targets = idx[self.starts]
        self.single = len(self.starts) == len(idx)  # every run one row long: nothing to add up
        # consecutive output rows (a chunk's frames, its camera-frame pairs): added in place into
        # a view, not through an index
        self.targets = slice(int(targets[0]), int(targets[-1]) + 1) if len(idx) and np.all(np.diff(targets) == 1) else targets

    def __call__(self, X: np.ndarray) -> tuple[np.ndarray | slice, np.ndarray]:
        if self.keep is not None:
            X = X[self.keep]
        if self.onehot is not None:
            return self.targets, (self.onehot @ X.reshape(len(X), -1)).reshape((-1,) + X.shape[1:])
        if self.order is not None:
            X = X[self.order]
        if self.single:
            return self.targets, X
        return self.targets, np.add.reduceat(X, self.starts, axis=0)


def _summed(sum_: _Sum, X: np.ndarray, n_out: int) -> np.ndarray:
    targets, sums = sum_(X)
    out = np.zeros((n_out,) + X.shape[1:])
    out[targets] = sums
    return out


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
            (a, a + CHUNK_GROUPS, _Sum(g_cam[a : a + CHUNK_GROUPS], n_cams), _Sum(g_pt[a : a + CHUNK_GROUPS], n_pts),
             _Sum(g_pair[a : a + CHUNK_GROUPS], len(pairs)))
            for a in range(0, len(first), CHUNK_GROUPS)
        ]
        self.n_pairs = len(pairs)
        self.n_groups = len(first)
        self.pair_to_cam = _Sum(self.pair_cam, n_cams)
        self.pair_to_pt = _Sum(self.pair_pt, n_pts)


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


def normal_equations(cam_size: int, n_cams: int, parts, like: Normal | None = None) -> Normal:
    """Sum the per-observation products into blocks, a chunk of groups at a time.

    Args:
        cam_size: c; n_cams: free cameras.
        parts: list of (structure, rows) where ``rows(lo, hi)`` returns the residuals (hi-lo, 2)
            and Jacobian (hi-lo, 2, c + p) of observations lo..hi (camera columns first), already
            multiplied by the square roots of their weights. The whole Jacobian never exists at
            once: at 8 x 32,000 it would be 84 MB.
        like: None, or normal equations of the same problem whose matrix blocks (U, V, W) to
            keep: then only the gradient (gc, gp) is summed here, the chord method's system
            (the Jacobian's products, 60% of a build, are left out).
    """
    c = cam_size
    U = np.zeros((n_cams, c, c)) if like is None else like.U
    gc = np.zeros((n_cams, c))
    terms = []
    for k, (s, rows) in enumerate(parts):
        p = s.size
        V = np.zeros((s.n_pts, p, p)) if like is None else like.terms[k].V
        gp = np.zeros((s.n_pts, p))
        W = np.zeros((s.n_pairs, c, p)) if like is None else like.terms[k].W
        for a, b, to_cam, to_pt, to_pair in s.chunks:
            r, J = rows(a * s.group, min(b, s.n_groups) * s.group)
            Jg = J.reshape(-1, 2 * s.group, c + p)
            rc = r.reshape(len(Jg), -1)
            Jc, Jp = Jg[:, :, :c], Jg[:, :, c:]
            sums = [(gp, np.einsum("gri,gr->gi", Jp, rc), to_pt)]
            if like is None:
                # the products by matmul on the transposed views: half the time of einsum's
                # batched product (which copies the column slices first), the same sums; a
                # camera's products and gradient side by side, summed in one pass
                JcT = np.swapaxes(Jc, 1, 2)
                cam = np.empty((len(Jg), c * c + c))
                np.matmul(JcT, Jc, out=cam[:, : c * c].reshape(-1, c, c))
                cam[:, c * c :] = np.einsum("gri,gr->gi", Jc, rc)
                targets, summed = to_cam(cam)
                U[targets] += summed[:, : c * c].reshape(-1, c, c)
                gc[targets] += summed[:, c * c :]
                sums += [(V, np.swapaxes(Jp, 1, 2) @ Jp, to_pt), (W, JcT @ Jp, to_pair)]
            else:
                sums.append((gc, np.einsum("gri,gr->gi", Jc, rc), to_cam))
            for out, products, sum_ in sums:
                targets, summed = sum_(products)
                out[targets] += summed
        terms.append(TermBlocks(s, V, gp, W))
    return Normal(U, gc, terms)


def _damped(blocks: np.ndarray, lam: float) -> np.ndarray:
    """blocks + lam * diag(blocks), Marquardt's scaling, with the diagonal floored."""
    diag = np.maximum(np.einsum("...ii->...i", blocks), MIN_DIAGONAL)
    out = blocks.copy()
    idx = np.arange(blocks.shape[-1])
    out[..., idx, idx] += lam * diag
    return out


TRIANGULAR_BLOCK = 96  # widths up to which a triangular factor is inverted by NumPy's inverse
# whole; wider, by halves (:func:`_lower_inverse`), whose products are BLAS's


class ReducedInverse:
    """The inverse of the reduced camera system S (n, n), kept as what made it: either the
    inverse itself (``full``) or the inverse of S's Cholesky factor, ``factor`` = L^-1 (lower
    triangular), S^-1 = L^-T L^-1. A step needs S^-1 b and diag(S^-1), each O(n^2) from the
    factor; the whole inverse (one symmetric product, n^3 flops) is formed only when asked for,
    by the pose covariance."""

    def __init__(self, *, full: np.ndarray | None = None, factor: np.ndarray | None = None):
        self._full, self._factor = full, factor

    def diagonal(self) -> np.ndarray:
        """diag(S^-1) (n,): the squared columns of L^-1 summed."""
        if self._factor is None:
            return np.diag(self.full()).copy()
        return np.einsum("ij,ij->j", self._factor, self._factor)

    def times(self, b: np.ndarray) -> np.ndarray:
        """S^-1 b for b (n,)."""
        if self._factor is None:
            return self.full() @ b
        return self._factor.T @ (self._factor @ b)

    def full(self) -> np.ndarray:
        """S^-1 (n, n), symmetric; formed once."""
        if self._full is None:
            assert self._factor is not None
            self._full = self._factor.T @ self._factor  # NumPy's matmul of a matrix by its own transpose: BLAS's syrk
        return self._full


@dataclass(eq=False)
class Step:
    """A solved step: dc (N, c) for the cameras, dp per term (P, p), and, for standard errors,
    the diagonal of the reduced camera system's inverse (N, c) and of each V^-1 (P, p); the
    reduced system's inverse (:class:`ReducedInverse`; ``cam_cov`` its whole (N c, N c)) and the
    V^-1 blocks are kept for the pose covariance (and for :func:`solve_again`)."""

    dc: np.ndarray
    dp: list[np.ndarray]
    cam_var: np.ndarray
    pt_var: list[np.ndarray]
    inverse: ReducedInverse
    pt_inv: list[np.ndarray]
    lam: float = 0.0  # the damping it was solved at

    @property
    def cam_cov(self) -> np.ndarray:
        """The reduced camera system's inverse (N c, N c)."""
        return self.inverse.full()


def solve(normal: Normal, lam: float) -> Step | None:
    """Solve the damped system (U + lam D) for the step; None when it is not positive definite.

    With V = L L^T per block and Z = W L^-T per camera-block pair, the reduction W V^-1 W^T is
    the Gram matrix Z Z^T: one dense symmetric product per chunk of blocks, Z formed per chunk."""
    n, c = normal.gc.shape
    S = np.zeros((n * c, n * c))
    for k, block in enumerate(_damped(normal.U, lam)):
        S[k * c : (k + 1) * c, k * c : (k + 1) * c] = block
    b = normal.gc.copy()
    solved = []
    for t in normal.terms:
        s = t.structure
        try:
            L = np.linalg.cholesky(_damped(t.V, lam))
        except np.linalg.LinAlgError:
            return None
        LinvT = np.swapaxes(np.linalg.inv(L), 1, 2)  # L^-T, upper triangular, (P, p, p)
        Vinv = LinvT @ np.swapaxes(LinvT, 1, 2)
        y = np.einsum("pij,pj->pi", Vinv, t.gp)
        b -= _summed(s.pair_to_cam, np.einsum("kij,kj->ki", t.W, y[s.pair_pt]), n)
        _subtract_gram(S, t.W, LinvT, s)
        solved.append(Vinv)
    S_inv = _spd_inverse(S)  # its diagonal gives the standard errors
    if S_inv is None:
        return None
    dc = -S_inv.times(b.ravel()).reshape(n, c)
    return Step(dc, _back_substituted(normal, solved, dc), S_inv.diagonal().reshape(n, c),
                [np.einsum("pii->pi", Vinv) for Vinv in solved], S_inv, solved, lam)


def _spd_inverse(S: np.ndarray) -> ReducedInverse | None:
    """The inverse of the symmetric (n, n) ``S``; None when it is not positive definite (no step at
    this damping). Up to :data:`LAPACK_INVERSE_WIDTH` from NumPy's Cholesky factor L (also the
    test) and its triangular inverse (:func:`_lower_inverse`): 1/3 + 2/3 n^3 flops, not the LU
    inverse's 8/3 after the test (CPU s a solve, one BLAS thread, 768 wide: 0.024 against 0.068),
    and scipy.linalg's start-up spared; wider, LAPACK's potrf and potri, the whole inverse."""
    if len(S) < LAPACK_INVERSE_WIDTH:
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return None
        return ReducedInverse(factor=_lower_inverse(L))
    from scipy.linalg.lapack import dpotrf, dpotri

    factor, info = dpotrf(S, lower=False, clean=False)
    if info != 0:
        return None
    upper, info = dpotri(factor, lower=False)
    if info != 0:
        return None
    return ReducedInverse(full=np.triu(upper) + np.triu(upper, 1).T)


def _lower_inverse(L: np.ndarray) -> np.ndarray:
    """The inverse of the lower-triangular (n, n) ``L`` (nonzero diagonal), lower triangular: by
    halves, [[A, 0], [B, C]]^-1 = [[A^-1, 0], [-C^-1 B A^-1, C^-1]], down to
    :data:`TRIANGULAR_BLOCK` wide blocks inverted whole (2/3 n^3 flops in matrix products)."""
    n = len(L)
    if n <= TRIANGULAR_BLOCK:
        return np.linalg.inv(L)
    h = n // 2
    A_inv, C_inv = _lower_inverse(L[:h, :h]), _lower_inverse(L[h:, h:])
    out = np.zeros_like(L)
    out[:h, :h], out[h:, h:] = A_inv, C_inv
    out[h:, :h] = -(C_inv @ (L[h:, :h] @ A_inv))
    return out


def solve_again(normal: Normal, factored: Step) -> Step:
    """The step of ``normal``, whose matrix blocks are those ``factored`` solved (only its gradient
    differs: :func:`normal_equations` ``like``), from that solve's inverses: no Gram and no
    factorisation, a few products over the pairs."""
    n, c = normal.gc.shape
    b = normal.gc.copy()
    for t, Vinv in zip(normal.terms, factored.pt_inv):
        s = t.structure
        b -= _summed(s.pair_to_cam, np.einsum("kij,kj->ki", t.W, np.einsum("pij,pj->pi", Vinv, t.gp)[s.pair_pt]), n)
    dc = -factored.inverse.times(b.ravel()).reshape(n, c)
    return replace(factored, dc=dc, dp=_back_substituted(normal, factored.pt_inv, dc))


def _back_substituted(normal: Normal, Vinvs: list[np.ndarray], dc: np.ndarray) -> list[np.ndarray]:
    """Each term's block steps (P, p) given the cameras' dc (N, c): V^-1 (-gp - W^T dc)."""
    dp = []
    for t, Vinv in zip(normal.terms, Vinvs):
        s = t.structure
        rhs = -t.gp - _summed(s.pair_to_pt, np.einsum("kji,kj->ki", t.W, dc[s.pair_cam]), s.n_pts)
        dp.append(np.einsum("pij,pj->pi", Vinv, rhs))
    return dp


def predicted_gain(normal: Normal, step: Step) -> float:
    """Decrease of the weighted least squares model, -(g . dx) - |J dx|^2 / 2, with |J dx|^2 =
    dx^T (J^T J) dx taken from the normal equations' blocks (no pass over the observations)."""
    dc = step.dc
    gain = -float(np.sum(normal.gc * dc)) - 0.5 * float(np.einsum("ni,nij,nj->", dc, normal.U, dc))
    for t, dp in zip(normal.terms, step.dp):
        s = t.structure
        gain -= float(np.sum(t.gp * dp)) + 0.5 * float(np.einsum("pi,pij,pj->", dp, t.V, dp))
        gain -= float(np.einsum("ki,kij,kj->", dc[s.pair_cam], t.W, dp[s.pair_pt]))
    return gain


def _subtract_gram(S: np.ndarray, W: np.ndarray, LinvT: np.ndarray, s: TermStructure) -> None:
    """S -= sum over blocks of Z_a Z_b^T, Z = W L^-T, for every two cameras a, b that saw the block.

    The pairs (sorted by block) are laid out as a dense (cameras * c) x (blocks * p) matrix, a
    chunk of blocks at a time, so the sum is one symmetric matrix product per chunk; Z is formed
    a chunk at a time too. When few cameras see each block (:data:`SPARSE_GRAM_FILL`), the
    products of each block's own camera pairs instead (:func:`_subtract_gram_sparse`)."""
    n, c, p = s.n_cams, W.shape[1], W.shape[2]
    if n == 0 or len(W) == 0:
        return
    per_block = np.bincount(s.pair_pt, minlength=s.n_pts)
    if np.sum(per_block.astype(float) ** 2) < SPARSE_GRAM_FILL * n * n * s.n_pts:
        _subtract_gram_sparse(S, W, LinvT, s, per_block)
        return
    chunk = max(1, CHUNK_ENTRIES // (n * c * p))
    bounds = np.searchsorted(s.pair_pt, np.arange(0, s.n_pts + chunk, chunk))
    for k in range(len(bounds) - 1):
        a, b = bounds[k], bounds[k + 1]
        if a == b:
            continue
        first = k * chunk
        Zd = np.zeros((n, c, min(chunk, s.n_pts - first), p))
        Zd[s.pair_cam[a:b], :, s.pair_pt[a:b] - first] = W[a:b] @ LinvT[s.pair_pt[a:b]]
        Zm = Zd.reshape(n * c, -1)
        S -= Zm @ Zm.T


def _subtract_gram_sparse(S: np.ndarray, W: np.ndarray, LinvT: np.ndarray, s: TermStructure, per_block: np.ndarray) -> None:
    """:func:`_subtract_gram` block by block: for every two pairs (i, j) of the same block (its
    cameras a, b), Z_i Z_j^T (c x c) summed into S's (a, b) block. The work is the sum over blocks
    of their cameras squared, not cameras^2 x blocks: 2-4 cameras a frame in a 256-camera rig
    (calib/sim/shapes.py) leave the dense product 99.9% zeros. A chunk of pairs at a time."""
    n, c = s.n_cams, W.shape[1]
    starts = np.r_[0, np.cumsum(per_block)[:-1]]
    flat = S.reshape(-1)
    within = np.arange(c)[:, None] * (n * c) + np.arange(c)[None, :]  # a c x c block's offsets in S
    per_pair = per_block[s.pair_pt]  # (K,) the pairs j each pair i is multiplied with
    total = np.cumsum(per_pair)
    edges = np.unique(np.r_[0, np.searchsorted(total, np.arange(SPARSE_GRAM_PRODUCTS, total[-1], SPARSE_GRAM_PRODUCTS),
                                                side="right"), len(per_pair)])
    Z = W @ LinvT[s.pair_pt]  # (K, c, p)
    ZT = np.ascontiguousarray(np.swapaxes(Z, 1, 2))  # (K, p, c): each Z_j^T gathered whole
    for lo, hi in zip(edges[:-1], edges[1:]):
        i = np.repeat(np.arange(lo, hi), per_pair[lo:hi])
        # j runs over the block's pairs: its first pair plus 0, 1, ..., count - 1
        j = starts[s.pair_pt[i]] + np.arange(len(i)) - np.repeat(np.cumsum(per_pair[lo:hi]) - per_pair[lo:hi], per_pair[lo:hi])
        # batched matmul, not einsum's loop over the tiny (c, p) x (p, c) products: a third of the
        # time at hallway:128x3000 (25,662 products, 4 against 13 ms), equal to 2e-16 relative
        G = Z[i] @ ZT[j]
        at = (s.pair_cam[i] * c * n * c + s.pair_cam[j] * c)[:, None, None] + within
        flat -= np.bincount(at.ravel(), G.ravel(), minlength=flat.size)
