"""Point metrics of one prediction against its target (DESIGN sec. 6), vectorised with numpy.

Pooled metrics (MAE, RMSE, R^2, PPMCC, MAPE) treat all rows alike; RMAE is seed
003's segment-averaged relative MAE, so long segments do not dominate. Every
input is validated: arrays must be 1-D, equally long, non-empty and finite, and
a failure names the argument, the segment and the row.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from enginebench.errors import DataError, EngineBenchError
from enginebench.results.stats import describe

__all__ = [
    "METRICS",
    "MetricInfo",
    "compute_metrics",
    "mae",
    "mape",
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
    """What a metric means and which direction is better (tables bold the best value)."""

    description: str
    lower_is_better: bool


METRICS: dict[str, MetricInfo] = {
    "mae": MetricInfo("mean absolute error, pooled over all rows (target units)", True),
    "rmse": MetricInfo("root mean squared error, pooled over all rows (target units)", True),
    "r2": MetricInfo("coefficient of determination 1 - SS_res/SS_tot, pooled", False),
    "ppmcc": MetricInfo("Pearson correlation of prediction and target, pooled", False),
    "mape": MetricInfo("mean absolute percentage error, pooled (%)", True),
    "rmae": MetricInfo("segment-averaged MAE / mean |y| of training data (%)", True),
    "rmae_seg_sd": MetricInfo("SD (ddof=1) of per-segment RMAE across segments (%)", True),
    "rmae_seg_median": MetricInfo("median of per-segment RMAE across segments (%)", True),
    "rmae_seg_iqr": MetricInfo("interquartile range of per-segment RMAE across segments (%)", True),
}


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


def mae(y_true: object, y_pred: object) -> float:
    """Mean absolute error, mean(|y_pred - y_true|)."""
    t, p = _validate(y_true, y_pred)
    return float(np.mean(np.abs(p - t)))


def rmse(y_true: object, y_pred: object) -> float:
    """Root mean squared error, sqrt(mean((y_pred - y_true)^2))."""
    t, p = _validate(y_true, y_pred)
    return float(np.sqrt(np.mean((p - t) ** 2)))


def r2(y_true: object, y_pred: object) -> float:
    """Coefficient of determination 1 - SS_res / SS_tot (may be negative).

    A constant target has SS_tot == 0 and no R^2: DataError.
    """
    t, p = _validate(y_true, y_pred)
    ss_tot = float(np.sum((t - t.mean()) ** 2))
    if ss_tot == 0.0:
        raise DataError(
            f"R^2 is undefined: target constant (all {t.size} values equal {float(t[0])!r}); "
            "report MAE or RMSE instead"
        )
    return 1.0 - float(np.sum((t - p) ** 2)) / ss_tot


def _mape_refusal(t: np.ndarray, floor: float | None) -> str | None:
    """Why MAPE cannot be computed for targets `t`, or None when it can."""
    a = np.abs(t)
    if floor is None:
        floor = 1e-3 * float(a.mean())
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
    return float(np.mean(np.abs(p - t) / np.abs(t)) * 100.0)


def ppmcc(y_true: object, y_pred: object) -> float:
    """Pearson product-moment correlation of target and prediction (agrees with scipy.stats.pearsonr).

    A constant target or a constant prediction has no correlation: returns nan
    (not an exception), which the runner reports as undefined.
    """
    t, p = _validate(y_true, y_pred)
    if np.all(t == t[0]) or np.all(p == p[0]):
        return float("nan")
    # r is scale-free: divide by the largest magnitude first, so that neither the squares of
    # tiny spreads underflow (np.linalg.norm squares) nor those of huge values overflow
    t = t / np.max(np.abs(t))
    p = p / np.max(np.abs(p))
    tc = t - t.mean()
    pc = p - p.mean()
    tn = np.linalg.norm(tc)
    pn = np.linalg.norm(pc)
    if tn == 0.0 or pn == 0.0:
        return float("nan")
    r = float(np.dot(tc / tn, pc / pn))
    return float(np.clip(r, -1.0, 1.0))


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


def _segment_mae(t: np.ndarray, p: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """MAE of each segment from pooled arrays, one vectorised reduction."""
    starts = np.concatenate(([0], np.cumsum(lengths)[:-1]))
    return np.add.reduceat(np.abs(p - t), starts) / lengths


def segment_rmae(
    segments_true: Sequence[object], segments_pred: Sequence[object], train_scale: float
) -> np.ndarray:
    """Per-segment RMAE in percent: each segment's MAE / `train_scale` * 100."""
    scale = _check_scale(train_scale)
    t, p, lengths = _segments(segments_true, segments_pred)
    return _segment_mae(t, p, lengths) / scale * 100.0


def rmae(
    segments_true: Sequence[object], segments_pred: Sequence[object], train_scale: float
) -> float:
    """Seed 003's relative MAE in percent: mean over segments of segment MAE, / `train_scale` * 100.

    `train_scale` is mean |y| over the training data. Averaging per segment keeps
    long segments from dominating (unlike pooled MAE / scale).
    """
    return float(np.mean(segment_rmae(segments_true, segments_pred, train_scale)))


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

    `values` has mae, rmse, r2, ppmcc, mape (pooled over all rows), rmae and
    rmae_seg_sd/median/iqr (over segments), n (rows) and n_segments. A metric
    that is undefined for this data (MAPE near zero targets, R^2 of a constant
    target, PPMCC of a constant prediction or target) is nan in `values` and its
    reason is in `notes` under the same key. Invalid input still raises DataError.
    """
    scale = _check_scale(train_scale)
    t, p, lengths = _segments(segments_true, segments_pred)
    notes: dict[str, str] = {}
    err = p - t

    try:
        r2_value = r2(t, p)
    except EngineBenchError as exc:
        r2_value = float("nan")
        notes["r2"] = str(exc)

    r_value = ppmcc(t, p)
    if np.isnan(r_value):
        which = "target" if np.all(t == t[0]) else "prediction"
        notes["ppmcc"] = f"PPMCC is undefined: {which} constant; no correlation exists"

    reason = _mape_refusal(t, mape_floor)
    if reason is None:
        mape_value = float(np.mean(np.abs(err) / np.abs(t)) * 100.0)
    else:
        mape_value = float("nan")
        notes["mape"] = reason

    seg = _segment_mae(t, p, lengths) / scale * 100.0
    summary = segment_summary(seg)
    if lengths.size == 1:
        notes["rmae_seg_sd"] = "SD across segments is undefined: only 1 test segment"
    values: dict[str, float] = {
        "mae": float(np.mean(np.abs(err))),
        "rmse": float(np.sqrt(np.mean(err**2))),
        "r2": r2_value,
        "ppmcc": r_value,
        "mape": mape_value,
        "rmae": summary["mean"],
        "rmae_seg_sd": summary["sd"],
        "rmae_seg_median": summary["median"],
        "rmae_seg_iqr": summary["iqr"],
        "n": int(t.size),
        "n_segments": int(lengths.size),
    }
    return values, notes
