"""Small statistics helpers for the verification harness (numpy only).

Student's t distribution (CDF via the regularised incomplete beta function)
so that tests with few independent runs use honest quantiles instead of
normal ones.
"""
import math

import numpy as np


def _betacf(a, b, x, iterations=300):
    """Continued fraction of the incomplete beta function (Lentz), vectorised in x."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = np.ones_like(x)
    d = 1.0 - qab * x / qap
    d = np.where(np.abs(d) < tiny, tiny, d)
    d = 1.0 / d
    h = d.copy()
    for m in range(1, iterations + 1):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = np.where(np.abs(d) < tiny, tiny, d)
        c = 1.0 + aa / c
        c = np.where(np.abs(c) < tiny, tiny, c)
        d = 1.0 / d
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = np.where(np.abs(d) < tiny, tiny, d)
        c = 1.0 + aa / c
        c = np.where(np.abs(c) < tiny, tiny, c)
        d = 1.0 / d
        delta = d * c
        h *= delta
        if np.all(np.abs(delta - 1.0) < 1e-14):
            break
    return h


def betainc(a, b, x):
    """Regularised incomplete beta function I_x(a, b) for arrays x in [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    lbeta = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b)
    with np.errstate(divide="ignore"):
        front = np.exp(lbeta + a * np.log(np.where(x > 0, x, 1.0)) + b * np.log(np.where(x < 1, 1.0 - x, 1.0)))
    direct = x < (a + 1.0) / (a + b + 2.0)
    xs = np.where(direct, x, 1.0 - x)
    cf = np.where(direct, _betacf(a, b, xs), _betacf(b, a, xs))
    result = np.where(direct, front * cf / a, 1.0 - front * cf / b)
    return np.where(x <= 0, 0.0, np.where(x >= 1, 1.0, result))


def t_two_sided_p(t, df):
    """Two-sided p-value P(|T| >= |t|) of Student's t with ``df`` degrees of freedom."""
    t = np.abs(np.asarray(t, dtype=np.float64))
    return betainc(df / 2.0, 0.5, df / (df + t * t))


def normal_two_sided_p(z):
    return math.erfc(abs(z) / math.sqrt(2.0))


def t_quantile_for_z(z, df):
    """The |t| bound with the same two-sided tail probability as a |z| bound."""
    if not np.isfinite(df) or df > 1e6:
        return float(z)
    p = normal_two_sided_p(z)
    lo, hi = 0.0, 1.0
    while t_two_sided_p(hi, df) > p:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_two_sided_p(mid, df) > p:
            lo = mid
        else:
            hi = mid
    return hi


def sidak_alpha(alpha, n):
    """Per-test significance so that n independent tests keep family-wise level alpha."""
    return 1.0 - (1.0 - alpha) ** (1.0 / max(int(n), 1))
