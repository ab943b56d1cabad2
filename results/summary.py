"""Summaries over repetitions: a run's long metric rows to one row per cell, and paired tests between methods.

``summarize`` turns a run's long metric rows into one row per (dataset, target, mode,
window, method, split, metric) with the mean, its interval over repetitions, and the
spread (sd, median, iqr) over repetitions. Skill against the naive baseline is added
per repetition (paired) where the baseline ran. Failed repetitions and diverged segments
are counted; identical repetitions carry no interval (their note says so); a Student-t
interval that crosses the metric's bound (MAE < 0, PPMCC > 1) is replaced by the
bootstrap percentile interval, which cannot cross it (its note keeps the t interval).
``paired_tests`` compares each method with its block's best, with Holm-adjusted p-values.

Rendering these frames (term, md, latex, csv, html) is ``results.tables``' job.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.results.metrics import METRICS, bounds
from enginebench.results.stats import bootstrap_interval, describe, holm, identical, paired_pvalues, t_interval

KEYS = ["dataset", "target", "mode", "window", "method", "split"]
SUMMARY_COLUMNS = KEYS + ["metric", "mean", "ci_low", "ci_high", "sd", "median", "iqr", "n_repeats", "n_failed",
                          "interval", "n_diverged", "n_segments", "note", "selected_score"]
BASELINE = "naive-mean"
SKILL_OF = ("mae", "rmae")
IDENTICAL_NOTE = "identical repetitions: every repetition gave the same value, so there is no interval"
CROSSED_NOTE = "interval crosses the metric's bound"
SELECTED_PREFIX = "selected_"
"""Job-level metric rows ``selected_<criterion>`` (split "-"): the selected point's mean validation score, which
``summarize`` puts beside the test metric of the same name as ``selected_score``."""


def with_skill(ok: pd.DataFrame) -> pd.DataFrame:
    """Add skill_<m> = 1 - m / m_baseline rows, paired on repetition (undefined where the baseline's error is 0)."""
    base = ok[(ok["method"] == BASELINE) & ok["metric"].isin(SKILL_OF)]
    if base.empty:
        return ok
    keys = ["dataset", "target", "mode", "window", "split", "repetition", "metric"]
    merged = ok[ok["metric"].isin(SKILL_OF)].merge(base[keys + ["value"]], on=keys, suffixes=("", "_base"))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        merged["value"] = 1.0 - merged["value"] / merged["value_base"]
    merged = merged[np.isfinite(merged["value"].to_numpy(dtype=float))]
    merged["metric"] = "skill_" + merged["metric"]
    return pd.concat([ok, merged.drop(columns="value_base")], ignore_index=True)


def bound_text(metric: str) -> str:
    """The bound of ``metric`` in words (``mae >= 0``, ``ppmcc lies in [-1, 1]``)."""
    low, high = bounds(metric)
    if math.isfinite(low) and math.isfinite(high):
        return f"{metric} lies in [{low:g}, {high:g}]"
    return f"{metric} >= {low:g}" if math.isfinite(low) else f"{metric} <= {high:g}"


def _segment_counts(metrics: pd.DataFrame) -> pd.DataFrame:
    """n_diverged and n_segments per KEYS: diverged and evaluated segments, summed over the successful repetitions."""
    rows = metrics[(metrics["status"] == "ok") & metrics["metric"].isin(["diverged", "n_segments"])]
    if rows.empty:
        return pd.DataFrame(columns=KEYS + ["n_diverged", "n_segments"])
    out = rows.pivot_table(index=KEYS, columns="metric", values="value", aggfunc="sum", sort=False)
    out = out.reindex(columns=["diverged", "n_segments"]).fillna(0).astype(int)
    return out.rename(columns={"diverged": "n_diverged"}).reset_index()


def summarize(metrics: pd.DataFrame, interval: str = "t", level: float = 0.95, seed: int = 0) -> pd.DataFrame:
    """One row per (keys, metric): mean, interval, sd, median, iqr over repetitions, with counts and a note.

    Non-finite stored values (nan for an undefined metric, inf written by older versions
    on overflow) are left out like undefined ones. ``note`` says when the values are
    identical (no interval) or when the Student-t interval crossed the metric's bound:
    then ``ci_low``/``ci_high`` hold the bootstrap percentile interval, ``interval``
    says "bootstrap" and the note keeps the t interval.
    """
    if metrics.empty:
        raise DataError("no metric rows to summarise")
    failed = (metrics[metrics["status"] != "ok"]
              .drop_duplicates(KEYS[:-1] + ["repetition"])
              .groupby(KEYS[:-1]).size().rename("n_failed"))
    ok = metrics[(metrics["status"] == "ok") & (metrics["split"] != "-") & ~metrics["metric"].isin(["n", "n_segments"])]
    ok = with_skill(ok[np.isfinite(ok["value"].to_numpy(dtype=float))])
    rng = np.random.default_rng(seed)
    fallback = np.random.default_rng([seed, 1])  # bootstrap in place of a bound-crossing t interval
    rows = []
    for key, group in ok.groupby(KEYS + ["metric"], sort=False):
        v = group["value"].to_numpy(dtype=float)
        kind, note = interval, ""
        if interval == "bootstrap":
            mean, low, high = bootstrap_interval(v, rng, level=level)
        else:
            mean, low, high = t_interval(v, level=level)
        lo, hi = bounds(key[-1])
        if identical(v):
            note = f"{IDENTICAL_NOTE} (n = {len(v)})"
        elif np.isfinite(low) and (low < lo or high > hi):
            note = (f"{CROSSED_NOTE} ({bound_text(key[-1])}): the Student-t interval [{low:.4g}, {high:.4g}] is "
                    "replaced by the bootstrap percentile interval")
            _, low, high = bootstrap_interval(v, fallback, level=level)
            low, high, kind = min(low, mean), max(high, mean), "bootstrap"  # an interval holds its mean
        d = describe(v)
        rows.append((*key, mean, low, high, d["sd"], d["median"], d["iqr"], len(v), 0, kind, 0, 0, note, np.nan))
    out = pd.DataFrame(rows, columns=SUMMARY_COLUMNS)
    if not failed.empty:
        out = pd.concat([out, _all_failed_rows(out, failed, interval)], ignore_index=True)
        out = out.drop(columns="n_failed").merge(failed.reset_index(), on=KEYS[:-1], how="left")
        out["n_failed"] = out["n_failed"].fillna(0).astype(int)
    counts = _segment_counts(metrics)
    if len(counts) and len(out):
        out = out.drop(columns=["n_diverged", "n_segments"]).merge(counts, on=KEYS, how="left")
        out[["n_diverged", "n_segments"]] = out[["n_diverged", "n_segments"]].fillna(0).astype(int)
    out = _with_selected_scores(out, metrics)[SUMMARY_COLUMNS]
    return out.sort_values(["target", "window", "split", "method", "metric"], kind="stable").reset_index(drop=True)


def _with_selected_scores(out: pd.DataFrame, metrics: pd.DataFrame) -> pd.DataFrame:
    """``selected_score`` on the rows whose metric is the selection's criterion: the selected point's validation
    score (job rows ``selected_<criterion>``), averaged over the successful repetitions; nan elsewhere.

    Beside the test mean it tells a model that selection already found poor from one that scored well on
    the validation blocks and not on the test records (``results.tables``' notes say which).
    """
    prefix = SELECTED_PREFIX
    rows = metrics[(metrics["status"] == "ok") & (metrics["split"] == "-")
                   & metrics["metric"].astype(str).str.startswith(prefix)]
    if rows.empty or out.empty:
        return out
    keys = KEYS[:-1]
    scores = (rows.assign(metric=rows["metric"].astype(str).str[len(prefix):])
              .groupby(keys + ["metric"], sort=False, dropna=False)["value"].mean().rename("score").reset_index())
    merged = out.merge(scores, on=keys + ["metric"], how="left")
    merged["selected_score"] = merged["score"].astype(float)
    return merged.drop(columns="score")


def _all_failed_rows(out: pd.DataFrame, failed: pd.Series, interval: str) -> pd.DataFrame:
    """Empty (nan, n = 0) rows for methods whose every repetition failed, so tables still list them.

    They take the splits and metrics that other methods of the same block report (MAE on
    the test part when no method of the block succeeded).
    """
    block = KEYS[:4]
    present = set(map(tuple, out[KEYS[:-1]].drop_duplicates().to_numpy().tolist())) if len(out) else set()
    rows = []
    for key in failed.index:
        if tuple(key) in present:
            continue
        others = out[(out[block] == pd.Series(dict(zip(block, key[:4])))).all(axis=1)] if len(out) else out
        cells = others[["split", "metric"]].drop_duplicates().itertuples(index=False) if len(others) else [("test", "mae")]
        for split, metric in cells:
            rows.append((*key, split, metric, *[float("nan")] * 6, 0, 0, interval, 0, 0, "", float("nan")))
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS).astype(out.dtypes.to_dict()) if rows else out.iloc[:0]


PAIRED_COLUMNS = ["target", "mode", "window", "split", "method", "versus", "mean_difference", "t_pvalue",
                  "wilcoxon_pvalue", "n_pairs", "t_pvalue_holm", "wilcoxon_pvalue_holm", "note"]


def paired_tests(metrics: pd.DataFrame, metric: str = "mae") -> pd.DataFrame:
    """Each method against the best (lowest mean) of its block, paired on repetitions.

    Columns: target, mode, window, split, method, versus, mean_difference, t_pvalue,
    wilcoxon_pvalue, n_pairs (raw p-values), t_pvalue_holm and wilcoxon_pvalue_holm (Holm
    adjusted over every test of the frame: the family printed under a table), note (why a
    pair has no test: identical repetitions, a difference that never varies). A positive
    difference means ``method`` is worse than ``versus``.
    """
    ok = metrics[(metrics["status"] == "ok") & (metrics["metric"] == metric)]
    ok = ok[np.isfinite(ok["value"].to_numpy(dtype=float))]
    rows = []
    block_keys = ["target", "mode", "window", "split"]
    for key, block in ok.groupby(block_keys, sort=False):
        table = block.pivot_table(index="repetition", columns="method", values="value", aggfunc="first")
        if table.shape[1] < 2:
            continue
        lower = METRICS[metric].lower_is_better if metric in METRICS else not metric.startswith("skill")
        best = table.mean().idxmin() if lower else table.mean().idxmax()
        for method in table.columns:
            if method == best:
                continue
            pair = table[[method, best]].dropna()
            if len(pair) < 2:
                continue
            p_t, p_w, note = paired_pvalues(pair[method], pair[best])
            with np.errstate(over="ignore", invalid="ignore"):
                diff = float((pair[method] - pair[best]).mean())
            rows.append((*key, method, best, diff, p_t, p_w, len(pair), np.nan, np.nan, note))
    out = pd.DataFrame(rows, columns=PAIRED_COLUMNS)
    if len(out):
        out["t_pvalue_holm"] = holm(out["t_pvalue"])
        out["wilcoxon_pvalue_holm"] = holm(out["wilcoxon_pvalue"])
    return out
