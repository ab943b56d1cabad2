"""The Student-t distribution's tail and quantile in plain Python (``math`` only).

Printing a stored run's table needs two numbers from the t distribution: the quantile of a t interval
over repetitions and the two-sided p-value of a paired t-test. ``scipy.special`` (``stdtrit``, ``stdtr``)
gives both but costs a quarter of a second to import on every ``enginebench table``; these two
functions give the same numbers (to 1e-10 relative or better: tests/results/test_student_t.py checks them
against scipy over degrees of freedom 1-1000 and p-values down to 1e-300) without it.

The tail is P(T > t) = I_x(df/2, 1/2) / 2 with x = df / (df + t^2), the regularised incomplete beta
function evaluated by its continued fraction (modified Lentz), on the side of the symmetry
I_x(a, b) = 1 - I_{1-x}(b, a) where the fraction converges fast; x and 1 - x are formed separately so that
neither tail loses digits to cancellation. The quantile solves tail(t) = q by Newton's method on
log tail(t), kept inside a bracket by bisection.
"""

from __future__ import annotations

import functools
import math

__all__ = ["t_cdf", "t_quantile", "t_tail"]

_TINY = 1e-300
_EPS = 1e-16


def _beta_fraction(a: float, b: float, x: float) -> float:
    """The continued fraction of I_x(a, b) (without its front factor), by the modified Lentz method."""
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, 10_000):
        # even step: m (b - m) x / ((a + 2m - 1)(a + 2m))
        num = m * (b - m) * x / ((a + 2 * m - 1.0) * (a + 2 * m))
        d = 1.0 + num * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + num / c
        c = c if abs(c) > _TINY else _TINY
        h *= d * c
        # odd step: -(a + m)(a + b + m) x / ((a + 2m)(a + 2m + 1))
        num = -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1.0))
        d = 1.0 + num * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + num / c
        c = c if abs(c) > _TINY else _TINY
        step = d * c
        h *= step
        if abs(step - 1.0) < _EPS:
            return h
    return h  # pragma: no cover - the fraction converges in far fewer steps for the t distribution's a, b


def _log_gamma_half_step(a: float) -> float:
    """log Gamma(a + 1/2) - log Gamma(a): for large ``a`` from its asymptotic series (the difference of two
    lgamma values near a log a would keep only some 1e-16 a log a of absolute accuracy)."""
    if a < 25.0:
        return math.lgamma(a + 0.5) - math.lgamma(a)
    r = 1.0 / a
    r2 = r * r
    return 0.5 * math.log(a) - r / 8.0 + r * r2 * (1.0 / 192.0 - r2 * (1.0 / 640.0 - r2 * 17.0 / 14336.0))


def _half_tail(t2: float, df: float) -> float:
    """P(T > |t|) = I_x(df/2, 1/2) / 2 with x = df / (df + t^2), from t^2; x, 1 - x and log x are formed
    without cancellation."""
    a, b = 0.5 * df, 0.5
    x, y = df / (df + t2), t2 / (df + t2)
    if y <= 0.0:
        return 0.5
    if x <= 0.0:
        return 0.0
    log_x = -math.log1p(t2 / df)
    log_beta = math.lgamma(0.5) - _log_gamma_half_step(a)  # log B(a, 1/2)
    front = math.exp(a * log_x + b * math.log(y) - log_beta)
    if x < (a + 1.0) / (a + b + 2.0):
        return 0.5 * front * _beta_fraction(a, b, x) / a
    return 0.5 * (1.0 - front * _beta_fraction(b, a, y) / b)


def t_tail(t: float, df: float) -> float:
    """P(T > t) for Student's t with ``df`` degrees of freedom (``scipy.special.stdtr(df, -t)``)."""
    t, df = float(t), float(df)
    if math.isnan(t) or math.isnan(df) or df <= 0.0:
        return math.nan
    if math.isinf(t):
        return 0.0 if t > 0 else 1.0
    upper = _half_tail(t * t, df)  # P(T > |t|)
    return upper if t >= 0.0 else 1.0 - upper


def t_cdf(t: float, df: float) -> float:
    """P(T <= t) for Student's t with ``df`` degrees of freedom (``scipy.special.stdtr(df, t)``); the lower
    tail is computed as itself (``t_tail(-t)``), never as 1 minus a number near 1."""
    return t_tail(-float(t), df)


def _log_density(t: float, df: float) -> float:
    return (_log_gamma_half_step(0.5 * df) - 0.5 * math.log(df * math.pi)
            - 0.5 * (df + 1.0) * math.log1p(t * t / df))


def _upper_quantile(q: float, df: float) -> float:
    """The t > 0 with P(T > t) = q (0 < q < 1/2)."""
    if df == 1.0:  # Cauchy: closed form, tan(pi (1/2 - q)) written so that a small q keeps its digits
        return 1.0 / math.tan(math.pi * q)
    if df == 2.0:  # closed form: t = (1 - 2q) / sqrt(2 q (1 - q))
        return (1.0 - 2.0 * q) / math.sqrt(2.0 * q * (1.0 - q))
    lo, hi = 0.0, 1.0
    while t_tail(hi, df) > q:  # bracket: tail(lo) > q >= tail(hi)
        lo, hi = hi, hi * 4.0
        if hi > 1e300:
            return math.inf
    t = 0.5 * (lo + hi)
    log_q = math.log(q)
    for _ in range(200):
        tail = t_tail(t, df)
        if tail > q:
            lo = t
        else:
            hi = t
        # Newton on log tail(t) - log q: d/dt log tail = -density / tail
        step = (math.log(tail) - log_q) * tail / math.exp(_log_density(t, df)) if tail > 0.0 else math.nan
        new = t + step
        if not (lo < new < hi) or not math.isfinite(new):
            new = 0.5 * (lo + hi)
        if abs(new - t) <= 4e-16 * abs(new) or hi - lo <= 4e-16 * hi:
            return new
        t = new
    return t  # pragma: no cover - Newton converges in a handful of steps


@functools.lru_cache(maxsize=1024)
def t_quantile(p: float, df: float) -> float:
    """The ``p`` quantile of Student's t with ``df`` degrees of freedom (``scipy.stats.t.ppf(p, df)``,
    ``scipy.special.stdtrit(df, p)``)."""
    p, df = float(p), float(df)
    if math.isnan(p) or math.isnan(df) or df <= 0.0 or not 0.0 <= p <= 1.0:
        return math.nan
    if p == 0.5:
        return 0.0
    if p == 0.0 or p == 1.0:
        return -math.inf if p == 0.0 else math.inf
    return _upper_quantile(1.0 - p, df) if p > 0.5 else -_upper_quantile(p, df)
