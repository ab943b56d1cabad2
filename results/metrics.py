"""Point metrics of one prediction against its target (docs/design.md, "Metrics"), vectorised with numpy.

Pooled metrics (MAE, RMSE, NRMSE, fit, R^2, PPMCC, MAPE) treat all rows alike; RMAE is
the turboshaft-moe paper's segment-averaged relative MAE, so long segments do not dominate; NRMSE and
fit are also summarised per segment (the identification view: one fit per record).
Every input is validated: arrays must be 1-D, equally long, non-empty and finite, and a
failure names the argument, the segment and the row.

Sums of squares and means are formed on values divided by a power of two near their
largest magnitude (exact scaling, as BLAS's nrm2 does), so data near 1e308 neither
overflow nor warn; a metric whose value itself does not fit in a double is nan with
its reason, never inf.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from enginebench.errors import DataError, SpecError
from enginebench.results.stats import describe
from enginebench.samples import Samples

__all__ = [
    "METRICS",
    "MetricInfo",
    "bounds",
    "compute_metrics",
    "fit",
    "mae",
    "mape",
    "mean_abs",
    "nrmse",
    "ppmcc",
    "r2",
    "rmae",
    "rmse",
    "segment_rmae",
    "segment_summary",
    "skill",
]


@dataclass(frozen=True)
class MetricInfo:
    """What a metric means, which direction is better (tables bold the best value) and its range.

    `low`/`high` are the bounds no value can cross (MAE >= 0, PPMCC in [-1, 1], fit <= 100):
    tables flag an interval over repetitions that crosses one.
    """

    description: str
    lower_is_better: bool
    low: float = -math.inf
    high: float = math.inf


METRICS: dict[str, MetricInfo] = {
    "mae": MetricInfo("mean absolute error, pooled over all rows (target units)", True, low=0.0),
    "rmse": MetricInfo("root mean squared error, pooled over all rows (target units)", True, low=0.0),
    "nrmse": MetricInfo("RMSE / standard deviation (ddof=0) of the measured output, pooled (dimensionless)",
                        True, low=0.0),
    "fit": MetricInfo("identification fit 100 (1 - ||y - yhat|| / ||y - mean(y)||), pooled (%)", False, high=100.0),
    "r2": MetricInfo("coefficient of determination 1 - SS_res/SS_tot, pooled", False, high=1.0),
    "ppmcc": MetricInfo("Pearson correlation of prediction and target, pooled", False, low=-1.0, high=1.0),
    "mape": MetricInfo("mean absolute percentage error, pooled (%)", True, low=0.0),
    "rmae": MetricInfo("segment-averaged MAE / mean |y| of training data (%)", True, low=0.0),
    "rmae_seg_sd": MetricInfo("SD (ddof=1) of per-segment RMAE across segments (%)", True, low=0.0),
    "rmae_seg_median": MetricInfo("median of per-segment RMAE across segments (%)", True, low=0.0),
    "rmae_seg_iqr": MetricInfo("interquartile range of per-segment RMAE across segments (%)", True, low=0.0),
    "nrmse_seg_mean": MetricInfo("mean over segments of each segment's NRMSE (its own output SD)", True, low=0.0),
    "nrmse_seg_median": MetricInfo("median over segments of each segment's NRMSE", True, low=0.0),
    "fit_seg_mean": MetricInfo("mean over segments of each segment's fit (%)", False, high=100.0),
    "fit_seg_median": MetricInfo("median over segments of each segment's fit (%)", False, high=100.0),
    "fit_seg_iqr": MetricInfo("interquartile range of per-segment fit across segments (%)", True, low=0.0),
}


def bounds(metric: str) -> tuple[float, float]:
    """(low, high) that no value of `metric` can cross; skill_* <= 1; unknown names are unbounded."""
    if metric in METRICS:
        return METRICS[metric].low, METRICS[metric].high
    if metric.startswith("skill_"):
        return -math.inf, 1.0
    if metric == "diverged":
        return 0.0, math.inf
    return -math.inf, math.inf


def _short(x: float) -> str:
    """Three significant digits, printed as Python prints floats (0.0, 3.2e-05, 0.00123)."""
    return repr(float(f"{x:.3g}"))


def _validate(y_true: object, y_pred: object, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """Return both arrays as float 1-D arrays, or raise DataError saying what and where."""
    t = np.asarray(y_true, dtype=float)
    p = np.asarray(y_pred, dtype=float)
    loc = f" in {where}" if where else ""
    for name, arr in (("y_true", t), ("y_pred", p)):
        if arr.ndim != 1:
            raise DataError(
                f"{name}{loc} must be a 1-D array, got shape {arr.shape}; pass one output column"
            )
    if t.shape != p.shape:
        raise DataError(
            f"y_true and y_pred{loc} differ in length: {t.size} vs {p.size} rows; "
            "predict exactly one value per target row"
        )
    if t.size == 0:
        raise DataError(f"y_true and y_pred{loc} are empty: no rows to score")
    for name, arr in (("y_true", t), ("y_pred", p)):
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise DataError(
                f"{name}{loc} has {bad.size} non-finite value(s), first at row {bad[0]} "
                f"({arr[bad[0]]}); clean the data or mark the prediction as diverged"
            )
    return t, p


# -- exact scaling: sums of squares and means that neither overflow nor warn -----------

def _pow2(x: np.ndarray) -> float:
    """A power of two with max|x| / 2 < it <= max|x| (1.0 for zeros): dividing by it is exact."""
    m = float(np.max(np.abs(x))) if x.size else 0.0
    if m == 0.0 or not math.isfinite(m):
        return 1.0
    return math.ldexp(1.0, math.frexp(m)[1] - 1)


def _mean(x: np.ndarray) -> float:
    """mean(x) without overflow in the sum (|result| <= max|x|, so it is always finite)."""
    s = _pow2(x)
    return float(np.mean(x / s)) * s


def _diff(a: np.ndarray, b: np.ndarray | float) -> tuple[np.ndarray, float]:
    """(d, factor) with a - b = factor * d: d = a - b, or (a - b) / 2 where the difference overflows."""
    with np.errstate(over="ignore", invalid="ignore"):
        d = a - b
    if np.all(np.isfinite(d)):
        return d, 1.0
    return a * 0.5 - np.multiply(b, 0.5), 2.0


def _scaled_sq(x: np.ndarray) -> tuple[float, float]:
    """(s, q) with mean(x^2) = s^2 q: q is the mean square of x / s, a number in [0, 4]."""
    s = _pow2(x)
    return s, float(np.mean(np.square(x / s)))


def _times(*factors: float) -> float:
    """The product of non-negative factors, smallest first; inf (never a warning) when it overflows."""
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        out = np.float64(1.0)
        for f in sorted(factors):
            out = out * np.float64(f)
    return float(out)


def _norm_ratio(e: np.ndarray, fe: float, c: np.ndarray, fc: float) -> float:
    """||fe e|| / ||fc c|| in scaled form (inf when it overflows, never OverflowError); c must not be all zero."""
    se, qe = _scaled_sq(e)
    sc, qc = _scaled_sq(c)
    if not qe:
        return 0.0
    with np.errstate(over="ignore", under="ignore"):
        r = np.float64(se) / np.float64(sc) * (np.float64(fe) / np.float64(fc))
    return _times(r, math.sqrt(qe / qc))


def mean_abs(values: object) -> float:
    """mean |values| of finite numbers without overflow in the sum (the RMAE denominator).

    Exact-scaled: finite whenever every value is (np.mean of values near 1e308 overflows),
    so it is the safe way to form the training scale passed to `compute_metrics`.
    """
    x = np.abs(np.asarray(values, dtype=float).ravel())
    return _mean(x) if x.size else float("nan")


CONSTANT_ULPS = 16
"""A target whose values all lie within this many units in the last place of its largest magnitude is constant:
its spread is rounding, and a ratio to it (NRMSE 1.5e14) would be noise."""


def _constant_reason(name: str, t: np.ndarray) -> str | None:
    """Why `name` (normalised by the output's spread) is undefined for targets `t`, or None."""
    if np.all(t == t[0]):
        return (f"{name} is undefined: target constant (all {t.size} values equal {float(t[0])!r}); "
                "report MAE or RMSE instead")
    lo, hi = float(np.min(t)), float(np.max(t))
    if np.isfinite(lo) and np.isfinite(hi) and hi - lo <= CONSTANT_ULPS * np.spacing(max(abs(lo), abs(hi))):
        return (f"{name} is undefined: target constant to rounding (its {t.size} values span {hi - lo:.3g}, within "
                f"{CONSTANT_ULPS} units in the last place of {hi:.17g}); report MAE or RMSE instead")
    return None


def _overflow_reason(name: str) -> str:
    return (f"{name} is undefined: its value overflows double precision (beyond 1.8e308); "
            "rescale the target, e.g. change its unit")


# -- pooled metrics ---------------------------------------------------------------------

def mae(y_true: object, y_pred: object) -> float:
    """Mean absolute error, mean(|y_pred - y_true|); inf only if it exceeds the double range."""
    t, p = _validate(y_true, y_pred)
    d, f = _diff(p, t)
    return _times(f, _mean(np.abs(d)))


def rmse(y_true: object, y_pred: object) -> float:
    """Root mean squared error, sqrt(mean((y_pred - y_true)^2)), computed exact-scaled."""
    t, p = _validate(y_true, y_pred)
    d, f = _diff(p, t)
    s, q = _scaled_sq(d)
    return _times(f, s, math.sqrt(q))


def r2(y_true: object, y_pred: object) -> float:
    """Coefficient of determination 1 - SS_res / SS_tot (may be negative).

    A constant target has SS_tot == 0 and no R^2: DataError.
    """
    t, p = _validate(y_true, y_pred)
    if np.all(t == t[0]):
        raise DataError(
            f"R^2 is undefined: target constant (all {t.size} values equal {float(t[0])!r}); "
            "report MAE or RMSE instead"
        )
    e, fe = _diff(p, t)
    c, fc = _diff(t, _mean(t))
    ratio = _norm_ratio(e, fe, c, fc)
    return 1.0 - _times(ratio, ratio)


def nrmse(y_true: object, y_pred: object) -> float:
    """RMSE / standard deviation (ddof=0) of the measured output: 0 is perfect, 1 is the mean's error.

    A constant target has no spread to normalise by: DataError.
    """
    t, p = _validate(y_true, y_pred)
    reason = _constant_reason("NRMSE", t)
    if reason is not None:
        raise DataError(reason)
    e, fe = _diff(p, t)
    c, fc = _diff(t, _mean(t))
    return _norm_ratio(e, fe, c, fc)


def fit(y_true: object, y_pred: object) -> float:
    """The identification fit in %: 100 (1 - ||y - yhat|| / ||y - mean(y)||) = 100 (1 - NRMSE).

    100 is perfect, 0 is as good as the output's own mean, negative is worse. A constant
    target: DataError.
    """
    t, p = _validate(y_true, y_pred)
    reason = _constant_reason("fit", t)
    if reason is not None:
        raise DataError(reason)
    return 100.0 * (1.0 - nrmse(t, p))


def _mape_refusal(t: np.ndarray, floor: float | None) -> str | None:
    """Why MAPE cannot be computed for targets `t`, or None when it can."""
    a = np.abs(t)
    if floor is None:
        floor = 1e-3 * _mean(a)
    else:
        floor = float(floor)
        if not np.isfinite(floor) or floor < 0.0:
            raise DataError(f"MAPE floor must be a finite number >= 0, got floor={floor}")
    relative = 1e-8 * float(a.max())
    near = (a <= relative) | (a < floor)
    count = int(near.sum())
    if count == 0:
        return None
    threshold = max(floor, relative)
    return (
        f"MAPE is undefined: {count} target {'value is' if count == 1 else 'values are'} "
        f"within {_short(threshold)} of zero "
        f"(smallest |y| = {_short(float(a.min()))}); report MAE or RMAE instead"
    )


def mape(y_true: object, y_pred: object, *, floor: float | None = None) -> float:
    """Mean absolute percentage error, mean(|e| / |y_true|) * 100.

    Refused (DataError) when any target is near zero: |y| <= 1e-8 max|y|, or
    |y| < `floor` (default 1e-3 * mean|y|). Percentages of near-zero targets
    explode and would make the metric meaningless.
    """
    t, p = _validate(y_true, y_pred)
    reason = _mape_refusal(t, floor)
    if reason is not None:
        raise DataError(reason)
    return _mape_value(t, p)


def _mape_value(t: np.ndarray, p: np.ndarray) -> float:
    """100 mean(|p - t| / |t|) for targets away from zero; inf if it exceeds the double range."""
    d, f = _diff(p, t)
    with np.errstate(over="ignore"):
        rel = np.abs(d) / np.abs(t)
    if not np.all(np.isfinite(rel)):
        return math.inf
    return _times(f, _mean(rel), 100.0)


def ppmcc(y_true: object, y_pred: object) -> float:
    """Pearson product-moment correlation of target and prediction (agrees with scipy.stats.pearsonr).

    A constant target or a constant prediction has no correlation: returns nan
    (not an exception), which the runner reports as undefined.
    """
    t, p = _validate(y_true, y_pred)
    if np.all(t == t[0]) or np.all(p == p[0]):
        return float("nan")
    # centre first, in the data's own units (t - mean(t) is exact for values near their mean,
    # so a large offset costs no digits), twice to remove the mean's own rounding; then divide
    # by a power of two near the largest deviation, so that neither the squares of tiny
    # spreads underflow nor those of huge ones overflow. r is scale-free.
    tc, pc = _centred(t), _centred(p)
    tn = np.linalg.norm(tc)
    pn = np.linalg.norm(pc)
    if tn == 0.0 or pn == 0.0:
        return float("nan")
    r = float(np.dot(tc / tn, pc / pn))
    return float(np.clip(r, -1.0, 1.0))


def _centred(x: np.ndarray) -> np.ndarray:
    """x - mean(x), centred twice and divided by a power of two near its largest magnitude."""
    c, _ = _diff(x, _mean(x))
    c = c - _mean(c)
    return c / _pow2(c)


def _check_scale(train_scale: float) -> float:
    """The RMAE denominator must be a positive finite mean |y| of the training data."""
    s = float(train_scale)
    if not np.isfinite(s) or s <= 0.0:
        raise DataError(
            f"train_scale must be a positive finite number (mean |y| over the training data), "
            f"got train_scale={train_scale}; RMAE is undefined for a zero training mean"
        )
    return s


def _segments(
    segments_true: Sequence[object], segments_pred: Sequence[object]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate paired segments; return pooled targets, pooled predictions and segment lengths."""
    if len(segments_true) != len(segments_pred):
        raise DataError(
            f"segments_true has {len(segments_true)} segments but segments_pred has "
            f"{len(segments_pred)}; predict every test segment"
        )
    if len(segments_true) == 0:
        raise DataError("no segments to score: segments_true and segments_pred are empty")
    pairs = [
        _validate(t, p, where=f"segment {i}")
        for i, (t, p) in enumerate(zip(segments_true, segments_pred))
    ]
    lengths = np.array([t.size for t, _ in pairs])
    return (
        np.concatenate([t for t, _ in pairs]),
        np.concatenate([p for _, p in pairs]),
        lengths,
    )


def _starts(lengths: np.ndarray) -> np.ndarray:
    return np.concatenate(([0], np.cumsum(lengths)[:-1]))


def _segment_mae(t: np.ndarray, p: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """MAE of each segment from pooled arrays, one vectorised (exact-scaled) reduction; inf on overflow."""
    d, f = _diff(p, t)
    a = np.abs(d)
    s = _pow2(a)
    with np.errstate(over="ignore"):
        # (m s) f, not m (s f): a segment of exact zeros stays 0 when s f alone would overflow (0 x inf = nan)
        return (np.add.reduceat(a / s, _starts(lengths)) / lengths * s) * f


def _segment_nrmse(t: np.ndarray, p: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Each segment's RMSE over its own output SD (ddof=0); nan for a segment whose output is constant."""
    starts = _starts(lengths)
    seg = np.repeat(np.arange(lengths.size), lengths)
    st = _pow2(t)
    means = np.add.reduceat(t / st, starts) / lengths * st
    c, fc = _diff(t, means[seg])
    e, fe = _diff(p, t)
    sc, se = _pow2(c), _pow2(e)
    ss_c = np.add.reduceat(np.square(c / sc), starts)
    ss_e = np.add.reduceat(np.square(e / se), starts)
    constant = np.minimum.reduceat(t, starts) == np.maximum.reduceat(t, starts)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        out = np.sqrt(ss_e / ss_c) * ((se / sc) * (fe / fc))
    out[constant] = np.nan
    return out


PER_SEGMENT = ("rmse", "nrmse", "mae")
"""The metrics kept per evaluated segment (a test record) in each job's metadata."""


def per_segment(segments_true: Sequence[object], segments_pred: Sequence[object]) -> dict[str, list[float]]:
    """RMSE, NRMSE (the segment's own output SD; nan when it is constant) and MAE of each segment, and its rows."""
    t, p, lengths = _segments(segments_true, segments_pred)
    starts = _starts(lengths)
    with np.errstate(over="ignore", invalid="ignore"):
        sq = np.add.reduceat(np.square(p - t), starts) / lengths
        ab = np.add.reduceat(np.abs(p - t), starts) / lengths
    return {"rmse": np.sqrt(sq).tolist(), "nrmse": _segment_nrmse(t, p, lengths).tolist(), "mae": ab.tolist(),
            "n": lengths.astype(int).tolist()}


def segment_rmae(
    segments_true: Sequence[object], segments_pred: Sequence[object], train_scale: float
) -> np.ndarray:
    """Per-segment RMAE in percent: each segment's MAE / `train_scale` * 100."""
    scale = _check_scale(train_scale)
    t, p, lengths = _segments(segments_true, segments_pred)
    with np.errstate(over="ignore"):
        return _segment_mae(t, p, lengths) / scale * 100.0


def rmae(
    segments_true: Sequence[object], segments_pred: Sequence[object], train_scale: float
) -> float:
    """The turboshaft-moe paper's relative MAE in percent: mean over segments of segment MAE, / `train_scale` * 100.

    `train_scale` is mean |y| over the training data. Averaging per segment keeps
    long segments from dominating (unlike pooled MAE / scale).
    """
    return _mean(segment_rmae(segments_true, segments_pred, train_scale))


def segment_summary(values: object) -> dict[str, float]:
    """Spread of per-segment values: mean, sd (ddof=1; nan for one segment), median, iqr."""
    d = describe(values)
    return {k: d[k] for k in ("mean", "sd", "median", "iqr")}


def skill(metric_method: float, metric_baseline: float) -> float:
    """Skill of an error metric against a baseline: 1 - method / baseline.

    0 = as good as the baseline, 1 = perfect, negative = worse. Only for
    lower-is-better metrics (MAE, RMSE, MAPE, RMAE). A nan input (an undefined
    metric) gives nan; a baseline <= 0 or a negative method error is refused.
    """
    m = float(metric_method)
    b = float(metric_baseline)
    if np.isnan(m) or np.isnan(b):
        return float("nan")
    if not np.isfinite(b) or b <= 0.0:
        raise DataError(
            f"skill is undefined: baseline error metric must be positive and finite, "
            f"got metric_baseline={b}; a perfect baseline leaves nothing to improve on"
        )
    if m < 0.0:
        raise DataError(
            f"skill needs an error metric (>= 0), got metric_method={m}; "
            "skill is not defined for R^2 or PPMCC"
        )
    return 1.0 - m / b


def compute_metrics(
    segments_true: Sequence[object],
    segments_pred: Sequence[object],
    train_scale: float,
    *,
    mape_floor: float | None = None,
) -> tuple[dict[str, float], dict[str, str]]:
    """All metrics for one job: `(values, notes)`.

    `values` has mae, rmse, nrmse, fit, r2, ppmcc, mape (pooled over all rows), rmae and
    rmae_seg_sd/median/iqr, nrmse_seg_mean/median and fit_seg_mean/median/iqr (over
    segments), n (rows) and n_segments. A metric that is undefined for this data (MAPE
    near zero targets; R^2, NRMSE and fit of a constant target; PPMCC of a constant
    prediction or target; any value beyond the double range) is nan in `values` and its
    reason is in `notes` under the same key; a note under ``seg_constant`` says which
    segments with a constant output the per-segment NRMSE/fit summaries leave out.
    Invalid input still raises DataError; an infinite `train_scale` (a training mean |y|
    that overflowed) makes the RMAE values nan with a note.
    """
    s = float(train_scale)
    scale = s if s == math.inf else _check_scale(train_scale)
    t, p, lengths = _segments(segments_true, segments_pred)
    notes: dict[str, str] = {}
    values: dict[str, float] = {"mae": mae(t, p), "rmse": rmse(t, p)}

    constant = _constant_reason("{}", t)
    for key, name in (("r2", "R^2"), ("nrmse", "NRMSE"), ("fit", "fit")):
        if constant is not None:
            values[key], notes[key] = math.nan, constant.format(name)
    if constant is None:
        e, fe = _diff(p, t)
        c, fc = _diff(t, _mean(t))
        ratio = _norm_ratio(e, fe, c, fc)
        values["r2"] = 1.0 - _times(ratio, ratio)
        values["nrmse"] = ratio
        with np.errstate(over="ignore"):
            values["fit"] = float(np.float64(100.0) * (1.0 - np.float64(ratio)))  # -inf is noted as overflow below

    values["ppmcc"] = ppmcc(t, p)
    if np.isnan(values["ppmcc"]):
        which = "target" if np.all(t == t[0]) else "prediction"
        notes["ppmcc"] = f"PPMCC is undefined: {which} constant; no correlation exists"

    reason = _mape_refusal(t, mape_floor)
    values["mape"] = _mape_value(t, p) if reason is None else math.nan
    if reason is not None:
        notes["mape"] = reason

    with np.errstate(over="ignore"):
        seg = _segment_mae(t, p, lengths) / scale * 100.0
    rmae_keys = {"rmae": "mean", "rmae_seg_sd": "sd", "rmae_seg_median": "median", "rmae_seg_iqr": "iqr"}
    if scale == math.inf:
        reason = ("RMAE is undefined: mean |y| of the training data overflows double precision; "
                  "rescale the target, e.g. change its unit")
        values.update(dict.fromkeys(rmae_keys, math.nan))
        notes.update(dict.fromkeys(rmae_keys, reason))
    elif np.all(np.isfinite(seg)):
        summary = segment_summary(seg)
        values.update({k: summary[v] for k, v in rmae_keys.items()})
    else:
        values.update(dict.fromkeys(rmae_keys, math.inf))  # noted as overflow below
    if lengths.size == 1:
        values["rmae_seg_sd"] = math.nan
        notes["rmae_seg_sd"] = "SD across segments is undefined: only 1 test segment"

    values.update(_segment_fit(t, p, lengths, notes))
    for key, value in values.items():
        if not math.isfinite(value) and key not in notes:
            values[key], notes[key] = math.nan, _overflow_reason(key)
    values = {k: values[k] for k in METRICS}
    values["n"] = int(t.size)
    values["n_segments"] = int(lengths.size)
    return values, notes


def _segment_fit(t: np.ndarray, p: np.ndarray, lengths: np.ndarray, notes: dict[str, str]) -> dict[str, float]:
    """nrmse_seg_mean/median and fit_seg_mean/median/iqr over the segments whose output varies.

    Segments with a constant output (or a single row) have no NRMSE; they are left out and
    named in ``notes["seg_constant"]``; when none is left every value is nan with a note.
    """
    keys = ("nrmse_seg_mean", "nrmse_seg_median", "fit_seg_mean", "fit_seg_median", "fit_seg_iqr")
    per = _segment_nrmse(t, p, lengths)
    defined = ~np.isnan(per)
    if not defined.any():
        reason = (f"per-segment NRMSE and fit are undefined: the output is constant within each of the "
                  f"{lengths.size} segment(s); report RMSE instead")
        notes.update(dict.fromkeys(keys, reason))
        return dict.fromkeys(keys, math.nan)
    if not defined.all():
        first = int(np.flatnonzero(~defined)[0])
        notes["seg_constant"] = (f"{int((~defined).sum())} of {lengths.size} segments (first: segment {first}) have a "
                                 "constant output and no NRMSE or fit; the per-segment summaries leave them out")
    per = per[defined]
    if not np.all(np.isfinite(per)):
        return dict.fromkeys(keys, math.inf)  # noted as overflow by the caller
    n = describe(per)
    with np.errstate(over="ignore", invalid="ignore"):
        f = describe(100.0 * (1.0 - per))
    return {"nrmse_seg_mean": n["mean"], "nrmse_seg_median": n["median"],
            "fit_seg_mean": f["mean"], "fit_seg_median": f["median"], "fit_seg_iqr": f["iqr"]}


CRITERIA = ("mae", "rmae", "rmse")
"""The metrics a model selection may minimise (``[selection] criterion``), scored over a whole grid by ``grid_scores``."""


def grid_scores(predictions: np.ndarray, data: Samples, criterion: str) -> np.ndarray:
    """Model selection's score of every grid point: (n_grid, n_rows, k) predictions of ``data`` -> (n_grid,).

    One of ``CRITERIA``: ``mae`` pools rows; ``rmae`` averages each segment's MAE (the training-scale divisor
    of RMAE is common to all grid points, so it does not change the ranking).
    Non-finite predictions score +inf. With several targets (a joint job) each target's
    errors are divided by its standard deviation over ``data`` first, so that outputs in
    different units weigh alike (one target: the scores are in its unit, as always).
    """
    err = np.abs(predictions - data.y[None])
    if data.y.shape[1] > 1:
        sd = data.y.std(axis=0)
        err = err / np.where(sd > 0, sd, 1.0)
    if criterion == "mae":
        score = err.mean(axis=(1, 2))
    elif criterion == "rmse":
        with np.errstate(over="ignore", invalid="ignore"):
            score = np.sqrt((err ** 2).mean(axis=(1, 2)))
    elif criterion == "rmae":
        sizes = [len(s) for s in data.segments]
        edges = np.r_[0, np.cumsum(sizes)]
        per_seg = np.stack([err[:, a:b].mean(axis=(1, 2)) for a, b in zip(edges[:-1], edges[1:])], axis=1)
        score = per_seg.mean(axis=1)
    else:
        raise SpecError(f"selection criterion {criterion!r} is not one of {', '.join(CRITERIA)}")
    return np.where(np.isfinite(score), score, np.inf)
