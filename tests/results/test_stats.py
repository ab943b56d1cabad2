"""Intervals and paired tests against hand-computed values and scipy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from enginebench.errors import DataError
from enginebench.results.stats import (
    bootstrap_interval,
    describe,
    holm,
    identical,
    paired_ttest,
    t_interval,
    wilcoxon,
)


def test_t_interval_hand_example() -> None:
    mean, low, high = t_interval([1.0, 2.0, 3.0, 4.0, 5.0])
    # t_{0.975,4} = 2.776445105, s/sqrt(5) = sqrt(2.5)/sqrt(5) = 0.707106781
    half = 2.776445105 * 0.707106781
    assert mean == 3.0
    assert low == pytest.approx(3.0 - half, abs=1e-8)
    assert high == pytest.approx(3.0 + half, abs=1e-8)
    assert high - mean == pytest.approx(1.963243, abs=1e-6)


def test_t_interval_matches_scipy_other_level() -> None:
    x = np.random.default_rng(3).normal(10.0, 2.0, size=30)
    low_ref, high_ref = scipy.stats.t.interval(
        0.9, df=29, loc=x.mean(), scale=scipy.stats.sem(x)
    )
    mean, low, high = t_interval(x, level=0.9)
    assert (low, high) == pytest.approx((low_ref, high_ref), rel=1e-12)


def test_t_interval_edge_cases() -> None:
    mean, low, high = t_interval([4.2])
    assert mean == 4.2 and math.isnan(low) and math.isnan(high)
    with pytest.raises(DataError, match=r"values has 1 non-finite value\(s\) \(first at index 1: nan\)"):
        t_interval([1.0, float("nan"), 2.0])
    with pytest.raises(DataError, match="level=1.5"):
        t_interval([1.0, 2.0], level=1.5)
    with pytest.raises(DataError, match="values is empty"):
        t_interval([])


def test_bootstrap_agrees_with_scipy() -> None:
    x = np.random.default_rng(11).gamma(2.0, 1.5, size=30)
    mean, low, high = bootstrap_interval(x, np.random.default_rng(5), n_resamples=20_000)
    ref = scipy.stats.bootstrap(
        (x,), np.mean, method="percentile", n_resamples=20_000, rng=np.random.default_rng(6)
    ).confidence_interval
    se = x.std(ddof=1) / math.sqrt(x.size)
    # Monte-Carlo SD of each 2.5 % / 97.5 % quantile is ~0.02 se at 20k resamples
    assert mean == pytest.approx(x.mean())
    assert low == pytest.approx(ref.low, abs=0.15 * se)
    assert high == pytest.approx(ref.high, abs=0.15 * se)
    assert low < mean < high


def test_bootstrap_deterministic_given_seed() -> None:
    x = [1.0, 3.0, 2.0, 8.0, 5.0, 4.0]
    a = bootstrap_interval(x, np.random.default_rng(123), n_resamples=500)
    b = bootstrap_interval(x, np.random.default_rng(123), n_resamples=500)
    c = bootstrap_interval(x, np.random.default_rng(124), n_resamples=500)
    assert a == b
    assert a != c


def test_bootstrap_edge_cases() -> None:
    mean, low, high = bootstrap_interval([2.0], np.random.default_rng(0))
    assert mean == 2.0 and math.isnan(low) and math.isnan(high)
    with pytest.raises(DataError, match="rng must be a numpy.random.Generator, got int"):
        bootstrap_interval([1.0, 2.0], 0)  # type: ignore[arg-type]
    with pytest.raises(DataError, match="n_resamples=0"):
        bootstrap_interval([1.0, 2.0], np.random.default_rng(0), n_resamples=0)


def test_describe_hand() -> None:
    d = describe([1.0, 2.0, 3.0, 4.0, 10.0])
    assert d == pytest.approx(
        {"mean": 4.0, "sd": math.sqrt(12.5), "median": 3.0, "iqr": 2.0, "n": 5}
    )
    assert d["n"] == 5 and isinstance(d["n"], int)


def test_paired_ttest_against_scipy() -> None:
    rng = np.random.default_rng(7)
    a = rng.normal(3.0, 1.0, size=30)
    b = a - 0.3 + 0.5 * rng.standard_normal(30)
    ref = scipy.stats.ttest_rel(a, b)
    stat, p = paired_ttest(a, b)
    assert stat == pytest.approx(ref.statistic, rel=1e-12)
    assert p == pytest.approx(ref.pvalue, rel=1e-10)
    # hand: differences 1, 2, 3 -> t = 2 / (1 / sqrt 3)
    stat, _ = paired_ttest([2.0, 4.0, 6.0], [1.0, 2.0, 3.0])
    assert stat == pytest.approx(2.0 * math.sqrt(3.0))


def test_paired_ttest_degenerate() -> None:
    stat, p = paired_ttest([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert math.isnan(stat) and p == 1.0
    # a constant non-zero difference (copies on each side) has no variance: no test, never p = 0
    stat, p = paired_ttest([2.0, 3.0, 4.0], [1.0, 2.0, 3.0])
    assert math.isnan(stat) and math.isnan(p)


def test_paired_length_mismatch_message() -> None:
    with pytest.raises(DataError) as exc:
        paired_ttest([1.0, 2.0, 3.0], [1.0, 2.0])
    assert str(exc.value) == (
        "paired test needs one value per repetition on both sides: a has 3 values, b has 2; "
        "compare the two methods on the same repetitions"
    )
    with pytest.raises(DataError, match="a has 2 values, b has 4"):
        wilcoxon([1.0, 2.0], [1.0, 2.0, 3.0, 4.0])


def test_wilcoxon_against_scipy_and_hand() -> None:
    rng = np.random.default_rng(9)
    a = rng.normal(2.0, 1.0, size=25)
    b = a + 0.4 * rng.standard_normal(25) - 0.2
    ref = scipy.stats.wilcoxon(a, b)
    assert wilcoxon(a, b) == pytest.approx((ref.statistic, ref.pvalue), rel=1e-12)
    # all five differences positive: W- = 0, exact two-sided p = 2 / 2^5
    stat, p = wilcoxon([2.0, 4.0, 6.0, 8.0, 10.0], [1.0, 2.0, 3.0, 4.0, 5.0])
    assert stat == 0.0 and p == pytest.approx(0.0625)


def test_wilcoxon_all_zero_differences() -> None:
    stat, p = wilcoxon([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    assert math.isnan(stat) and p == 1.0


# ---------------------------------------------------------------- identical repetitions

def test_identical_repetitions_carry_no_interval() -> None:
    assert identical([0.1719, 0.1719]) and not identical([0.1719]) and not identical([1.0, 1.0 + 1e-15])
    mean, low, high = t_interval([0.1719] * 5)
    assert mean == 0.1719 and math.isnan(low) and math.isnan(high)
    mean, low, high = bootstrap_interval([0.1719] * 5, np.random.default_rng(0))
    assert mean == 0.1719 and math.isnan(low) and math.isnan(high)


# ---------------------------------------------------------------- Holm

def test_holm_hand_and_step_down() -> None:
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1 = 0.02, 0.03, 0.06, 0.04 -> running max 0.06
    np.testing.assert_allclose(holm([0.01, 0.04, 0.03, 0.005]), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(holm([0.5, 0.9]), [1.0, 1.0])  # capped at 1
    out = holm([0.01, float("nan"), 0.02])  # nan is no test: the family has 2 members
    assert math.isnan(out[1]) and out[0] == pytest.approx(0.02) and out[2] == pytest.approx(0.02)
    assert holm([]).size == 0


def test_holm_against_its_definition() -> None:
    p = np.random.default_rng(4).uniform(0, 0.2, 12)
    m, ranked = p.size, np.sort(p)
    ref = [min(1.0, max((m - j) * ranked[j] for j in range(k + 1))) for k in range(m)]
    np.testing.assert_allclose(np.sort(holm(p)), ref, rtol=1e-15)
    assert (holm(p) >= p).all()


# ---------------------------------------------------------------- magnitudes near the double range

@pytest.mark.filterwarnings("error")
def test_statistics_of_huge_values_scale_exactly() -> None:
    x = np.random.default_rng(2).normal(3.0, 1.0, 10)
    k = 2.0**1015  # values up to ~1.8e306: plain sums of squares overflow
    mean, low, high = t_interval(x * k)
    ref = t_interval(x)
    assert (mean, low, high) == pytest.approx(tuple(v * k for v in ref), rel=1e-14)
    d, dk = describe(x), describe(x * k)
    assert all(dk[key] == pytest.approx(d[key] * k, rel=1e-14) for key in ("mean", "sd", "median", "iqr"))
    b = bootstrap_interval(x * k, np.random.default_rng(1), n_resamples=200)
    assert b == pytest.approx(tuple(v * k for v in bootstrap_interval(x, np.random.default_rng(1), n_resamples=200)))
    assert paired_ttest(x * k, x[::-1] * k) == pytest.approx(paired_ttest(x, x[::-1]), rel=1e-12)
    # a spread beyond the double range: no interval and no SD rather than inf
    mean, low, high = t_interval([1.7e308, -1.7e308, 1.7e308])
    assert math.isfinite(mean) and math.isnan(low) and math.isnan(high)
    assert math.isnan(describe([1.7e308, -1.7e308])["sd"])
