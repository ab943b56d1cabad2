"""The comparison tables printed or exported from a run's summary: wide cells, term blocks, md, latex, csv,
html, the notes under a table, and the paired tests as sentences.

The summary itself (``summarize``, ``paired_tests``) is ``results.summary``'s job; its
names are re-exported here, so ``tables.summarize`` keeps working.

Tables never mislead: failed repetitions and diverged segments are counted in every
format; identical repetitions (copies) carry no interval (marked ‡); a Student-t
interval that crosses the metric's bound (MAE < 0, PPMCC > 1) is replaced by the
bootstrap percentile interval, which cannot cross it (marked †); the notes under a
table say what each mark and column means. Paired p-values come with their Holm
adjustment over the comparisons listed.
"""

from __future__ import annotations

import html
import shutil
import textwrap
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.results.metrics import METRICS
from enginebench.results.summary import BASELINE, CROSSED_NOTE, IDENTICAL_NOTE, bound_text
from enginebench.results.summary import paired_tests, summarize  # noqa: F401 - read as tables.summarize, tables.paired_tests
from enginebench.results.units import WINDOW, axis_label, header, metric_unit

DEFAULT_METRICS = ("mae", "mape", "ppmcc", "rmae")
SIMULATION_METRICS = ("rmse", "nrmse", "fit", "rmae")
CROSSED = "†"
IDENTICAL = "‡"
COUNT_COLUMNS = ("n", "failed", "diverged")
"""The count columns of a wide table (no unit)."""


def default_metrics(summary: pd.DataFrame) -> tuple[str, ...]:
    """The wide table's columns for the modes in `summary`: simulation runs show rmse, nrmse, fit and rmae."""
    modes = set(summary["mode"]) if len(summary) else set()
    if modes == {"simulation"}:
        return SIMULATION_METRICS
    if "simulation" in modes:
        return DEFAULT_METRICS + tuple(m for m in SIMULATION_METRICS if m not in DEFAULT_METRICS)
    return DEFAULT_METRICS


def default_paired_metric(mode: str) -> str:
    """The metric the paired tests use by default: the simulation error's rmse, else mae."""
    return "rmse" if mode == "simulation" else "mae"


# -- wide tables --------------------------------------------------------------------

def _fmt(x: float, digits: int = 4) -> str:
    if not np.isfinite(x):
        return "n/a"
    return f"{x:.{digits}g}"


def _cell(mean: float, low: float, high: float, note: str) -> str:
    """``mean ± half-width``; ``mean [low, high] †`` for a bound-crossing row; ``mean ‡`` for copies."""
    if not np.isfinite(mean):
        return "n/a"
    if note.startswith(IDENTICAL_NOTE):
        return f"{_fmt(mean)} {IDENTICAL}"
    if note.startswith(CROSSED_NOTE):
        return f"{_fmt(mean)} [{_fmt(low, 3)}, {_fmt(high, 3)}] {CROSSED}"
    if not (np.isfinite(low) and np.isfinite(high)):
        return _fmt(mean)
    return f"{_fmt(mean)} ± {_fmt((high - low) / 2, 2)}"


def wide(summary: pd.DataFrame, metrics: Sequence[str] | None = None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(cells, bold): rows = target x window x split x method, one column per metric.

    Cells read ``mean ± half-width`` (see ``_cell`` for the marked forms); ``bold`` marks
    the best mean of each column within its (target, mode, window, split) block. Columns
    ``failed`` (failed repetitions) and ``diverged`` (diverged / evaluated segments over the
    successful repetitions) appear whenever one of their counts is non-zero. `metrics`
    None: ``default_metrics(summary)``.
    """
    metrics = default_metrics(summary) if metrics is None else tuple(metrics)
    present = [m for m in metrics if m in set(summary["metric"])]
    if not present:
        raise DataError(f"none of the metrics {', '.join(metrics)} is in this run")
    s = summary[summary["metric"].isin(present)].copy()
    notes = s["note"] if "note" in s else pd.Series("", index=s.index)
    s["cell"] = [_cell(m, lo, hi, str(n)) for m, lo, hi, n in zip(s["mean"], s["ci_low"], s["ci_high"], notes.fillna(""))]
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
    count_cols = [c for c in ("n_repeats", "n_failed", "n_diverged", "n_segments") if c in s]
    n = s.pivot_table(index=index, values=count_cols, aggfunc="max", sort=False).reindex(cells.index)
    cells.insert(0, "n", n["n_repeats"].astype(int).astype(str))
    bold.insert(0, "n", False)
    at = 1
    if (n["n_failed"] > 0).any():  # failed repetitions are excluded from the statistics: say how many
        cells.insert(at, "failed", n["n_failed"].astype(int).astype(str))
        bold.insert(at, "failed", False)
        at += 1
    if "n_diverged" in n and (n["n_diverged"] > 0).any():  # diverged segments are scored, but say how many
        cells.insert(at, "diverged", [f"{int(d)}/{int(k)}" for d, k in zip(n["n_diverged"].fillna(0), n["n_segments"].fillna(0))])
        bold.insert(at, "diverged", False)
    return cells.fillna("n/a"), bold


def _common_unit(cells: pd.DataFrame, units: Mapping[str, str] | None) -> str | None:
    """The one unit of every target in `cells` ("" when unknown), or None when the targets' units differ."""
    targets = cells.index.get_level_values("target").unique() if "target" in cells.index.names else []
    found = {(units or {}).get(str(t), "") for t in targets}
    return found.pop() if len(found) == 1 else None if found else ""


def _header(cells: pd.DataFrame, units: Mapping[str, str] | None = None) -> list[str]:
    """Column names as printed: ``Delta [s]`` for the window, each metric with its unit (``mae [degC]``).

    When the targets of one table have different units, a target-unit metric reads
    ``mae [target's unit]`` and the target cells carry their unit (``_with_target_units``).
    """
    common = _common_unit(cells, units)
    names = [WINDOW if n == "window" else n for n in cells.index.names]
    return names + [_column_header(c, common) for c in cells.columns]


def _column_header(column: str, unit: str | None) -> str:
    """A wide table's column header: counts as they are, a metric with its unit (None: the targets' units differ)."""
    if column in COUNT_COLUMNS:
        return column
    if unit is None:
        return f"{column} [target's unit]" if metric_unit(column, "x") == "x" else header(column)
    return header(column, unit)


def _with_target_units(cells: pd.DataFrame, units: Mapping[str, str] | None) -> pd.DataFrame:
    """`cells` with each target named with its unit (``y [degC]``) when the table's targets have different units."""
    if "target" not in cells.index.names or _common_unit(cells, units) is not None:
        return cells
    u = units or {}
    return cells.rename(index=lambda v: axis_label(str(v), u.get(str(v), "")), level="target")


def _rows(cells: pd.DataFrame, bold: pd.DataFrame, mark) -> list[list[str]]:
    out = []
    for idx, row in cells.iterrows():
        idx = idx if isinstance(idx, tuple) else (idx,)
        keys = [f"{k:g}" if isinstance(k, float) else str(k) for k in idx]
        flags = bold.loc[idx if len(idx) > 1 else idx[0]]
        out.append(keys + [mark(v) if flags[c] else v for c, v in row.items()])
    return out


def interval_note(summary: pd.DataFrame, bold: bool = True) -> str:
    """The first note under a table: which interval the cells show, and (``bold``: where bold is drawn) that the
    best per block is in bold."""
    plain = summary[~summary["note"].fillna("").str.startswith(CROSSED_NOTE)] if "note" in summary else summary
    kind = plain["interval"].iloc[0] if len(plain) else (summary["interval"].iloc[0] if len(summary) else "t")
    which = "Student-t" if kind == "t" else "bootstrap percentile"
    best = "; best per block in bold" if bold else ""
    return f"mean ± half-width of the {which} 95% interval over repetitions (n){best}"


def table_notes(summary: pd.DataFrame, cells: pd.DataFrame, bold: bool = True) -> list[str]:
    """The notes printed under a wide table: the interval, and what every mark and extra column shown means
    (``bold``: the table draws the best per block in bold)."""
    text = cells.to_numpy().ravel().tolist()
    notes = [interval_note(summary, bold)]
    if any(CROSSED in str(c) for c in text):
        shown = [m for m in cells.columns if any(CROSSED in str(c) for c in cells[m])]
        notes.append(f"{CROSSED} the Student-t interval crosses the metric's bound "
                     f"({'; '.join(bound_text(m) for m in shown)}): mean [bootstrap percentile 95% interval] shown "
                     "instead; the csv's note keeps the t interval")
    if any(IDENTICAL in str(c) for c in text):
        notes.append(f"{IDENTICAL} identical repetitions: every repetition gave the same value (e.g. a deterministic "
                     "method on the same training rows each time, as when train_size is at least the training pool): "
                     "no interval and no paired test")
    if "failed" in cells.columns:
        notes.append("failed: repetitions that failed, left out of every statistic (their reasons: enginebench runs show RUN)")
    if "diverged" in cells.columns:
        notes.append("diverged: diverged segments / evaluated segments, summed over the successful repetitions "
                     "(their predictions are scored as they are)")
    if {"rmse", "nrmse", "fit"} & set(cells.columns):
        notes.append("rmse in the target's unit; nrmse = rmse / standard deviation of the measured output "
                     "(dimensionless); fit = 100 (1 - nrmse), in %")
    return notes + worse_than_baseline(summary) + no_better_than_linear(summary)


def worse_than_baseline(summary: pd.DataFrame) -> list[str]:
    """A note for each method whose mean error is above the training mean's (``BASELINE``) in the same block.

    The error is rmse in simulation mode and mae otherwise: a model that does worse than a
    constant is never left for the reader to spot (its settings do not suit these data).
    """
    out = []
    block_keys = ["dataset", "target", "mode", "window", "split"]
    for key, block in summary.groupby(block_keys, sort=False, dropna=False):
        metric = "rmse" if key[2] == "simulation" else "mae"
        rows = block[block["metric"] == metric]
        base = rows[rows["method"] == BASELINE]["mean"].to_numpy(dtype=float)
        if base.size != 1 or not np.isfinite(base[0]):
            continue
        means = rows["mean"].to_numpy(dtype=float)
        others = rows["method"] != BASELINE
        worse = rows[others & (means > base[0])]
        for _, r in worse.iterrows():
            out.append(f"worse than the training mean: {r['method']} ({metric} {r['mean']:.4g} vs {base[0]:.4g}; "
                       f"{r['target']}, Delta {r['window']:g} s, {r['split']}): {_why_worse(r, base[0])}")
        level = rows[others & (means <= base[0]) & (means >= (1.0 - NO_BETTER) * base[0])]
        for _, r in level.iterrows():
            out.append(f"no better than the training mean (within {100 * NO_BETTER:g} %): {r['method']} ({metric} "
                       f"{r['mean']:.4g} vs {base[0]:.4g}; {r['target']}, Delta {r['window']:g} s, {r['split']}): it "
                       "has learnt next to nothing here")
    return out


def _why_worse(row: pd.Series, base: float) -> str:
    """Why a method did worse than a constant (``base``, the mean's error): its free run diverged (and on how many
    segments); or its selected point was already no better than that on the validation blocks; or it was, and
    the model fitted on all training data does not carry over to the evaluated records; or (no selection
    score) its settings."""
    diverged = row.get("n_diverged", 0)
    if isinstance(diverged, (int, float, np.integer, np.floating)) and np.isfinite(diverged) and diverged > 0:
        return (f"its free run diverged on {int(diverged)} of {int(row.get('n_segments', 0))} test segments (left the "
                "training outputs' envelope; held there and scored): the model is unstable on these inputs")
    chosen = row.get("selected_score", np.nan)
    if isinstance(chosen, (float, np.floating)) and np.isfinite(chosen):
        if chosen >= base:
            return (f"its selected point scored {chosen:.4g} on the validation blocks, no better than the training "
                    "mean does here: no setting searched suits these data")
        return (f"its selected point scored {chosen:.4g} on the validation blocks, {row['mean']:.4g} here: fitted on "
                "all training data it does not carry over to these records (`enginebench table RUN --folds` lists "
                "every point's fold scores)")
    return "its settings do not suit these data"


NO_BETTER = 0.02
"""A method whose error is within this fraction below the training mean's (at least 0.98 x it) is flagged as no better
than it."""

LINEAR_BASELINES = ("ridge", "arx")
"""The linear baselines: ``ridge`` in static and window tables, ``arx`` in simulation tables. A method whose error is
not clearly below theirs is flagged under the table (``no_better_than_linear``): a linear model does as well."""
NAIVE_BASELINES = (BASELINE, "naive-last")
"""Constant and persistence baselines: never flagged against a linear baseline (they do not claim to learn)."""


def linear_baseline(rows: pd.DataFrame) -> tuple[str, float] | None:
    """(name, mean) of the best linear baseline among one block's rows of one metric (columns method and mean), or
    None when none has a finite mean."""
    lin = rows[rows["method"].isin(LINEAR_BASELINES)]
    means = lin["mean"].to_numpy(dtype=float)
    if not np.isfinite(means).any():
        return None
    best = int(np.argmin(np.where(np.isfinite(means), means, np.inf)))
    return str(lin["method"].iloc[best]), float(means[best])


def no_better_than_linear(summary: pd.DataFrame) -> list[str]:
    """A note for each method whose mean error is above, or within ``NO_BETTER`` below, the linear baseline's.

    The error is rmse in simulation mode and mae otherwise, as for the training mean: where a nonlinear,
    physical or hybrid model does not beat ridge (arx in simulation), a straight line explains these data as
    well, and the headline says so rather than leaving the reader to compare rows.
    """
    out = []
    block_keys = ["dataset", "target", "mode", "window", "split"]
    for key, block in summary.groupby(block_keys, sort=False, dropna=False):
        metric = "rmse" if key[2] == "simulation" else "mae"
        rows = block[block["metric"] == metric]
        found = linear_baseline(rows)
        if found is None:
            continue
        name, base = found
        means = rows["mean"].to_numpy(dtype=float)
        others = ~rows["method"].isin(LINEAR_BASELINES + NAIVE_BASELINES).to_numpy() & np.isfinite(means)
        for (_, r), other, mean in zip(rows.iterrows(), others, means):
            if not other or mean < (1.0 - NO_BETTER) * base:
                continue
            where = f"{metric} {mean:.4g} vs {base:.4g}; {r['target']}, Delta {r['window']:g} s, {r['split']}"
            if mean > base:
                out.append(f"worse than {name} (the linear baseline): {r['method']} ({where}): a linear model does "
                           "better here")
            else:
                out.append(f"no better than {name} (the linear baseline, within {100 * NO_BETTER:g} %): "
                           f"{r['method']} ({where}): a linear model does as well here")
    return out


def _labelled(summary: pd.DataFrame, metrics: Sequence[str] | None,
              units: Mapping[str, str] | None) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    """``wide`` with the printed header (units, ``Delta [s]``) and, for mixed units, targets named with theirs."""
    cells, bold = wide(summary, metrics)
    head = _header(cells, units)
    return _with_target_units(cells, units), _with_target_units(bold, units), head


def to_markdown(summary: pd.DataFrame, metrics: Sequence[str] | None = None, *,
                units: Mapping[str, str] | None = None, **_: object) -> str:
    """A markdown table with its notes; `units` ({column: unit}, the run's ``info["units"]``) label the headers."""
    cells, bold, head = _labelled(summary, metrics, units)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in _rows(cells, bold, lambda v: f"**{v}**")]
    return "\n".join(lines) + "\n\n" + "\n\n".join(table_notes(summary, cells)) + "\n"


def _latex_escape(text: str) -> str:
    for a, b in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#"), ("±", r"$\pm$"),
                 (CROSSED, r"\dag{}"), (IDENTICAL, r"\ddag{}")):
        text = text.replace(a, b)
    return text


def to_latex(summary: pd.DataFrame, metrics: Sequence[str] | None = None, *,
             units: Mapping[str, str] | None = None, **_: object) -> str:
    """A LaTeX tabular (booktabs) with the notes as comments; headers carry the units as ``to_markdown``'s."""
    cells, bold, head = _labelled(summary, metrics, units)
    lines = [r"\begin{tabular}{" + "l" * len(cells.index.names) + "r" * len(cells.columns) + "}", r"\toprule",
             " & ".join(_latex_escape(h) for h in head) + r" \\", r"\midrule"]
    for r in _rows(cells, bold, lambda v: "\x00" + v):
        lines.append(" & ".join(r"\textbf{" + _latex_escape(c[1:]) + "}" if c.startswith("\x00") else _latex_escape(c)
                                for c in r) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"] + [f"% {_latex_escape(n)}" for n in table_notes(summary, cells)]
    return "\n".join(lines) + "\n"


def to_html(summary: pd.DataFrame, metrics: Sequence[str] | None = None, *,
            units: Mapping[str, str] | None = None, **_: object) -> str:
    """An HTML table with the notes as paragraphs; headers carry the units as ``to_markdown``'s."""
    cells, bold, head_names = _labelled(summary, metrics, units)
    head = "".join(f"<th>{html.escape(h)}</th>" for h in head_names)
    body = "\n".join(
        "<tr>" + "".join(f"<td><b>{html.escape(c[1:])}</b></td>" if c.startswith("\x00") else f"<td>{html.escape(c)}</td>"
                         for c in r) + "</tr>"
        for r in _rows(cells, bold, lambda v: "\x00" + v)
    )
    notes = "".join(f"<p>{html.escape(n)}</p>\n" for n in table_notes(summary, cells))
    return f'<table class="enginebench">\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>\n' + notes


def long_table(summary: pd.DataFrame, *, units: Mapping[str, str] | None = None) -> pd.DataFrame:
    """The long summary as the csv holds it: the window column is ``Delta [s]`` as in the other formats, and
    ``unit`` (after ``metric``) is each row's metric unit ("" when unknown, e.g. mae of a run without units).
    ``enginebench.api``'s ``Run.table`` is this frame with tidier column names."""
    u = units or {}
    out = summary.rename(columns={"window": WINDOW})
    if "metric" in out.columns:
        unit = [metric_unit(str(m), u.get(str(t), "")) for m, t in zip(out["metric"], out["target"])]
        out.insert(out.columns.get_loc("metric") + 1, "unit", unit)
    return out


def to_csv(summary: pd.DataFrame, metrics: Sequence[str] | None = None, *, units: Mapping[str, str] | None = None,
           **_: object) -> str:
    """The long summary as csv, one value per cell (``long_table``): every metric of ``summary`` (``metrics`` is
    not used: a reader of the csv selects rows)."""
    return long_table(summary, units=units).to_csv(index=False)


BLOCK = ["target", "mode", "window", "split"]
"""The index levels of one terminal block (one title; methods as rows)."""


def block_title(target: str, mode: str, window: float, split: str, unit: str = "") -> str:
    """The title above one terminal block: ``y [degC] | static | Delta 0 s | test``, names never shortened."""
    return f"{axis_label(str(target), unit)} | {mode} | Delta {float(window):g} s | {split}"


def _block_table(cells: pd.DataFrame, bold: pd.DataFrame, columns: list[str], unit: str):
    """A rich Table of one block: methods as rows, the count columns and `columns` (metrics) as columns."""
    from rich import box
    from rich.markup import escape
    from rich.table import Table

    table = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, collapse_padding=True)
    table.add_column("method", no_wrap=True)  # a name is never cut: a block too wide splits its metrics instead
    counts = [c for c in cells.columns if c in COUNT_COLUMNS]
    for c in counts + columns:
        table.add_column(escape(_column_header(c, unit)), justify="right", overflow="fold")
    for method, row in cells.iterrows():
        flags = bold.loc[method]
        table.add_row(escape(str(method)), *[f"[bold]{escape(row[c])}[/bold]" if flags[c] else escape(row[c])
                                            for c in counts + columns])
    return table


def _width_of(renderable) -> int:
    from rich.console import Console
    from rich.measure import Measurement

    console = Console(width=100_000, color_system=None)
    return Measurement.get(console, console.options, renderable).maximum


def term_blocks(summary: pd.DataFrame, metrics: Sequence[str] | None = None, *,
                units: Mapping[str, str] | None = None, width: int = 80) -> list[tuple[str, object]]:
    """(title, rich Table) per (target, mode, Delta, split) block, each at most `width` columns wide.

    Methods are rows; the count columns (n, and failed and diverged when non-zero) come in
    every block, next to the numbers they qualify; the metric columns go on as many
    blocks of the same title as it takes to stay within `width` (the title then says
    ``(columns 2 of 2)``). Names are never shortened: a single metric column that still
    does not fit wraps its numbers, never a method name.
    """
    cells, bold = wide(summary, metrics)
    metric_cols = [c for c in cells.columns if c not in COUNT_COLUMNS]
    u = units or {}
    out = []
    for key, block in cells.groupby(level=BLOCK, sort=False):
        rows = block.droplevel(BLOCK)
        flags = bold.loc[block.index].droplevel(BLOCK)
        unit = u.get(str(key[0]), "")
        groups: list[list[str]] = []
        for m in metric_cols:
            if groups and _width_of(_block_table(rows, flags, groups[-1] + [m], unit)) <= width:
                groups[-1].append(m)
            else:
                groups.append([m])
        title = block_title(*key, unit=unit)
        for k, group in enumerate(groups):
            part = f" (columns {k + 1} of {len(groups)})" if len(groups) > 1 else ""
            out.append((title + part, _block_table(rows, flags, group, unit)))
    return out


def to_rich(summary: pd.DataFrame, metrics: Sequence[str] | None = None, title: str | None = None, *,
            units: Mapping[str, str] | None = None, width: int | None = None, bold: bool = True):
    """The terminal table as one rich renderable: `title`, then one titled block per (target, mode, Delta, split)
    (``term_blocks``), then the notes. `width` None: the terminal's (``shutil.get_terminal_size``). `bold`: the
    console draws styles (``Console.color_system`` is not None), so the notes may say the best is in bold."""
    from rich.console import Group
    from rich.text import Text

    width = width or shutil.get_terminal_size().columns
    cells, _ = wide(summary, metrics)
    parts: list[object] = [Text(title, style="bold")] if title else []
    for head, table in term_blocks(summary, metrics, units=units, width=width):
        parts += [Text(""), Text(head, style="bold"), table]
    parts += [Text("")] + [Text(n) for n in table_notes(summary, cells, bold)] + [Text("")]  # a gap before what follows
    return Group(*parts)


def to_term(summary: pd.DataFrame, metrics: Sequence[str] | None = None, title: str | None = None, *,
            units: Mapping[str, str] | None = None, width: int = 80, **_: object) -> str:
    """``to_rich`` as plain text, every line at most `width` characters (notes wrap at word boundaries)."""
    import io

    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, color_system=None, legacy_windows=False)
    console.print(to_rich(summary, metrics, title, units=units, width=width, bold=False))  # plain text: no bold
    return console.file.getvalue()


# -- paired tests -------------------------------------------------------------------

def paired_text(tests: pd.DataFrame, metric: str, width: int | None = None) -> str:
    """Plain sentences for the paired tests of each method against its block's best, raw and Holm p-values.

    With `width`, each sentence wraps at spaces to that many columns (continuation lines
    indented); names and numbers are never split.
    """
    if tests.empty:
        return ""
    m = int(tests["t_pvalue"].notna().sum())
    holm_text = f"; p = unadjusted p-value, Holm = adjusted for the {m} tests listed (Holm-Bonferroni)" if m > 1 else ""
    lines = [f"Paired tests on {metric} against the best method of each block (over repetitions){holm_text}:"]
    for r in tests.itertuples():
        where = f"  {r.target}, {r.mode}, Delta {float(r.window):g} s, {r.split}: {r.method} - {r.versus} = {r.mean_difference:+.4g}"
        note = getattr(r, "note", "")
        if isinstance(note, str) and note:
            lines.append(f"{where}  ({note}; n = {r.n_pairs})")
            continue
        if m > 1:
            t_holm, w_holm = getattr(r, "t_pvalue_holm", np.nan), getattr(r, "wilcoxon_pvalue_holm", np.nan)
            lines.append(f"{where}  (paired t p = {r.t_pvalue:.2g}, Holm {t_holm:.2g}; "
                         f"Wilcoxon p = {r.wilcoxon_pvalue:.2g}, Holm {w_holm:.2g}; n = {r.n_pairs})")
        else:  # a family of one test: Holm changes nothing
            lines.append(f"{where}  (paired t p = {r.t_pvalue:.2g}, Wilcoxon p = {r.wilcoxon_pvalue:.2g}, n = {r.n_pairs})")
    if width:
        lines = [textwrap.fill(x, width, subsequent_indent="      " if k else "", break_long_words=False,
                               break_on_hyphens=False) if len(x) > width else x for k, x in enumerate(lines)]
    return "\n".join(lines) + "\n"
