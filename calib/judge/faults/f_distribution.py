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
