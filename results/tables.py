"""Summaries over repetitions and the comparison tables printed or exported from them.

``summarize`` turns a run's long metric rows into one row per (dataset, target, mode,
window, method, split, metric) with the mean, its interval over repetitions, and the
spread (sd, median, iqr) over repetitions. Skill against the naive baseline is added
per repetition (paired) where the baseline ran.
"""

from __future__ import annotations

import html
from typing import Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.results.metrics import METRICS
from enginebench.results.stats import bootstrap_interval, t_interval

KEYS = ["dataset", "target", "mode", "window", "method", "split"]
SUMMARY_COLUMNS = KEYS + ["metric", "mean", "ci_low", "ci_high", "sd", "median", "iqr", "n_repeats", "n_failed", "interval"]
DEFAULT_METRICS = ("mae", "mape", "ppmcc", "rmae")
BASELINE = "naive-mean"
SKILL_OF = ("mae", "rmae")
FORMATS = ("term", "md", "latex", "csv", "html")


def with_skill(ok: pd.DataFrame) -> pd.DataFrame:
    """Add skill_<m> = 1 - m / m_baseline rows, paired on repetition."""
    base = ok[(ok["method"] == BASELINE) & ok["metric"].isin(SKILL_OF)]
    if base.empty:
        return ok
    keys = ["dataset", "target", "mode", "window", "split", "repetition", "metric"]
    merged = ok[ok["metric"].isin(SKILL_OF)].merge(base[keys + ["value"]], on=keys, suffixes=("", "_base"))
    merged["value"] = 1.0 - merged["value"] / merged["value_base"]
    merged["metric"] = "skill_" + merged["metric"]
    return pd.concat([ok, merged.drop(columns="value_base")], ignore_index=True)


def summarize(metrics: pd.DataFrame, interval: str = "t", level: float = 0.95, seed: int = 0) -> pd.DataFrame:
    """One row per (keys, metric): mean, interval, sd, median, iqr over repetitions."""
    if metrics.empty:
        raise DataError("no metric rows to summarise")
    failed = (metrics[metrics["status"] != "ok"]
              .drop_duplicates(KEYS[:-1] + ["repetition"])
              .groupby(KEYS[:-1]).size().rename("n_failed"))
    ok = metrics[(metrics["status"] == "ok") & (metrics["split"] != "-") & ~metrics["metric"].isin(["n", "n_segments"])]
    ok = with_skill(ok.dropna(subset=["value"]))
    rng = np.random.default_rng(seed)
    rows = []
    for key, group in ok.groupby(KEYS + ["metric"], sort=False):
        v = group["value"].to_numpy(dtype=float)
        if interval == "bootstrap":
            mean, low, high = bootstrap_interval(v, rng, level=level)
        else:
            mean, low, high = t_interval(v, level=level)
        q25, q50, q75 = np.percentile(v, [25, 50, 75])
        rows.append((*key, mean, low, high, float(np.std(v, ddof=1)) if len(v) > 1 else float("nan"),
                     q50, q75 - q25, len(v), 0, interval))
    out = pd.DataFrame(rows, columns=SUMMARY_COLUMNS)
    if not failed.empty:
        out = pd.concat([out, _all_failed_rows(out, failed, interval)], ignore_index=True)
        out = out.drop(columns="n_failed").merge(failed.reset_index(), on=KEYS[:-1], how="left")
        out["n_failed"] = out["n_failed"].fillna(0).astype(int)
        out = out[SUMMARY_COLUMNS]
    return out.sort_values(["target", "window", "split", "method", "metric"], kind="stable").reset_index(drop=True)


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
            rows.append((*key, split, metric, *[float("nan")] * 6, 0, 0, interval))
    return pd.DataFrame(rows, columns=SUMMARY_COLUMNS).astype(out.dtypes.to_dict()) if rows else out.iloc[:0]


# -- wide tables --------------------------------------------------------------------

def _fmt(x: float, digits: int = 4) -> str:
    if not np.isfinite(x):
        return "n/a"
    return f"{x:.{digits}g}"


def wide(summary: pd.DataFrame, metrics: Sequence[str] = DEFAULT_METRICS) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(cells, bold): rows = target x window x split x method, one column per metric.

    Cells read ``mean ± half-width``; ``bold`` marks the best mean of each column within
    its (target, mode, window, split) block.
    """
    present = [m for m in metrics if m in set(summary["metric"])]
    if not present:
        raise DataError(f"none of the metrics {', '.join(metrics)} is in this run")
    s = summary[summary["metric"].isin(present)].copy()
    s["cell"] = [
        _fmt(m) + ("" if not np.isfinite(h) else f" ± {_fmt(h, 2)}")
        for m, h in zip(s["mean"], (s["ci_high"] - s["ci_low"]) / 2)
    ]
    index = ["target", "mode", "window", "split", "method"]
    cells = s.pivot_table(index=index, columns="metric", values="cell", aggfunc="first", sort=False)[present]
    means = (s.pivot_table(index=index, columns="metric", values="mean", aggfunc="first", sort=False)
             .reindex(index=cells.index, columns=present))  # rows of all-failed methods are all nan
    bold = pd.DataFrame(False, index=means.index, columns=present)
    for _, block in means.groupby(level=["target", "mode", "window", "split"], sort=False):
        for m in present:
            col = block[m].dropna()
            if col.empty or len(col) < 2:
                continue
            lower = METRICS[m].lower_is_better if m in METRICS else not m.startswith("skill")
            best = col.idxmin() if lower else col.idxmax()
            bold.loc[best, m] = True
    n = s.pivot_table(index=index, values=["n_repeats", "n_failed"], aggfunc="max", sort=False).reindex(cells.index)
    cells.insert(0, "n", n["n_repeats"].astype(int).astype(str))
    bold.insert(0, "n", False)
    if (n["n_failed"] > 0).any():  # failed repetitions are excluded from the statistics: say how many
        cells.insert(1, "failed", n["n_failed"].astype(int).astype(str))
        bold.insert(1, "failed", False)
    return cells.fillna("n/a"), bold


def _header(cells: pd.DataFrame) -> list[str]:
    return list(cells.index.names) + list(cells.columns)


def _rows(cells: pd.DataFrame, bold: pd.DataFrame, mark) -> list[list[str]]:
    out = []
    for idx, row in cells.iterrows():
        idx = idx if isinstance(idx, tuple) else (idx,)
        keys = [f"{k:g}" if isinstance(k, float) else str(k) for k in idx]
        flags = bold.loc[idx if len(idx) > 1 else idx[0]]
        out.append(keys + [mark(v) if flags[c] else v for c, v in row.items()])
    return out


def interval_note(summary: pd.DataFrame) -> str:
    kind = summary["interval"].iloc[0] if len(summary) else "t"
    which = "Student-t" if kind == "t" else "bootstrap percentile"
    return f"mean ± half-width of the {which} 95% interval over repetitions (n); best per block in bold"


def to_markdown(summary: pd.DataFrame, metrics: Sequence[str] = DEFAULT_METRICS) -> str:
    cells, bold = wide(summary, metrics)
    head = _header(cells)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in _rows(cells, bold, lambda v: f"**{v}**")]
    return "\n".join(lines) + f"\n\n{interval_note(summary)}\n"


def _latex_escape(text: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"), ("±", r"$\pm$")):
        text = text.replace(a, b)
    return text


def to_latex(summary: pd.DataFrame, metrics: Sequence[str] = DEFAULT_METRICS) -> str:
    cells, bold = wide(summary, metrics)
    head = _header(cells)
    lines = [r"\begin{tabular}{" + "l" * len(cells.index.names) + "r" * len(cells.columns) + "}", r"\toprule",
             " & ".join(_latex_escape(h) for h in head) + r" \\", r"\midrule"]
    for r in _rows(cells, bold, lambda v: "\x00" + v):
        lines.append(" & ".join(r"\textbf{" + _latex_escape(c[1:]) + "}" if c.startswith("\x00") else _latex_escape(c)
                                for c in r) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", f"% {interval_note(summary)}"]
    return "\n".join(lines) + "\n"


def to_html(summary: pd.DataFrame, metrics: Sequence[str] = DEFAULT_METRICS) -> str:
    cells, bold = wide(summary, metrics)
    head = "".join(f"<th>{html.escape(h)}</th>" for h in _header(cells))
    body = "\n".join(
        "<tr>" + "".join(f"<td><b>{html.escape(c[1:])}</b></td>" if c.startswith("\x00") else f"<td>{html.escape(c)}</td>"
                         for c in r) + "</tr>"
        for r in _rows(cells, bold, lambda v: "\x00" + v)
    )
    return (f'<table class="enginebench">\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>\n'
            f"<p>{html.escape(interval_note(summary))}</p>\n")


def to_csv(summary: pd.DataFrame) -> str:
    return summary.to_csv(index=False)


def _drop_constant_levels(cells: pd.DataFrame, bold: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame, str]:
    """Move index levels with a single value into a caption line (narrow terminals)."""
    fixed = []
    for name in list(cells.index.names):
        values = cells.index.get_level_values(name).unique()
        if len(values) == 1 and cells.index.nlevels > 1:
            v = values[0]
            fixed.append(f"{name} {v:g}" if isinstance(v, float) else f"{name} {v}")
            cells, bold = cells.droplevel(name), bold.droplevel(name)
    return cells, bold, ", ".join(fixed)


def to_rich(summary: pd.DataFrame, metrics: Sequence[str] = DEFAULT_METRICS, title: str | None = None):
    """A rich Table for the terminal; levels that never change go to the title."""
    from rich.markup import escape
    from rich.table import Table

    cells, bold = wide(summary, metrics)
    cells, bold, fixed = _drop_constant_levels(cells, bold)
    cells = cells.rename(index=lambda v: escape(v) if isinstance(v, str) else v)
    bold = bold.rename(index=lambda v: escape(v) if isinstance(v, str) else v)
    title = " | ".join(t for t in (title, fixed) if t) or None
    table = Table(title=title, caption=interval_note(summary))
    for i, h in enumerate(_header(cells)):
        table.add_column(h, justify="left" if i < len(cells.index.names) else "right")
    for r in _rows(cells, bold, lambda v: f"[bold]{v}[/bold]"):
        table.add_row(*r)
    return table


def paired_tests(metrics: pd.DataFrame, metric: str = "mae") -> pd.DataFrame:
    """Each method against the best (lowest mean) of its block, paired on repetitions.

    Columns: target, mode, window, split, method, versus, mean_difference, t_pvalue,
    wilcoxon_pvalue, n_pairs. A positive difference means ``method`` is worse than ``versus``.
    """
    from enginebench.results.stats import paired_ttest, wilcoxon

    ok = metrics[(metrics["status"] == "ok") & (metrics["metric"] == metric)].dropna(subset=["value"])
    rows = []
    block_keys = ["target", "mode", "window", "split"]
    for key, block in ok.groupby(block_keys, sort=False):
        table = block.pivot_table(index="repetition", columns="method", values="value", aggfunc="first")
        if table.shape[1] < 2:
            continue
        lower = METRICS[metric].lower_is_better if metric in METRICS else True
        best = table.mean().idxmin() if lower else table.mean().idxmax()
        for method in table.columns:
            if method == best:
                continue
            pair = table[[method, best]].dropna()
            if len(pair) < 2:
                continue
            _, p_t = paired_ttest(pair[method], pair[best])
            _, p_w = wilcoxon(pair[method], pair[best])
            rows.append((*key, method, best, float((pair[method] - pair[best]).mean()), p_t, p_w, len(pair)))
    return pd.DataFrame(rows, columns=block_keys + ["method", "versus", "mean_difference", "t_pvalue",
                                                    "wilcoxon_pvalue", "n_pairs"])
