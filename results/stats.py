"""Intervals over repetitions and paired tests between methods (seed protocol, DESIGN sec. 6).

Every function here works on *repetition-level* values (one metric value per
repetition, typically R = 30). The caller removes failed repetitions first; a
non-finite value reaching this module is a bug upstream and is refused loudly
rather than silently ignored.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.stats

from enginebench.errors import DataError

__all__ = [
    "bootstrap_interval",
    "describe",
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


def t_interval(values: object, level: float = 0.95) -> tuple[float, float, float]:
    """Student-t interval of the mean over R repetitions: mean +- t_{(1+level)/2, R-1} s / sqrt(R).

    `s` is the sample standard deviation (ddof=1). With a single repetition no
    interval exists and `(mean, nan, nan)` is returned.
    """
    x = _finite_1d(values, "values")
    level = _check_level(level)
    mean = float(x.mean())
    r = x.size
    if r == 1:
        return mean, float("nan"), float("nan")
    half = float(scipy.stats.t.ppf(0.5 * (1.0 + level), r - 1)) * float(x.std(ddof=1)) / np.sqrt(r)
    return mean, mean - half, mean + half


def bootstrap_interval(
    values: object,
    rng: np.random.Generator,
    level: float = 0.95,
    n_resamples: int = 10_000,
) -> tuple[float, float, float]:
    """Percentile bootstrap interval of the mean: `(mean, low, high)`.

    All resamples come from one `(n_resamples, R)` integer draw of `rng`, so the
    result is a deterministic function of the generator state. With a single
    repetition every resample is identical and `(mean, nan, nan)` is returned,
    matching `t_interval`.
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
    mean = float(x.mean())
    if x.size == 1:
        return mean, float("nan"), float("nan")
    idx = rng.integers(0, x.size, size=(int(n_resamples), x.size))
    means = x[idx].mean(axis=1)
    alpha = 1.0 - level
    low, high = np.percentile(means, [50.0 * alpha, 100.0 * (1.0 - 0.5 * alpha)])
    return mean, float(low), float(high)


def describe(values: object) -> dict[str, float]:
    """Mean, SD (ddof=1), median, IQR (q75 - q25, linear percentiles) and n of finite values.

    The SD of a single value is undefined and reported as nan.
    """
    x = _finite_1d(values, "values")
    q25, q50, q75 = np.percentile(x, [25.0, 50.0, 75.0])
    return {
        "mean": float(x.mean()),
        "sd": float(x.std(ddof=1)) if x.size > 1 else float("nan"),
        "median": float(q50),
        "iqr": float(q75 - q25),
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
    difference. A constant non-zero difference gives `(+-inf, 0.0)`.
    """
    x, y = _paired(a, b)
    d = x - y
    if np.all(d == d[0]):
        return (float("nan"), 1.0) if d[0] == 0.0 else (float(np.copysign(np.inf, d[0])), 0.0)
    res = scipy.stats.ttest_rel(x, y)
    return float(res.statistic), float(res.pvalue)


def wilcoxon(a: object, b: object) -> tuple[float, float]:
    """Two-sided Wilcoxon signed-rank test on paired repetitions: `(statistic, pvalue)`.

    Delegates to `scipy.stats.wilcoxon` (zero differences dropped, exact or normal
    approximation chosen by scipy). All differences zero gives `(nan, 1.0)`
    instead of scipy's warnings.
    """
    x, y = _paired(a, b)
    if np.all(x == y):
        return float("nan"), 1.0
    with warnings.catch_warnings():
        # scipy warns when it falls back from the exact distribution (ties/zeros);
        # the fallback is the documented behaviour, not something the user can act on.
        warnings.simplefilter("ignore", category=UserWarning)
        res = scipy.stats.wilcoxon(x, y)
    return float(res.statistic), float(res.pvalue)
