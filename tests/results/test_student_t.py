"""results.student_t: the Student-t tail and quantile without scipy, against scipy and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from enginebench.results.student_t import t_cdf, t_quantile, t_tail

scipy_stats = pytest.importorskip("scipy.stats", reason="the reference values come from scipy")
scipy_special = pytest.importorskip("scipy.special", reason="the reference values come from scipy")

DFS = [*range(1, 61), 75, 99, 120, 199, 299, 499, 999, 5_000, 100_000]
LEVELS = [0.5, 0.8, 0.9, 0.95, 0.98, 0.99, 0.995, 0.999, 0.9999, 1 - 1e-8]


@pytest.mark.parametrize("level", LEVELS)
def test_the_quantile_agrees_with_scipy_stats_t_ppf(level):
    """Both ends of every two-sided interval a table can print (p = (1 +- level) / 2), every df up to 60 and
    larger ones: relative difference at most 1e-10 (in practice a few 1e-16)."""
    for df in DFS:
        for p in (0.5 * (1 + level), 0.5 * (1 - level)):
            mine, ref = t_quantile(p, df), float(scipy_stats.t.ppf(p, df))
            assert mine == pytest.approx(ref, rel=1e-10, abs=0), (p, df)


def test_the_quantile_has_the_closed_forms_of_one_and_two_degrees_of_freedom():
    for p in (0.6, 0.9, 0.975, 0.999, 1 - 1e-12, 0.025, 1e-9):
        cauchy = 1 / math.tan(math.pi * (1 - p)) if p > 0.5 else -1 / math.tan(math.pi * p)  # tan(pi (p - 1/2))
        assert t_quantile(p, 1) == pytest.approx(cauchy, rel=1e-12)
        assert t_quantile(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)), rel=1e-12)
    assert t_quantile(0.5, 7) == 0.0 and t_quantile(1.0, 7) == math.inf and t_quantile(0.0, 7) == -math.inf
    assert math.isnan(t_quantile(1.5, 7)) and math.isnan(t_quantile(0.9, 0)) and math.isnan(t_quantile(math.nan, 3))


def test_the_quantile_inverts_the_tail():
    for df in (3, 29, 1000):
        for q in (0.4, 0.025, 1e-5, 1e-12):
            assert t_tail(t_quantile(1 - q, df), df) == pytest.approx(q, rel=1e-12)


def test_the_tails_agree_with_scipy_special_stdtr_down_to_tiny_p_values():
    """The paired test's two-sided p = 2 P(T < -|t|): agreement with scipy to 1e-10 relative for p-values from
    1/2 down to ~1e-300 (each tail computed as itself, not as 1 minus a number near 1)."""
    for df in DFS:
        for t in (0.0, 0.01, 0.3, 1.0, 2.0, 2.5, 4.0, 8.0, 20.0, 60.0, 300.0, 3e3, 1e5):
            for sign in (1.0, -1.0):
                ref = float(scipy_special.stdtr(df, sign * t))
                if ref < 1e-300:
                    assert t_cdf(sign * t, df) < 1e-290
                    continue
                assert t_cdf(sign * t, df) == pytest.approx(ref, rel=1e-10, abs=0), (df, sign * t)
                assert t_tail(-sign * t, df) == pytest.approx(ref, rel=1e-10, abs=0), (df, -sign * t)
    assert t_cdf(-math.inf, 4) == 0.0 and t_cdf(math.inf, 4) == 1.0 and math.isnan(t_cdf(math.nan, 4))


def test_the_paired_t_test_and_the_t_interval_agree_with_scipy():
    """What the tables print: stats.paired_ttest as scipy.stats.ttest_rel, stats.t_interval with scipy's quantile."""
    from enginebench.results.stats import paired_ttest, t_interval

    rng = np.random.default_rng(3)
    for n in (2, 3, 5, 30, 200):
        a, b = rng.normal(1.0, 0.2, n), rng.normal(1.1, 0.2, n)
        stat, p = paired_ttest(a, b)
        ref = scipy_stats.ttest_rel(a, b)
        assert stat == pytest.approx(ref.statistic, rel=1e-12) and p == pytest.approx(ref.pvalue, rel=1e-10)
        mean, low, high = t_interval(a, level=0.95)
        half = scipy_stats.t.ppf(0.975, n - 1) * a.std(ddof=1) / math.sqrt(n)
        assert (low, high) == pytest.approx((a.mean() - half, a.mean() + half), rel=1e-12)


@pytest.mark.parametrize("case", ["ties", "zeros", "ties-and-zeros", "over-50"])
def test_the_wilcoxon_normal_approximation_agrees_with_scipy(case):
    """Where scipy.stats.wilcoxon takes its normal approximation (more than 13 pairs with tied magnitudes or zero
    differences, or more than 50 pairs), stats.wilcoxon computes it without scipy: the same statistic and p."""
    import warnings

    from enginebench.results import stats

    rng = np.random.default_rng(len(case))
    for n in (14, 20, 30, 51, 120):
        x = np.round(rng.normal(1.0, 0.3, n), 6)
        step = {"ties": np.round(rng.normal(0.05, 0.2, n), 1),
                "zeros": np.where(rng.random(n) < 0.25, 0.0, rng.normal(0.05, 0.2, n)),
                "ties-and-zeros": np.round(rng.normal(0.0, 0.1, n), 1),
                "over-50": rng.normal(0.05, 0.3, n)}[case]
        y = np.round(x + step, 6)
        if case == "over-50" and n <= 50:
            continue
        assert stats._wilcoxon_exact(x - y) is None and stats._wilcoxon_normal(x - y) is not None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = scipy_stats.wilcoxon(x, y)
        stat, p = stats.wilcoxon(x, y)
        assert stat == ref.statistic and p == pytest.approx(ref.pvalue, rel=1e-12), (case, n)
    # 13 or fewer pairs with ties: scipy's permutation test, not this approximation
    assert stats._wilcoxon_normal(np.array([0.1, 0.1, -0.2, 0.3, 0.0, 0.5])) is None
