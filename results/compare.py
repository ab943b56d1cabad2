"""Compare stored runs metric by metric: differences, tests, and what moved beyond its interval.

Two runs: A (the reference) and B. Several runs: every later run against the first
(``compare_many``), shown side by side (``side_by_side``) and pair by pair.

``compare_metrics`` joins the summaries of run A (the reference) and run B on (target,
mode, window, method, split, metric) and, for every row, reports

- both means with their interval over repetitions (the run's interval kind),
- the difference B - A with a Student-t 95% interval, a t-test and a rank test (paired:
  the mean of the per-repetition differences over the repetitions both runs have),
- a verdict: ``better`` or ``worse`` when B's mean lies outside A's interval (a metric
  "changed beyond its interval"; better/worse follows the metric's direction), else
  ``within``. Where A has no interval (a single repetition, or identical repetitions)
  its interval is the point ``[mean, mean]``, the same convention ``guard`` uses.

Identical repetitions are copies, not evidence: a difference that is the same on every
repetition, or two runs whose values never vary, get no interval and no test
(``test_note`` says why), never an interval of width 0 or p = 0.

Repetitions pair up when both runs drew the same training rows for repetition r: the
subsample seed depends only on (seed, repetition, split), so that holds when dataset,
variant, seed, training size, split, roles and mode agree (``pairing``). Paired rows get
the paired t-test and the Wilcoxon signed-rank test on the repetitions present in both;
unpaired rows get Welch's t-test and the Mann-Whitney U test.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.results.metrics import METRICS
from enginebench.results.stats import paired_pvalues, t_interval
from enginebench.results.summary import with_skill, summarize

__all__ = [
    "COMPARE_COLUMNS",
    "Comparison",
    "JOIN",
    "PAIRING_KEYS",
    "compare_many",
    "compare_metrics",
    "compare_runs",
    "comparison_table",
    "coverage_note",
    "lower_is_better",
    "many_csv",
    "many_text",
    "num",
    "pairing",
    "repetition_values",
    "run_labels",
    "side_by_side",
    "statements",
    "text_table",
    "welch_interval",
]

JOIN = ["target", "mode", "window", "method", "split", "metric"]
PAIRING_KEYS = ("dataset", "dataset_variant", "seed", "train_size", "split", "roles", "mode")
COMPARE_COLUMNS = JOIN + [
    "lower_is_better", "mean_a", "ci_low_a", "ci_high_a", "n_a", "mean_b", "ci_low_b", "ci_high_b", "n_b",
    "difference", "diff_low", "diff_high", "relative", "paired", "n_pairs", "t_test", "t_pvalue",
    "rank_test", "rank_pvalue", "verdict", "test_note",
]


def lower_is_better(metric: str) -> bool:
    """Direction of a metric: METRICS knows the named ones; skill_* is higher-is-better, other counts lower."""
    if metric in METRICS:
        return METRICS[metric].lower_is_better
    return not metric.startswith("skill")


def repetition_values(metrics: pd.DataFrame) -> pd.DataFrame:
    """One value per (JOIN keys, repetition): the rows ``summarize`` averages, skill included."""
    ok = metrics[(metrics["status"] == "ok") & (metrics["split"] != "-") & ~metrics["metric"].isin(["n", "n_segments"])]
    ok = with_skill(ok.dropna(subset=["value"]))
    return ok[JOIN + ["repetition", "value"]]


def pairing(config_a: dict[str, Any], config_b: dict[str, Any]) -> tuple[bool, str]:
    """Whether repetition r of run A and of run B trained on the same rows, and why (not)."""
    diffs = [k for k in PAIRING_KEYS if config_a.get(k) != config_b.get(k)]
    if not diffs:
        return True, "same dataset, seed, training size, split, roles and mode, so repetition r of both runs used the same training rows"
    return False, "; ".join(f"{k} differs ({config_a.get(k)!r} vs {config_b.get(k)!r})" for k in diffs)


def welch_interval(a: Sequence[float], b: Sequence[float], level: float = 0.95) -> tuple[float, float, float]:
    """mean(b) - mean(a) with Welch's t interval (Welch-Satterthwaite degrees of freedom).

    Two samples without spread (copies) have no interval: `(difference, nan, nan)`.
    """
    x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if x.size < 2 or y.size < 2:
        raise DataError(f"Welch's interval needs at least 2 repetitions per run, got {x.size} and {y.size}")
    diff = float(y.mean() - x.mean())
    va, vb = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    se2 = va + vb
    if se2 == 0.0:
        return diff, float("nan"), float("nan")
    df = se2**2 / (va**2 / (x.size - 1) + vb**2 / (y.size - 1))
    import scipy.special  # the Student-t quantile (scipy.stats.t.ppf) without scipy.stats' import

    half = float(scipy.special.stdtrit(df, 0.5 * (1.0 + level)) * np.sqrt(se2))
    return diff, diff - half, diff + half


def _unpaired_tests(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(Welch t p-value, Mann-Whitney U p-value); equal constant samples give 1.0, different ones no test (nan)."""
    if np.all(a == a[0]) and np.all(b == b[0]):
        if a[0] == b[0]:
            return 1.0, 1.0
        return float("nan"), float("nan")  # copies on both sides: no variance to test against
    import scipy.stats  # only where two unpaired runs are compared

    t_p = float(scipy.stats.ttest_ind(b, a, equal_var=False).pvalue)
    u_p = float(scipy.stats.mannwhitneyu(b, a, alternative="two-sided").pvalue)
    return t_p, u_p


def _test_row(a: pd.Series | None, b: pd.Series | None, paired: bool, level: float) -> tuple:
    """(difference, low, high, n_pairs, t_test, t_p, rank_test, rank_p, test_note) for one JOIN key."""
    nan = float("nan")
    if a is None or b is None:
        return nan, nan, nan, 0, "", nan, "", nan, "in one run only"
    if paired:
        both = pd.concat([a.rename("a"), b.rename("b")], axis=1, join="inner")
        if len(both) < 2:  # no test possible: report the plain difference of the means
            return (float(b.mean() - a.mean()), nan, nan, len(both), "", nan, "", nan,
                    f"only {len(both)} paired repetition(s); a paired test needs at least 2")
        d, low, high = t_interval((both["b"] - both["a"]).to_numpy(), level=level)
        t_p, w_p, note = paired_pvalues(both["b"], both["a"])
        if note:
            return d, nan, nan, len(both), "", nan, "", nan, note
        return d, low, high, len(both), "paired t", t_p, "Wilcoxon", w_p, ""
    x, y = a.to_numpy(dtype=float), b.to_numpy(dtype=float)
    if x.size < 2 or y.size < 2:
        return float(y.mean() - x.mean()), nan, nan, 0, "", nan, "", nan, "too few repetitions for a test"
    d, low, high = welch_interval(x, y, level)
    t_p, u_p = _unpaired_tests(x, y)
    if np.isnan(t_p):
        return d, nan, nan, 0, "", nan, "", nan, "identical repetitions (each run gave the same value every time): no test"
    return d, low, high, 0, "Welch t", t_p, "Mann-Whitney U", u_p, ""


def compare_metrics(
    metrics_a: pd.DataFrame,
    metrics_b: pd.DataFrame,
    *,
    paired: bool,
    interval: str = "t",
    level: float = 0.95,
    metric_names: Sequence[str] | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(table, unmatched): one COMPARE_COLUMNS row per key present in both runs, and the keys in only one.

    ``unmatched`` has the JOIN columns plus ``only_in`` ("A" or "B").
    """
    sa = summarize(metrics_a, interval=interval, level=level)
    sb = summarize(metrics_b, interval=interval, level=level)
    if metric_names:
        sa, sb = sa[sa["metric"].isin(metric_names)], sb[sb["metric"].isin(metric_names)]
        if sa.empty and sb.empty:
            raise DataError(f"none of the metrics {', '.join(metric_names)} is in either run")
    cols = ["mean", "ci_low", "ci_high", "n_repeats"]
    merged = sa[JOIN + cols].merge(sb[JOIN + cols], on=JOIN, how="outer", suffixes=("_a", "_b"), indicator=True)
    unmatched = merged[merged["_merge"] != "both"][JOIN].copy()
    unmatched["only_in"] = np.where(merged.loc[unmatched.index, "_merge"] == "left_only", "A", "B")
    merged = merged[merged["_merge"] == "both"].drop(columns="_merge").reset_index(drop=True)
    groups = []
    for frame in (metrics_a, metrics_b):
        v = repetition_values(frame)
        groups.append({k: g.set_index("repetition")["value"] for k, g in v.groupby(JOIN, sort=False)})
    tests = [_test_row(groups[0].get(k), groups[1].get(k), paired, level)
             for k in merged[JOIN].itertuples(index=False, name=None)]
    out = merged.rename(columns={"n_repeats_a": "n_a", "n_repeats_b": "n_b"})
    out = out.astype({"n_a": int, "n_b": int})  # counts (the outer merge made them floats: "n 4.0 vs 4.0")
    out["lower_is_better"] = [lower_is_better(m) for m in out["metric"]]
    test_cols = ["difference", "diff_low", "diff_high", "n_pairs", "t_test", "t_pvalue", "rank_test", "rank_pvalue",
                 "test_note"]
    out[test_cols] = pd.DataFrame(tests, columns=test_cols, index=out.index) if tests else pd.DataFrame(columns=test_cols)
    out["paired"] = paired
    mean_a = out["mean_a"].to_numpy(dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out["relative"] = np.where(mean_a != 0, out["difference"].to_numpy(dtype=float) / np.abs(mean_a), np.nan)
    low = out["ci_low_a"].fillna(out["mean_a"]).to_numpy(dtype=float)
    high = out["ci_high_a"].fillna(out["mean_a"]).to_numpy(dtype=float)
    b = out["mean_b"].to_numpy(dtype=float)
    lower = out["lower_is_better"].to_numpy(dtype=bool)
    worse = np.where(lower, b > high, b < low)
    better = np.where(lower, b < low, b > high)
    out["verdict"] = np.select([worse, better], ["worse", "better"], "within")
    return out[COMPARE_COLUMNS], unmatched.reset_index(drop=True)


@dataclass
class Comparison:
    """The result of comparing run A (reference) with run B."""

    run_a: str
    run_b: str
    table: pd.DataFrame
    unmatched: pd.DataFrame
    paired: bool
    pairing_reason: str
    notes: list[str] = field(default_factory=list)


def compare_runs(run_a, run_b, *, interval: str | None = None, metric_names: Sequence[str] | None = None) -> Comparison:
    """Compare two stored runs (``results.store.Run``); A is the reference."""
    ca, cb = run_a.config(), run_b.config()
    paired, reason = pairing(ca, cb)
    interval = interval or ca.get("interval", "t")
    table, unmatched = compare_metrics(run_a.metrics(), run_b.metrics(), paired=paired, interval=interval,
                                       metric_names=metric_names)
    notes = []
    if ca.get("dataset") != cb.get("dataset"):
        notes.append(f"the runs are on different datasets ({ca.get('dataset')} vs {cb.get('dataset')}); "
                     "rows were matched on target, mode, window, method, split and metric only")
    for run in (run_a, run_b):
        status = run.info().get("status")
        if status != "finished":
            notes.append(f"run {run.id} is {status}: its means cover only its finished jobs")
    return Comparison(run_a.id, run_b.id, table, unmatched, paired, reason, notes)


# -- text ---------------------------------------------------------------------------

def num(x: Any, digits: int = 4) -> str:
    """A number for people: ``digits`` significant digits, n/a for missing values."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return str(x)
    return f"{x:.{digits}g}" if np.isfinite(x) else "n/a"


def text_table(header: Sequence[str], rows: Sequence[Sequence[str]], right: Sequence[bool] | None = None,
               width: int | None = None, keep: int = 0) -> str:
    """A plain table fitted to ``width`` columns (the terminal's, 80 in a CI log): ``results.term.grid``; the first
    ``keep`` columns (names) are never wrapped."""
    from enginebench.results.term import grid

    return grid(header, rows, right=right, width=width, no_wrap=[i < keep for i in range(len(header))])


def _where(r) -> str:
    return f"{r.target}, {r.mode}, window {float(r.window):g} s, {r.split}"


def _pvalues(r) -> str:
    if not r.t_test:
        return r.test_note or "too few repetitions for a test"
    n = f"{r.n_pairs} pairs" if r.paired else f"n {r.n_a} vs {r.n_b}"
    return f"{r.t_test} p = {num(r.t_pvalue, 2)}, {r.rank_test} p = {num(r.rank_pvalue, 2)} ({n})"


def statements(cmp: Comparison, b: str = "B") -> list[str]:
    """Plain sentences: how the runs pair up, what changed beyond A's interval, what is in one run only.

    ``b`` is the compared run's label (C, D... when several runs are compared with A).
    """
    t = cmp.table
    tests = "paired t-test and Wilcoxon signed-rank test" if cmp.paired else "Welch t-test and Mann-Whitney U test"
    lines = [f"A = {cmp.run_a}, {b} = {cmp.run_b}; differences are {b} - A.",
             f"Repetitions {'pair up' if cmp.paired else 'do not pair up'}: {cmp.pairing_reason}; tests: {tests}."]
    lines += [f"Note: {n}." for n in cmp.notes]
    changed = t[t["verdict"] != "within"]
    if t.empty:
        lines.append("No metric row is in both runs: nothing to compare.")
    elif changed.empty:
        lines.append(f"Nothing changed beyond A's interval ({len(t)} metric rows compared).")
    else:
        lines.append(f"Changed beyond A's interval ({len(changed)} of {len(t)} metric rows):")
        for r in changed.itertuples():
            rel = f", {r.relative:+.1%}" if np.isfinite(r.relative) else ""
            lines.append(
                f"  {r.method} {r.metric} ({_where(r)}): {r.verdict} in {b}, {num(r.mean_a)} -> {num(r.mean_b)} "
                f"({r.difference:+.3g}{rel}); "
                f"A's interval [{num(r.ci_low_a)}, {num(r.ci_high_a)}]; difference 95% CI "
                f"[{num(r.diff_low, 3)}, {num(r.diff_high, 3)}]; {_pvalues(r)}"
            )
        lines.append(f"Within A's interval: {len(t) - len(changed)} of {len(t)} metric rows.")
    for side, name in (("A", cmp.run_a), ("B", cmp.run_b)):
        only = cmp.unmatched[cmp.unmatched["only_in"] == side]
        if only.empty:
            continue
        other = cmp.unmatched[cmp.unmatched["only_in"] != side]
        methods = sorted(set(only["method"]) - set(t["method"]) - set(other["method"]))
        rest = only[~only["method"].isin(methods)]
        parts = [f"method(s) {', '.join(methods)}"] if methods else []
        parts += [f"{len(rest)} other metric row(s)"] if len(rest) else []
        lines.append(f"Only in {b if side == 'B' else side} ({name}), not compared: {'; '.join(parts)}.")
    return lines


def comparison_table(cmp: Comparison, b: str = "B") -> str:
    """All compared rows as a fixed-width table; key columns that never change go to a caption line (``b``: B's label)."""
    t = cmp.table
    keys = ["target", "mode", "window", "split", "method", "metric"]
    fixed = [k for k in keys[:4] if t[k].nunique() == 1 and len(t)]
    shown = [k for k in keys if k not in fixed]
    header = shown + ["A mean [interval]", f"{b} mean [interval]", f"{b} - A [95% CI]", "p (t)", "p (rank)", "verdict"]
    rows = []
    for r in t.itertuples():
        keycells = [f"{float(getattr(r, k)):g}" if k == "window" else str(getattr(r, k)) for k in shown]
        rows.append(keycells + [
            f"{num(r.mean_a)} [{num(r.ci_low_a)}, {num(r.ci_high_a)}]",
            f"{num(r.mean_b)} [{num(r.ci_low_b)}, {num(r.ci_high_b)}]",
            f"{num(r.difference, 3)} [{num(r.diff_low, 3)}, {num(r.diff_high, 3)}]",
            num(r.t_pvalue, 2), num(r.rank_pvalue, 2), r.verdict,
        ])
    caption = ", ".join(f"{k} {float(t[k].iloc[0]):g}" if k == "window" else f"{k} {t[k].iloc[0]}" for k in fixed)
    right = [False] * len(shown) + [True] * 5 + [False]
    return (caption + "\n" if caption else "") + text_table(header, rows, right, keep=len(shown))


# -- several runs against the first ----------------------------------------------------------

def run_labels(n: int) -> list[str]:
    """Labels of ``n`` compared runs: A (the reference), B, C, ..., Z, then R27, R28..."""
    return [chr(ord("A") + i) if i < 26 else f"R{i + 1}" for i in range(n)]


def compare_many(runs: Sequence, *, interval: str | None = None,
                 metric_names: Sequence[str] | None = None) -> list[Comparison]:
    """Every later run against the first (``compare_runs(first, later)``), all with the first run's interval kind."""
    if len(runs) < 2:
        raise DataError(f"compare needs at least 2 runs, got {len(runs)}")
    interval = interval or runs[0].config().get("interval", "t")
    return [compare_runs(runs[0], other, interval=interval, metric_names=metric_names) for other in runs[1:]]


def _names(values) -> str:
    return ", ".join(sorted(map(str, values))) or "none"


def coverage_note(cmp: Comparison, b: str = "B") -> str:
    """One line: which methods and targets of ``b`` were compared with A, and what was skipped (in one run only)."""
    t, u = cmp.table, cmp.unmatched
    said = f"{b} vs A: compared {len(t)} metric row(s) of method(s) {_names(set(t['method']))} on target(s) " \
           f"{_names(set(t['target']))}"
    skipped = []
    for side, label in (("A", "A"), ("B", b)):
        only = u[u["only_in"] == side]
        methods = set(only["method"]) - set(t["method"]) - set(u.loc[u["only_in"] != side, "method"])
        targets = set(only["target"]) - set(t["target"]) - set(u.loc[u["only_in"] != side, "target"])
        rest = only[~only["method"].isin(methods) & ~only["target"].isin(targets)]
        skipped += [f"method(s) {_names(methods)} only in {label}"] if methods else []
        skipped += [f"target(s) {_names(targets)} only in {label}"] if targets else []
        skipped += [f"{len(rest)} other metric row(s) only in {label}"] if len(rest) else []
    return f"Note: {said}; skipped: {'; '.join(skipped) if skipped else 'nothing'}."


def side_by_side(comparisons: Sequence[Comparison]) -> str:
    """One row per (target, mode, window, split, method, metric) of A that a later run has, one column group per
    run: A's mean [interval], then each later run's mean [interval] and its difference from A ('-' where it lacks
    the row). Key columns that never change go to a caption line, as in ``comparison_table``."""
    labels = run_labels(len(comparisons) + 1)
    by_key: list[dict] = [{k: r for k, r in zip(c.table[JOIN].itertuples(index=False, name=None), c.table.itertuples())}
                          for c in comparisons]
    order = list(dict.fromkeys(k for found in by_key for k in found))
    keys = ["target", "mode", "window", "split", "method", "metric"]
    frame = pd.DataFrame(order, columns=JOIN)
    fixed = [k for k in keys[:4] if len(frame) and frame[k].nunique() == 1]
    shown = [k for k in keys if k not in fixed]
    header = shown + ["A mean [interval]"]
    for b in labels[1:]:
        header += [f"{b} mean [interval]", f"{b} - A"]
    rows = []
    for key in order:
        named = dict(zip(JOIN, key))
        first = next(found[key] for found in by_key if key in found)
        cells = [f"{float(named[k]):g}" if k == "window" else str(named[k]) for k in shown]
        cells.append(f"{num(first.mean_a)} [{num(first.ci_low_a)}, {num(first.ci_high_a)}]")
        for found in by_key:
            r = found.get(key)
            cells += ([f"{num(r.mean_b)} [{num(r.ci_low_b)}, {num(r.ci_high_b)}]", num(r.difference, 3)]
                      if r is not None else ["-", "-"])
        rows.append(cells)
    caption = ", ".join(f"{k} {float(frame[k].iloc[0]):g}" if k == "window" else f"{k} {frame[k].iloc[0]}"
                        for k in fixed)
    right = [False] * len(shown) + [True] * (1 + 2 * len(comparisons))
    return (caption + "\n" if caption else "") + text_table(header, rows, right, keep=len(shown))


def many_text(comparisons: Sequence[Comparison]) -> str:
    """The report of several runs against the first: who is who, a coverage note per run, the side-by-side table,
    then each run's own comparison with A (its table and statements, as for two runs)."""
    from enginebench.results.term import note_text

    labels = run_labels(len(comparisons) + 1)
    ids = [comparisons[0].run_a] + [c.run_b for c in comparisons]
    lines = ["Runs: " + ", ".join(f"{b} = {i}" for b, i in zip(labels, ids)) + "; each later run is compared with A."]
    lines += [coverage_note(c, b) for c, b in zip(comparisons, labels[1:])]
    text = note_text(lines) + "\nSide by side (mean [interval] of each run; X - A: difference of the means):\n"
    text += side_by_side(comparisons)
    for c, b in zip(comparisons, labels[1:]):
        text += f"\n{b} - A:\n" + comparison_table(c, b) + "\n" + note_text(statements(c, b))
    return text


def many_csv(comparisons: Sequence[Comparison]) -> str:
    """One CSV of every comparison's table, each row led by the two runs' ids (``run_a``, ``run_b``)."""
    frames = [c.table.assign(run_a=c.run_a, run_b=c.run_b) for c in comparisons]
    out = pd.concat(frames, ignore_index=True)
    return out[["run_a", "run_b"] + COMPARE_COLUMNS].to_csv(index=False)
