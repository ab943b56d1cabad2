"""Point metrics against hand-computed values, scikit-learn and scipy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from sklearn.metrics import (
    mean_absolute_error,
    mean_absolute_percentage_error,
    mean_squared_error,
    r2_score,
)

from enginebench.errors import DataError
from enginebench.results.metrics import (
    METRICS,
    bounds,
    compute_metrics,
    fit,
    mae,
    mean_abs,
    nrmse,
    mape,
    ppmcc,
    r2,
    rmae,
    rmse,
    segment_rmae,
    segment_summary,
    skill,
)


@pytest.fixture
def data() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(42)
    y = 400.0 + 50.0 * rng.standard_normal(200)
    p = y + 5.0 * rng.standard_normal(200) + 2.0
    return y, p


# ---------------------------------------------------------------- hand values

def test_hand_computed_values() -> None:
    y = [1.0, 2.0, 3.0]
    p = [2.0, 2.0, 5.0]  # errors 1, 0, 2; SS_res = 5, SS_tot = 2
    assert mae(y, p) == pytest.approx(1.0)
    assert rmse(y, p) == pytest.approx(math.sqrt(5.0 / 3.0))
    assert r2(y, p) == pytest.approx(-1.5)
    assert mape(y, p) == pytest.approx((1.0 + 0.0 + 2.0 / 3.0) / 3.0 * 100.0)


def test_against_sklearn(data: tuple[np.ndarray, np.ndarray]) -> None:
    y, p = data
    assert mae(y, p) == pytest.approx(mean_absolute_error(y, p), rel=1e-12)
    assert rmse(y, p) == pytest.approx(math.sqrt(mean_squared_error(y, p)), rel=1e-12)
    assert r2(y, p) == pytest.approx(r2_score(y, p), rel=1e-12)
    # sklearn returns a fraction, ours is percent
    assert mape(y, p) == pytest.approx(100.0 * mean_absolute_percentage_error(y, p), rel=1e-12)


def test_ppmcc_against_scipy(data: tuple[np.ndarray, np.ndarray]) -> None:
    y, p = data
    assert ppmcc(y, p) == pytest.approx(scipy.stats.pearsonr(y, p).statistic, rel=1e-12)
    assert ppmcc(y, -3.0 * y + 7.0) == pytest.approx(-1.0)
    # large offset: centring must keep precision
    assert ppmcc(y + 1e9, p + 1e9) == pytest.approx(scipy.stats.pearsonr(y, p).statistic, rel=1e-6)


def test_ppmcc_constant_is_nan() -> None:
    y = np.array([1.0, 2.0, 4.0])
    assert math.isnan(ppmcc(y, np.full(3, 2.5)))
    assert math.isnan(ppmcc(np.full(3, 2.5), y))


def test_r2_constant_target_refused() -> None:
    with pytest.raises(DataError, match=r"^R\^2 is undefined: target constant"):
        r2([3.0, 3.0, 3.0], [1.0, 2.0, 3.0])


# ---------------------------------------------------------------- validation

def test_length_mismatch_message() -> None:
    with pytest.raises(DataError) as exc:
        mae([1.0, 2.0, 3.0], [1.0, 2.0])
    assert str(exc.value) == (
        "y_true and y_pred differ in length: 3 vs 2 rows; predict exactly one value per target row"
    )


def test_non_finite_names_row() -> None:
    with pytest.raises(DataError, match=r"y_pred has 2 non-finite value\(s\), first at row 1 \(nan\)"):
        rmse([1.0, 2.0, 3.0], [1.0, np.nan, np.inf])
    with pytest.raises(DataError, match=r"y_true in segment 1 has 1 non-finite value\(s\), first at row 0"):
        rmae([[1.0], [np.inf, 2.0]], [[1.0], [1.0, 2.0]], 1.0)


def test_empty_and_2d_refused() -> None:
    with pytest.raises(DataError, match="empty"):
        mae([], [])
    with pytest.raises(DataError, match=r"y_true must be a 1-D array, got shape \(2, 2\)"):
        mae(np.ones((2, 2)), np.ones((2, 2)))


# ---------------------------------------------------------------- MAPE refusal

def test_mape_refusal_message_exact() -> None:
    # 12 zeros among 100 targets whose mean |y| is 0.032: default floor = 3.2e-05
    y = np.concatenate([np.zeros(12), np.full(88, 0.032 * 100 / 88)])
    with pytest.raises(DataError) as exc:
        mape(y, y + 0.01)
    assert str(exc.value) == (
        "MAPE is undefined: 12 target values are within 3.2e-05 of zero "
        "(smallest |y| = 0.0); report MAE or RMAE instead"
    )


def test_mape_refusal_explicit_floor_and_relative_zero() -> None:
    with pytest.raises(DataError) as exc:
        mape([1.0, 2.0, -0.5], [1.0, 2.0, 0.0], floor=0.6)
    assert str(exc.value) == (
        "MAPE is undefined: 1 target value is within 0.6 of zero "
        "(smallest |y| = 0.5); report MAE or RMAE instead"
    )
    # floor=0 leaves only the relative test |y| <= 1e-8 max|y|
    with pytest.raises(DataError, match=r"1 target value is within 1e-08 of zero \(smallest \|y\| = 1e-12\)"):
        mape([1.0, 1e-12], [1.0, 1.0], floor=0.0)
    assert mape([1.0, 1e-3], [1.0, 2e-3], floor=0.0) == pytest.approx(50.0)
    with pytest.raises(DataError, match="floor must be a finite number >= 0, got floor=-1.0"):
        mape([1.0], [1.0], floor=-1.0)


# ---------------------------------------------------------------- RMAE

def test_rmae_two_segments_hand() -> None:
    st_ = [np.full(4, 10.0), np.array([10.0])]
    sp = [np.full(4, 11.0), np.array([15.0])]
    # segment MAEs 1 and 5; pooled MAE (4*1 + 5)/5 = 1.8, segment-averaged 3.0
    assert mae(np.concatenate(st_), np.concatenate(sp)) == pytest.approx(1.8)
    np.testing.assert_allclose(segment_rmae(st_, sp, 10.0), [10.0, 50.0])
    assert rmae(st_, sp, 10.0) == pytest.approx(30.0)


def test_rmae_bad_inputs() -> None:
    with pytest.raises(DataError, match="train_scale must be a positive finite number"):
        rmae([[1.0]], [[1.0]], 0.0)
    with pytest.raises(DataError, match="segments_true has 2 segments but segments_pred has 1"):
        rmae([[1.0], [2.0]], [[1.0]], 1.0)
    with pytest.raises(DataError, match="y_true and y_pred in segment 0 differ in length: 2 vs 1"):
        segment_rmae([[1.0, 2.0]], [[1.0]], 1.0)


def test_segment_summary_hand() -> None:
    s = segment_summary([1.0, 2.0, 3.0, 4.0, 10.0])
    assert s == pytest.approx({"mean": 4.0, "sd": math.sqrt(12.5), "median": 3.0, "iqr": 2.0})
    assert math.isnan(segment_summary([2.0])["sd"])


# ---------------------------------------------------------------- skill

def test_skill() -> None:
    assert skill(2.0, 4.0) == pytest.approx(0.5)
    assert skill(4.0, 4.0) == 0.0
    assert skill(0.0, 4.0) == 1.0
    assert skill(8.0, 4.0) == pytest.approx(-1.0)
    assert math.isnan(skill(float("nan"), 4.0))
    with pytest.raises(DataError, match="metric_baseline=0.0"):
        skill(1.0, 0.0)
    with pytest.raises(DataError, match="metric_method=-0.5"):
        skill(-0.5, 1.0)


# ---------------------------------------------------------------- compute_metrics

def test_compute_metrics_matches_parts(data: tuple[np.ndarray, np.ndarray]) -> None:
    y, p = data
    segs_t = [y[:20], y[20:150], y[150:]]
    segs_p = [p[:20], p[20:150], p[150:]]
    scale = 380.0
    values, notes = compute_metrics(segs_t, segs_p, scale)
    assert notes == {}
    assert values["mae"] == pytest.approx(mean_absolute_error(y, p))
    assert values["rmse"] == pytest.approx(math.sqrt(mean_squared_error(y, p)))
    assert values["r2"] == pytest.approx(r2_score(y, p))
    assert values["ppmcc"] == pytest.approx(scipy.stats.pearsonr(y, p).statistic)
    assert values["mape"] == pytest.approx(100.0 * mean_absolute_percentage_error(y, p))
    per_seg = np.array([mean_absolute_error(t, q) for t, q in zip(segs_t, segs_p)]) / scale * 100
    assert values["rmae"] == pytest.approx(per_seg.mean())
    assert values["rmae_seg_sd"] == pytest.approx(per_seg.std(ddof=1))
    assert values["rmae_seg_median"] == pytest.approx(np.median(per_seg))
    q75, q25 = np.percentile(per_seg, [75, 25])
    assert values["rmae_seg_iqr"] == pytest.approx(q75 - q25)
    assert values["n"] == 200 and values["n_segments"] == 3
    # every reported metric is registered (n and n_segments are counts, not metrics)
    assert set(values) - {"n", "n_segments"} == set(METRICS)


def test_compute_metrics_undefined_become_nan_with_notes() -> None:
    segs_t = [np.array([0.0, 1.0, 2.0]), np.array([3.0, 4.0])]
    segs_p = [np.full(3, 2.0), np.full(2, 2.0)]
    values, notes = compute_metrics(segs_t, segs_p, 2.0)
    assert math.isnan(values["mape"])
    assert notes["mape"] == (
        "MAPE is undefined: 1 target value is within 0.002 of zero "
        "(smallest |y| = 0.0); report MAE or RMAE instead"
    )
    assert math.isnan(values["ppmcc"])
    assert notes["ppmcc"] == "PPMCC is undefined: prediction constant; no correlation exists"
    assert values["mae"] == pytest.approx(1.2)
    assert values["r2"] == pytest.approx(1.0 - 10.0 / 10.0)
    assert set(notes) == {"mape", "ppmcc"}

    values, notes = compute_metrics([np.full(3, 5.0)], [np.array([4.0, 5.0, 6.0])], 5.0)
    assert math.isnan(values["r2"]) and notes["r2"].startswith("R^2 is undefined: target constant")
    assert notes["ppmcc"] == "PPMCC is undefined: target constant; no correlation exists"
    assert math.isnan(values["rmae_seg_sd"]) and "only 1 test segment" in notes["rmae_seg_sd"]
    assert values["rmae"] == pytest.approx(2.0 / 3.0 / 5.0 * 100.0)


def test_metric_registry_directions() -> None:
    lower = {k for k, v in METRICS.items() if v.lower_is_better}
    assert lower == {"mae", "rmse", "mape", "rmae", "rmae_seg_sd", "rmae_seg_median", "rmae_seg_iqr",
                     "nrmse", "nrmse_seg_mean", "nrmse_seg_median", "fit_seg_iqr"}
    assert not METRICS["r2"].lower_is_better and not METRICS["ppmcc"].lower_is_better
    assert not METRICS["fit"].lower_is_better and not METRICS["fit_seg_median"].lower_is_better
    assert all(v.description for v in METRICS.values())


# ---------------------------------------------------------------- identification metrics

def test_nrmse_and_fit_by_their_definitions(data: tuple[np.ndarray, np.ndarray]) -> None:
    y, p = data
    assert nrmse(y, p) == pytest.approx(math.sqrt(mean_squared_error(y, p)) / np.std(y), rel=1e-12)
    assert fit(y, p) == pytest.approx(100 * (1 - np.linalg.norm(y - p) / np.linalg.norm(y - y.mean())), rel=1e-12)
    # hand: y = 1, 2, 3 (SD sqrt(2/3)), errors 1, 0, 2 (RMSE sqrt(5/3)): NRMSE sqrt(5/2), fit 100 (1 - sqrt(5/2))
    assert nrmse([1.0, 2.0, 3.0], [2.0, 2.0, 5.0]) == pytest.approx(math.sqrt(2.5))
    assert fit([1.0, 2.0, 3.0], [2.0, 2.0, 5.0]) == pytest.approx(100 * (1 - math.sqrt(2.5)))
    assert fit(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-9) and fit(y, y) == 100.0
    with pytest.raises(DataError, match=r"^NRMSE is undefined: target constant \(all 3 values equal 2.0\)"):
        nrmse([2.0, 2.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(DataError, match=r"^fit is undefined: target constant"):
        fit([2.0, 2.0], [1.0, 2.0])


def test_compute_metrics_identification_values_per_segment_and_pooled(data: tuple[np.ndarray, np.ndarray]) -> None:
    y, p = data
    segs_t, segs_p = [y[:20], y[20:150], y[150:]], [p[:20], p[20:150], p[150:]]
    values, notes = compute_metrics(segs_t, segs_p, 380.0)
    assert notes == {}
    assert values["nrmse"] == pytest.approx(nrmse(y, p), rel=1e-12)  # pooled over all evaluated rows
    assert values["fit"] == pytest.approx(fit(y, p), rel=1e-12)
    per = np.array([math.sqrt(mean_squared_error(t, q)) / np.std(t) for t, q in zip(segs_t, segs_p)])
    assert values["nrmse_seg_mean"] == pytest.approx(per.mean(), rel=1e-12)
    assert values["nrmse_seg_median"] == pytest.approx(np.median(per), rel=1e-12)
    fits = 100 * (1 - per)
    assert values["fit_seg_mean"] == pytest.approx(fits.mean(), rel=1e-12)
    assert values["fit_seg_median"] == pytest.approx(np.median(fits), rel=1e-12)
    q75, q25 = np.percentile(fits, [75, 25])
    assert values["fit_seg_iqr"] == pytest.approx(q75 - q25, rel=1e-9)


def test_constant_outputs_make_nrmse_and_fit_nan_with_a_reason() -> None:
    values, notes = compute_metrics([np.full(4, 5.0)], [np.array([4.0, 5.0, 6.0, 5.0])], 5.0)
    for key, name in (("nrmse", "NRMSE"), ("fit", "fit"), ("r2", "R^2")):
        assert math.isnan(values[key])
        assert notes[key] == f"{name} is undefined: target constant (all 4 values equal 5.0); report MAE or RMSE instead"
    assert values["rmse"] == pytest.approx(math.sqrt(0.5))
    for key in ("nrmse_seg_mean", "fit_seg_median", "fit_seg_iqr"):
        assert math.isnan(values[key]) and notes[key].startswith("per-segment NRMSE and fit are undefined")
    # one constant segment of two: the per-segment summaries use the other and say so
    values, notes = compute_metrics([np.full(3, 2.0), np.array([1.0, 2.0, 3.0])],
                                    [np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 4.0])], 2.0)
    assert values["nrmse_seg_mean"] == pytest.approx(math.sqrt(1 / 3) / math.sqrt(2 / 3))
    assert values["fit_seg_iqr"] == 0.0 and math.isfinite(values["fit"])
    assert notes["seg_constant"] == ("1 of 2 segments (first: segment 0) have a constant output and no NRMSE or fit; "
                                     "the per-segment summaries leave them out")


def test_metric_bounds_are_declared() -> None:
    assert bounds("mae") == (0.0, math.inf) and bounds("nrmse") == (0.0, math.inf) and bounds("rmae") == (0.0, math.inf)
    assert bounds("ppmcc") == (-1.0, 1.0) and bounds("fit") == (-math.inf, 100.0) and bounds("r2") == (-math.inf, 1.0)
    assert bounds("skill_mae") == (-math.inf, 1.0) and bounds("time_fit_s") == (-math.inf, math.inf)


# ---------------------------------------------------------------- huge and tiny magnitudes

def _exact_pearson(t: np.ndarray, p: np.ndarray) -> float:
    """Pearson's r in exact rational arithmetic on the given doubles (one rounding, in the final root)."""
    from decimal import Decimal, getcontext
    from fractions import Fraction

    getcontext().prec = 40
    t_, p_ = [Fraction(float(a)) for a in t], [Fraction(float(b)) for b in p]
    mt, mp = sum(t_) / len(t_), sum(p_) / len(p_)
    sxy = sum((a - mt) * (b - mp) for a, b in zip(t_, p_))
    r2_ = sxy * sxy / (sum((a - mt) ** 2 for a in t_) * sum((b - mp) ** 2 for b in p_))
    return math.copysign(float((Decimal(r2_.numerator) / Decimal(r2_.denominator)).sqrt()), sxy)


def test_ppmcc_keeps_its_digits_under_a_large_offset() -> None:
    # offset 1e9, spread 1e-3: scaling before centring lost 1e-6 here (8.9e-5 in the issue)
    rng = np.random.default_rng(0)
    y = 1e9 + 1e-3 * rng.standard_normal(200)
    p = y + 5e-4 * rng.standard_normal(200)
    assert abs(ppmcc(y, p) - _exact_pearson(y, p)) < 1e-12
    # tiny spreads still do not underflow (b86baa1), huge ones do not overflow
    small = np.array([1.0, 2.0, 4.0, 3.0]) * 1e-276
    assert ppmcc(small, small[::-1]) == pytest.approx(_exact_pearson(small, small[::-1]), abs=1e-14)
    huge = np.array([1.0, 2.0, 4.0, 3.0]) * 4e307
    assert ppmcc(huge, small[::-1]) == pytest.approx(_exact_pearson(small, small[::-1]), abs=1e-14)


@pytest.mark.filterwarnings("error")  # no numpy RuntimeWarning may reach the user
def test_values_near_the_double_range_scale_exactly_or_are_nan_with_a_reason(data) -> None:
    y, p = data
    segs = lambda a: [a[:50], a[50:]]  # noqa: E731
    ref, _ = compute_metrics(segs(y), segs(p), mean_abs(y))
    big, notes = compute_metrics(segs(y * 2.0**1000), segs(p * 2.0**1000), mean_abs(y * 2.0**1000))
    assert notes == {}
    for key in ("mae", "rmse"):
        assert big[key] == pytest.approx(ref[key] * 2.0**1000, rel=1e-13)
    for key in ("nrmse", "fit", "r2", "ppmcc", "mape", "rmae", "rmae_seg_sd", "nrmse_seg_mean", "fit_seg_iqr"):
        assert big[key] == pytest.approx(ref[key], rel=1e-12), key
    # errors beyond the double range: nan with a reason, never inf; the scale-free metrics survive
    t = np.array([1e308, -1e308, 1e308, -1e308])
    values, notes = compute_metrics([t], [-t], 1.0)
    assert all(math.isnan(v) or math.isfinite(v) for v in values.values())
    assert {k for k, v in values.items() if isinstance(v, float) and math.isnan(v)} == set(notes)
    assert notes["rmse"] == ("rmse is undefined: its value overflows double precision (beyond 1.8e308); "
                             "rescale the target, e.g. change its unit")
    assert math.isnan(values["mae"]) and values["nrmse"] == pytest.approx(2.0) and values["ppmcc"] == pytest.approx(-1.0)
    assert values["mape"] == pytest.approx(200.0) and values["fit"] == pytest.approx(-100.0)
    # errors 1e300 times the output's spread: R^2 overflows (never an OverflowError); NRMSE is 1e300-ish
    t = np.array([0.0, 1.0, 0.0, 2.0])
    values, notes = compute_metrics([t], [t + np.array([1e300, -1e300, 1e300, 0.0])], 1.0)
    assert math.isnan(values["r2"]) and notes["r2"].startswith("r2 is undefined: its value overflows")
    assert values["rmse"] == pytest.approx(math.sqrt(3 / 4) * 1e300)
    assert values["nrmse"] == pytest.approx(values["rmse"] / np.std(t)) and values["fit"] < -1e300
    # a training mean |y| that overflowed (jobs should use mean_abs, which does not): RMAE is nan with a note
    values, notes = compute_metrics([t / 4], [t / 8], math.inf)
    assert math.isnan(values["rmae"]) and notes["rmae"].startswith("RMAE is undefined: mean |y| of the training data")
    assert mean_abs([1.5e308, -1.7e308]) == pytest.approx(1.6e308)


# ---------------------------------------------------------------- properties

_vals = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False, allow_infinity=False)


@st.composite
def _pairs(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = draw(st.integers(min_value=2, max_value=30))
    t = draw(arrays(float, n, elements=_vals))
    p = draw(arrays(float, n, elements=_vals))
    perm = draw(st.permutations(range(n)))
    return t, p, np.array(perm)


@settings(max_examples=40, deadline=None)
@given(_pairs())
def test_properties(pair: tuple[np.ndarray, np.ndarray, np.ndarray]) -> None:
    t, p, perm = pair
    m, r = mae(t, p), rmse(t, p)
    assert 0.0 <= m <= r * (1 + 1e-12) + 1e-12
    assert mae(t[perm], p[perm]) == pytest.approx(m, rel=1e-12, abs=1e-12)
    assert rmse(t[perm], p[perm]) == pytest.approx(r, rel=1e-12, abs=1e-12)
    c = ppmcc(t, p)
    assert math.isnan(c) or -1.0 <= c <= 1.0
    # one segment: RMAE is pooled MAE over the scale
    assert rmae([t], [p], 7.0) == pytest.approx(m / 7.0 * 100.0, rel=1e-12, abs=1e-12)


_any = st.floats(min_value=-1.7e308, max_value=1.7e308, allow_nan=False, allow_infinity=False)


@st.composite
def _segments_any_magnitude(draw: st.DrawFn) -> tuple[list[np.ndarray], list[np.ndarray]]:
    lengths = draw(st.lists(st.integers(1, 6), min_size=1, max_size=3))
    truth = [draw(arrays(float, n, elements=_any)) for n in lengths]
    pred = [draw(arrays(float, n, elements=_any)) for n in lengths]
    return truth, pred


@pytest.mark.filterwarnings("error")  # no RuntimeWarning and no OverflowError, whatever the magnitudes
@settings(max_examples=80, deadline=None)
@given(_segments_any_magnitude(), st.floats(1e-300, 1e300))
def test_every_value_is_finite_and_in_its_bounds_or_nan_with_a_note(pair, scale) -> None:
    truth, pred = pair
    values, notes = compute_metrics(truth, pred, scale)
    undefined = {k for k in METRICS if math.isnan(values[k])}
    assert undefined == set(notes) - {"seg_constant"}
    for key in set(METRICS) - undefined:
        low, high = bounds(key)
        assert math.isfinite(values[key]) and low <= values[key] <= high, (key, values[key])
