"""Per-record results: which test record a model gets wrong, and the spread of its error across records.

A campaign's test part is a handful of records (measurements); an engineer asks on which of
them each method fails, and how much its score would move on another record. Every job keeps
each evaluated segment's RMSE, NRMSE and MAE in its metadata (``meta["segments"]``, parts of up
to ``jobs.MAX_RECORDED_SEGMENTS`` segments); this module reads them back as one tidy table and
summarises them across records: the mean over records with a Student-t 95% interval whose n is
the number of records (the records, not the repetitions, are the samples here).
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import pandas as pd

from enginebench.results.stats import t_interval
from enginebench.results.summary import BASELINE
from enginebench.results.tables import LINEAR_BASELINES, NAIVE_BASELINES, NO_BETTER, linear_baseline

COLUMNS = ("target", "window", "method", "repetition", "part", "record", "metric", "value", "rows")


def record_frame(metas: Mapping[str, Mapping[str, Any]]) -> pd.DataFrame:
    """Tidy rows (target, window, method, repetition, part, record, metric, value, rows) of every ok job."""
    rows = []
    for meta in metas.values():
        if meta.get("status") != "ok":
            continue
        for part, kept in (meta.get("segments") or {}).items():
            ids = kept.get("ids", [])
            for target, values in kept.items():
                if target == "ids":
                    continue
                n = values.get("n", [None] * len(ids))
                for metric, per in values.items():
                    if metric == "n":
                        continue
                    rows += [(target, meta.get("window", 0.0), meta.get("method"), meta.get("repetition", 0), part,
                              rid, metric, float(v) if v is not None else np.nan, k)
                             for rid, v, k in zip(ids, per, n)]
    return pd.DataFrame(rows, columns=list(COLUMNS))


def record_table(frame: pd.DataFrame, metric: str, part: str = "test") -> pd.DataFrame:
    """Per (target, window, method): the metric on each record (mean over repetitions) and across records
    their mean, the 95% Student-t interval over records (low, high) and the worst record."""
    sel = frame[(frame["metric"] == metric) & (frame["part"] == part)]
    if sel.empty:
        return pd.DataFrame()
    per = sel.groupby(["target", "window", "method", "record"], sort=False)["value"].mean().reset_index()
    wide = per.pivot_table(index=["target", "window", "method"], columns="record", values="value", sort=False)
    records = list(dict.fromkeys(per["record"]))
    wide = wide[records]
    summary = []
    for _, row in wide.iterrows():
        v = row.to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        mean, low, high = t_interval(v) if len(v) else (np.nan,) * 3
        worst = row.idxmax() if np.isfinite(row.to_numpy(dtype=float)).any() else ""
        summary.append((mean, low, high, len(v), worst))
    out = wide.reset_index()
    out[["mean", "low", "high", "n_records", "worst"]] = pd.DataFrame(summary, index=out.index)
    return out.sort_values(["target", "window", "mean"], kind="stable").reset_index(drop=True)


def to_rich(table: pd.DataFrame, metric: str, units: Mapping[str, str] | None = None) -> list[Any]:
    """One rich table per (target, window): methods as rows, records as columns, then the summary over records."""
    from rich.table import Table

    units = units or {}
    records = [c for c in table.columns if c not in ("target", "window", "method", "mean", "low", "high",
                                                      "n_records", "worst")]
    out = []
    for (target, window), block in table.groupby(["target", "window"], sort=False):
        unit = units.get(target, "")
        shown = f"{metric} [{unit}]" if metric in ("rmse", "mae") and unit else metric
        t = Table(title=f"{target} | {shown} per test record | Delta {window:g} s", title_justify="left",
                  box=None, header_style="bold")
        t.add_column("method")
        present = [r for r in records if block[r].notna().any()]
        for r in present:
            t.add_column(str(r), justify="right")
        t.add_column("mean over records (95% t)", justify="right")
        t.add_column("worst", justify="left")
        for _, row in block.iterrows():
            ci = "" if not np.isfinite(row["low"]) else f" [{row['low']:.4g}, {row['high']:.4g}]"
            t.add_row(str(row["method"]), *[f"{row[r]:.4g}" for r in present], f"{row['mean']:.4g}{ci}",
                      str(row["worst"]))
        t.caption = verdict(block, present)
        t.caption_justify = "left"
        out.append(t)
    return out


def verdict(block: pd.DataFrame, records: list[str], baseline: str = BASELINE) -> str:
    """One line: the method with the lowest mean over records, its margin over the next and over the baseline,
    on how many records it is the best, and the methods no better than the linear baseline (``_linear_clause``)."""
    ranked = block.sort_values("mean", kind="stable")
    best = ranked.iloc[0]
    wins = sum(int(block.loc[block[r].idxmin(), "method"] == best["method"]) for r in records
               if block[r].notna().any())
    text = f"best: {best['method']} (mean {best['mean']:.4g}; best on {wins} of {len(records)} records)"
    shown = {best["method"]}
    if len(ranked) > 1:
        second = ranked.iloc[1]
        text += f"; next {second['method']} {second['mean']:.4g} ({second['mean'] / best['mean'] - 1:+.0%})"
        shown.add(second["method"])
    base = block[block["method"] == baseline]
    if len(base) and best["method"] != baseline:
        text += f"; {baseline} {float(base['mean'].iloc[0]):.4g}"
    return text + _linear_clause(block, shown)


def _linear_clause(block: pd.DataFrame, shown: set[str]) -> str:
    """"; ridge 2.1; no better than ridge (the linear baseline): a, b" where a linear baseline is in the block: its
    mean over records (unless ``shown`` already gives it) and the methods whose mean is not clearly below it
    (``NO_BETTER``), so the line says when the paper's method loses to a straight line."""
    found = linear_baseline(block)
    if found is None:
        return ""
    name, base = found
    text = "" if name in shown else f"; {name} {base:.4g}"
    means = block["mean"].to_numpy(dtype=float)
    others = ~block["method"].isin(LINEAR_BASELINES + NAIVE_BASELINES).to_numpy() & np.isfinite(means)
    losing = [str(m) for m, o, v in zip(block["method"], others, means) if o and v >= (1.0 - NO_BETTER) * base]
    if losing:
        text += f"; no better than {name} (the linear baseline): {', '.join(losing)}"
    return text
