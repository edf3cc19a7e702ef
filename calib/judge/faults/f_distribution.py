"""The F distribution's upper tail, for the judgement's F and Hotelling tests (the pose step's,
its screen's, the lens pattern's against its own scatter), and the binomial's (outlier shares, rejected
views), without loading SciPy into calibrate."""

from __future__ import annotations

import math

import numpy as np


def f_survival(q: int, dof: float, f: float) -> float:
    """P(F(q, dof) > f): the regularised incomplete beta I_x(dof/2, q/2), x = dof / (dof + q f), by
    its continued fraction (Numerical Recipes' betacf); scipy is not loaded by calibrate."""
    if f <= 0:
        return 1.0
    a, b, x = dof / 2, q / 2, dof / (dof + q * f)
    if x <= 0:
        return 0.0
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x))
    if x > (a + 1) / (a + b + 2):  # the fraction converges fast on this side only: I_x(a, b) = 1 - I_{1-x}(b, a)
        return 1.0 - front * _betacf(b, a, 1 - x) / b
    return front * _betacf(a, b, x) / a


def _betacf(a: float, b: float, x: float) -> float:
    tiny = 1e-300
    c, d = 1.0, 1 - (a + b) * x / (a + 1)
    d = 1 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 300):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)), -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1 + num * d
            d = 1 / (d if abs(d) > tiny else tiny)
            c = 1 + num / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1) < 1e-14:
            break
    return h


def binomial_tail(k: int, n: int, p: float) -> float:
    """P(X >= k), X ~ Binomial(n, p), summed in logs (a calibration loads no scipy)."""
    if k <= 0:
        return 1.0
    if k > n or p <= 0.0:
        return 0.0
    if p >= 1.0:
        return 1.0
    i = np.arange(k + 1, n + 1, dtype=float)
    head = math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1) + k * math.log(p) + (n - k) * math.log1p(-p)
    logs = head + np.concatenate([[0.0], np.cumsum(np.log((n - i + 1) / i) + math.log(p) - math.log1p(-p))])
    top = float(logs.max())
    return min(1.0, math.exp(top) * float(np.exp(logs - top).sum()))


def critical_f(q: int, dof: float, alpha: float) -> float:
    """The F(q, dof) value whose upper tail is ``alpha``: bisection of :func:`f_survival` on log F
    (it falls monotonically in F); 1e9 where even that is not rare enough."""
    lo, hi = 0.0, 1e9
    if f_survival(q, dof, hi) > alpha:
        return hi
    for _ in range(200):
        mid = np.sqrt(max(lo, 1e-12) * hi)
        if f_survival(q, dof, mid) > alpha:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9 * hi:
            break
    return hi


def binomial_upper(k: int, n: int, alpha: float = 0.025) -> float:
    """The Clopper-Pearson upper bound of a rate seen k times in n: the q at which k or fewer
    happen with probability ``alpha`` (1 with n = 0). The root of P(Bin(n, q) <= k) = alpha by
    Newton's method on the exact sum, whose derivative in q is -(n - k) C(n, k) q^k (1 - q)^(n - k - 1),
    from Wilson's upper bound, each step kept inside the bracket the sum's signs leave (a bisection
    step where it would leave it): the 60-step bisection's root within 1e-13 relative in 4-8 sums
    (decision 0090)."""
    if n == 0 or k >= n:
        return 1.0
    j = np.arange(k + 1)
    log_comb = np.concatenate([[0.0], np.cumsum(np.log((n - j[1:] + 1) / j[1:]))])  # log C(n, j), j <= k
    log_slope = math.log(n - k) + float(log_comb[-1])  # log (n - k) C(n, k)
    lo, hi = k / n, 1.0
    q = _wilson_upper(k, n)
    q = q if lo < q < hi else (lo + hi) / 2
    for _ in range(100):
        lq, l1q = math.log(q), math.log1p(-q)
        f = float(np.exp(log_comb + j * lq + (n - j) * l1q).sum()) - alpha  # P(Bin(n, q) <= k) - alpha
        lo, hi = (q, hi) if f > 0 else (lo, q)
        slope = math.exp(log_slope + k * lq + (n - k - 1) * l1q)  # -f'(q), 0 where it underflows
        nxt = q + f / slope if slope > 0 and lo < q + f / slope < hi else (lo + hi) / 2
        if abs(nxt - q) <= 1e-15 * q or hi - lo <= 1e-15 * hi:
            return nxt
        q = nxt
    return q


def _wilson_upper(k: int, n: int, z: float = 1.959963984540054) -> float:
    """Wilson's score bound of a rate seen k times in n (the normal approximation's, two-sided 95%):
    the start of :func:`binomial_upper`'s Newton steps."""
    p = k / n
    return (p + z * z / (2 * n) + z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))) / (1 + z * z / n)
