"""Intervals over repetitions and paired tests between methods (the protocol of docs/design.md).

Every function here works on *repetition-level* values (one metric value per
repetition, typically R = 30). The caller removes failed repetitions first; a
non-finite value reaching this module is a bug upstream and is refused loudly
rather than silently ignored.

Identical repetitions (every value equal: the same training rows each time and a
deterministic method) are copies, not evidence: they carry no interval (nan bounds) and
a paired difference that never varies carries no test. Means and spreads are formed on
values divided by a power of two near their largest magnitude, so values near 1e308
neither overflow nor warn; a bound beyond the double range is nan.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from enginebench.errors import DataError
from enginebench.results.student_t import t_cdf, t_quantile

__all__ = [
    "bootstrap_interval",
    "describe",
    "holm",
    "identical",
    "paired_pvalues",
    "paired_ttest",
    "t_interval",
    "wilcoxon",
]


def _finite_1d(values: object, name: str) -> np.ndarray:
    """Return `values` as a non-empty finite 1-D float array, or raise DataError naming `name`."""
    arr = np.asarray(values, dtype=float)
    if arr.ndim != 1:
        raise DataError(
            f"{name} must be a 1-D sequence of numbers, got an array of shape {arr.shape}; "
            "pass one value per repetition"
        )
    if arr.size == 0:
        raise DataError(f"{name} is empty: at least one repetition value is needed")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        raise DataError(
            f"{name} has {bad.size} non-finite value(s) (first at index {bad[0]}: {arr[bad[0]]}); "
            "remove failed repetitions before computing statistics"
        )
    return arr


def _check_level(level: float) -> float:
    """Validate a confidence level in the open interval (0, 1)."""
    level = float(level)
    if not (0.0 < level < 1.0):
        raise DataError(f"confidence level must lie strictly between 0 and 1, got level={level}")
    return level


def _pow2(x: np.ndarray) -> float:
    """A power of two near max|x| (1.0 for zeros): dividing by it is exact."""
    m = float(np.max(np.abs(x)))
    return math.ldexp(1.0, math.frexp(m)[1] - 1) if m > 0.0 else 1.0


def _mean_sd(x: np.ndarray) -> tuple[float, float]:
    """(mean, SD with ddof=1) computed on x / 2^k: no overflow; SD is nan for one value, inf beyond the range."""
    s = _pow2(x)
    y = x / s
    with np.errstate(over="ignore"):
        return float(y.mean()) * s, (float(y.std(ddof=1)) * s if x.size > 1 else float("nan"))


def _bounds(mean: float, half: float) -> tuple[float, float]:
    """(mean - half, mean + half), both nan when either leaves the double range."""
    with np.errstate(over="ignore", invalid="ignore"):
        low, high = mean - half, mean + half
    if not (math.isfinite(low) and math.isfinite(high)):
        return float("nan"), float("nan")
    return low, high


def identical(values: object) -> bool:
    """True when there are at least two values and all are equal: copies, no spread to speak of."""
    x = np.asarray(values, dtype=float)
    return bool(x.size > 1 and np.all(x == x.flat[0]))


def t_interval(values: object, level: float = 0.95) -> tuple[float, float, float]:
    """Student-t interval of the mean over R repetitions: mean +- t_{(1+level)/2, R-1} s / sqrt(R).

    `s` is the sample standard deviation (ddof=1). With a single repetition, or R
    identical values (copies), no interval exists and `(mean, nan, nan)` is returned.
    """
    x = _finite_1d(values, "values")
    level = _check_level(level)
    mean, sd = _mean_sd(x)
    r = x.size
    if r == 1 or identical(x):
        return mean, float("nan"), float("nan")
    with np.errstate(over="ignore"):
        # the Student-t quantile (scipy.stats.t.ppf's, to 1e-10 relative: tests/results/test_student_t.py) in plain
        # Python, so printing a stored table imports no scipy at all (scipy.special alone costs a quarter second)
        half = t_quantile(0.5 * (1.0 + level), r - 1) * sd / np.sqrt(r)
    return (mean, *_bounds(mean, half))


def bootstrap_interval(
    values: object,
    rng: np.random.Generator,
    level: float = 0.95,
    n_resamples: int = 10_000,
) -> tuple[float, float, float]:
    """Percentile bootstrap interval of the mean: `(mean, low, high)`.

    All resamples come from one `(n_resamples, R)` integer draw of `rng`, so the
    result is a deterministic function of the generator state. With a single
    repetition, or identical values, every resample is identical and `(mean, nan,
    nan)` is returned (no draw is made), matching `t_interval`. The interval of
    values within a metric's bounds lies within them.
    """
    x = _finite_1d(values, "values")
    level = _check_level(level)
    if not isinstance(rng, np.random.Generator):
        raise DataError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__}; "
            "create one with numpy.random.default_rng(seed)"
        )
    if int(n_resamples) != n_resamples or n_resamples < 1:
        raise DataError(f"n_resamples must be a positive integer, got n_resamples={n_resamples}")
    mean, _ = _mean_sd(x)
    if x.size == 1 or identical(x):
        return mean, float("nan"), float("nan")
    s = _pow2(x)
    idx = rng.integers(0, x.size, size=(int(n_resamples), x.size))
    means = (x / s)[idx].mean(axis=1)
    alpha = 1.0 - level
    low, high = np.percentile(means, [50.0 * alpha, 100.0 * (1.0 - 0.5 * alpha)]) * s
    return mean, float(low), float(high)


def describe(values: object) -> dict[str, float]:
    """Mean, SD (ddof=1), median, IQR (q75 - q25, linear percentiles) and n of finite values.

    The SD of a single value is undefined and reported as nan; an SD or IQR beyond the
    double range (values spanning -1e308 to 1e308) is nan too, never inf.
    """
    x = _finite_1d(values, "values")
    mean, sd = _mean_sd(x)
    s = _pow2(x)
    q25, q50, q75 = np.percentile(x / s, [25.0, 50.0, 75.0])
    with np.errstate(over="ignore"):
        iqr = float(q75 - q25) * s
    finite = lambda v: v if math.isfinite(v) else float("nan")  # noqa: E731
    return {
        "mean": mean,
        "sd": finite(sd),
        "median": float(q50) * s,
        "iqr": finite(iqr),
        "n": int(x.size),
    }


def _paired(a: object, b: object) -> tuple[np.ndarray, np.ndarray]:
    """Validate two paired samples: finite, 1-D, equal length, at least two pairs."""
    x = _finite_1d(a, "a")
    y = _finite_1d(b, "b")
    if x.size != y.size:
        raise DataError(
            f"paired test needs one value per repetition on both sides: a has {x.size} values, "
            f"b has {y.size}; compare the two methods on the same repetitions"
        )
    if x.size < 2:
        raise DataError("paired test needs at least 2 paired repetitions, got 1")
    return x, y


def paired_ttest(a: object, b: object) -> tuple[float, float]:
    """Two-sided paired t-test of mean(a - b) == 0 (scipy.stats.ttest_rel): `(statistic, pvalue)`.

    Identical samples (all differences zero) give `(nan, 1.0)`: no evidence of a
    difference. A constant non-zero difference (copies of one repetition on each side)
    has no variance to test against: `(nan, nan)`, never p = 0.
    """
    x, y = _paired(a, b)
    with np.errstate(over="ignore", invalid="ignore"):
        d = x - y
    if np.all(d == d[0]):
        return (float("nan"), 1.0) if d[0] == 0.0 else (float("nan"), float("nan"))
    s = max(_pow2(x), _pow2(y))  # the t statistic is scale-free: test the scaled values
    d = x / s - y / s
    n = d.size
    t = float(d.mean() / (d.std(ddof=1) / np.sqrt(n)))
    # the t distribution's two tails (what scipy.stats.ttest_rel reports) from results.student_t: printing a stored
    # table with its paired tests imports no scipy
    return t, 2.0 * t_cdf(-abs(t), n - 1)


def holm(pvalues: object) -> np.ndarray:
    """Holm's step-down adjustment of a family of p-values (nan entries are not tests and stay nan).

    The k-th smallest of m p-values becomes max over j <= k of min(1, (m - j + 1) p_(j)): it
    controls the family-wise error rate at the nominal level, for any dependence.
    """
    p = np.asarray(pvalues, dtype=float).ravel()
    out = np.full(p.shape, np.nan)
    tested = np.flatnonzero(~np.isnan(p))
    if tested.size == 0:
        return out
    order = tested[np.argsort(p[tested], kind="stable")]
    m = order.size
    adjusted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out[order] = adjusted
    return out


def wilcoxon(a: object, b: object) -> tuple[float, float]:
    """Two-sided Wilcoxon signed-rank test on paired repetitions: `(statistic, pvalue)`.

    `scipy.stats.wilcoxon`'s answer (zero differences dropped, exact or normal
    approximation chosen as scipy chooses): computed here for the exact distribution and the
    normal approximation, so printing a table imports no scipy; scipy.stats itself only for 13
    or fewer pairs with ties or zeros (its permutation test). All differences zero gives
    `(nan, 1.0)` instead of scipy's warnings.
    """
    x, y = _paired(a, b)
    if np.all(x == y):
        return float("nan"), 1.0
    s = max(_pow2(x), _pow2(y))  # ranks of the differences are scale-free: no overflow in x - y
    x, y = x / s, y / s
    exact = _wilcoxon_exact(x - y)
    if exact is not None:
        return exact
    normal = _wilcoxon_normal(x - y)
    if normal is not None:
        return normal
    with warnings.catch_warnings():
        # scipy warns when it falls back from the exact distribution (ties/zeros);
        # the fallback is the documented behaviour, not something the user can act on.
        warnings.simplefilter("ignore", category=UserWarning)
        import scipy.stats

        res = scipy.stats.wilcoxon(x, y)
    return float(res.statistic), float(res.pvalue)


def _wilcoxon_exact(d: np.ndarray) -> tuple[float, float] | None:
    """The signed-rank test's exact two-sided p-value where scipy.stats.wilcoxon uses its exact null distribution
    (at most 50 differences, none zero, no tied magnitudes): ``(min(W+, W-), p)``; None elsewhere (scipy decides).

    Under the null each rank's sign is a fair coin, so W+ is distributed as the sum of a random subset of
    1..n: its counts come from one pass per rank over the 2^n subsets' sums."""
    n = d.size
    a = np.abs(d)
    if n > 50 or np.any(a == 0) or np.unique(a).size < n:
        return None
    ranks = np.empty(n)
    ranks[np.argsort(a, kind="stable")] = np.arange(1, n + 1)
    w_plus = float(ranks[d > 0].sum())
    top = n * (n + 1) // 2
    counts = np.zeros(top + 1)
    counts[0] = 1.0
    for k in range(1, n + 1):  # subsets of 1..k: those without k, plus those with it (shifted by k)
        counts[k:] = counts[k:] + counts[:-k].copy()
    cdf = np.cumsum(counts) / 2.0 ** n
    w = int(round(min(w_plus, top - w_plus)))
    return float(min(w_plus, top - w_plus)), float(min(1.0, 2.0 * cdf[w]))


def _wilcoxon_normal(d: np.ndarray) -> tuple[float, float] | None:
    """The signed-rank test's normal approximation where scipy.stats.wilcoxon (method 'auto') takes it: more than
    50 differences, or more than 13 with tied magnitudes or zeros: ``(min(W+, W-), p)``; None elsewhere (13 or
    fewer with ties or zeros: scipy's permutation test decides).

    Zero differences are dropped (Wilcoxon's convention); tied magnitudes share their average rank, and the
    variance n (n + 1)(2 n + 1) / 24 loses sum(t^3 - t) / 48 over the groups of t ties; no continuity correction;
    p = 2 P(Z > |W+ - n (n + 1) / 4| / sd) = erfc(|z| / sqrt 2)."""
    if d.size <= 13:
        return None
    nz = d[d != 0.0]
    n = nz.size
    if n == 0:
        return None
    a = np.abs(nz)
    order = np.argsort(a, kind="stable")
    sorted_a = a[order]
    starts = np.flatnonzero(np.r_[True, sorted_a[1:] != sorted_a[:-1]])
    sizes = np.diff(np.r_[starts, n])
    ranks = np.empty(n)
    ranks[order] = np.repeat(starts + (sizes + 1) / 2.0, sizes)  # the average of ranks start+1 .. start+size
    w_plus = float(ranks[nz > 0].sum())
    w_minus = float(ranks[nz < 0].sum())
    ties = float(np.sum(sizes.astype(float) ** 3 - sizes))
    sd = math.sqrt((n * (n + 1.0) * (2.0 * n + 1.0) - ties / 2.0) / 24.0)
    z = (w_plus - n * (n + 1.0) / 4.0) / sd
    return min(w_plus, w_minus), float(math.erfc(abs(z) / math.sqrt(2.0)))


def paired_pvalues(a: object, b: object) -> tuple[float, float, str]:
    """(paired t p, Wilcoxon p, note) for paired repetitions; where no test exists both are nan and the note says why.

    No test: fewer than 2 pairs; a difference that is the same non-zero number on every
    repetition (identical repetitions on both sides are the usual cause: copies). All
    differences zero keep p = 1: the two sides agree exactly, there is nothing to detect.
    """
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    nan = float("nan")
    if x.size < 2:
        return nan, nan, f"only {x.size} paired repetition(s); a paired test needs at least 2"
    with np.errstate(over="ignore", invalid="ignore"):
        d = x - y
    if d[0] != 0.0 and np.all(d == d[0]):
        if identical(x) and identical(y):
            return nan, nan, "identical repetitions (each side gave the same value every time): no test"
        return nan, nan, "the difference is the same on every repetition: no test"
    return paired_ttest(x, y)[1], wilcoxon(x, y)[1], ""
