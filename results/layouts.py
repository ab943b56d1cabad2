"""The papers' table layouts (docs/papers.md), built from a run's per-job metric rows, with literature rows beside them.

- ``turboshaft_moe_table``: the turboshaft-moe paper's Tables 2-3. Rows = method; columns = RMAE (%)
  over trajectories on the validation and test flights: mean +- SD, median, IQR across
  trajectories (each job's ``rmae``, ``rmae_seg_sd``, ``rmae_seg_median``,
  ``rmae_seg_iqr``), averaged over repetitions; plus diverged trajectories per repetition.
- ``egt_hybrid_table``: the egt-hybrid paper's Tables 8-9. Rows = Delta x model; MAE, MAPE, PPMCC
  on the test part, mean +- half-width of the Student-t 95% interval over repetitions.

Literature rows come from ``results/published/literature-<paper>.csv`` and are labelled
``LITERATURE``: the papers' data are confidential, so their numbers give the layout and
the order of magnitude, never a target the synthetic datasets could be compared with.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError
from enginebench.papers import PAPERS
from enginebench.results.stats import paired_pvalues, t_interval
from enginebench.results.units import axis_label

PUBLISHED = Path(__file__).resolve().parent / "published"
LEGACY_FILES = {"literature-seed000.csv": "literature-egt-hybrid.csv",
                "literature-seed003.csv": "literature-turboshaft-moe.csv"}
"""Old literature file names (papers named by seed number) -> the shipped files."""
LITERATURE = "literature (confidential data; not comparable)"
THIS_RUN = "this run"
TURBOSHAFT_MOE_ORDER = PAPERS["turboshaft-moe"].method_order
TURBOSHAFT_MOE_METRICS = {"rmae": "mean", "rmae_seg_sd": "sd", "rmae_seg_median": "median", "rmae_seg_iqr": "iqr"}
TURBOSHAFT_MOE_SPLITS = {"validation": "val", "test": "test"}
TURBOSHAFT_MOE_COLUMNS = (
    ["target", "method", "source"]
    + [f"{p}_{s}" for p in ("val", "test") for s in ("mean", "sd", "median", "iqr", "diverged", "trajectories")]
    + ["n_repeats", "n_failed"]
)
EGT_HYBRID_METRICS = ("mae", "mape", "ppmcc")
EGT_HYBRID_COLUMNS = ["target", "window", "method", "source"] + [c for m in EGT_HYBRID_METRICS for c in (m, f"{m}_ci")] + ["n_repeats"]


def is_ideal(method: str) -> bool:
    """Rows fed a signal that is not available at run time (e.g. the measured WF)."""
    return "[ideal]" in method


def read_literature(name: str) -> pd.DataFrame:
    """A literature table shipped in ``results/published`` (``#`` lines are comments)."""
    path = PUBLISHED / LEGACY_FILES.get(name, name)
    if not path.is_file():
        raise DataError(f"literature table {path} is missing from the installation; reinstall enginebench")
    return pd.read_csv(path, comment="#")


def _ok_rows(metrics: pd.DataFrame, wanted: Sequence[str], splits: Sequence[str], layout: str,
             single: Sequence[str] = ("mode", "window")) -> pd.DataFrame:
    need = {"target", "method", "split", "metric", "value", "repetition", "status"}
    missing = need - set(metrics.columns)
    if missing:
        raise DataError(f"{layout}: the metric rows lack column(s) {', '.join(sorted(missing))}; pass a run's metrics()")
    ok = metrics[(metrics["status"] == "ok") & metrics["metric"].isin(wanted) & metrics["split"].isin(splits)]
    if ok.empty:
        raise DataError(
            f"{layout}: the run has no {'/'.join(wanted[:1])} rows on the {' or '.join(splits)} part; "
            "this layout needs a finished run with those parts (a split with a validation part for turboshaft-moe)"
        )
    for key in single:
        if key in ok.columns and ok.groupby(["target", "method"])[key].nunique().max() > 1:
            raise DataError(f"{layout}: the rows mix several {key}s for one method; pass one {key} at a time")
    return ok


def _failed(metrics: pd.DataFrame, keys: list[str]) -> pd.Series:
    bad = metrics[metrics["status"] != "ok"].drop_duplicates(keys + ["repetition"])
    return bad.groupby(keys).size()


def _method_order(methods: Sequence[str], order: Sequence[str]) -> list[str]:
    known = [m for m in order if m in methods]
    return known + sorted(m for m in set(methods) if m not in order)


# -- turboshaft-moe (formerly seed 003) ----------------------------------------------------------
def turboshaft_moe_table(metrics: pd.DataFrame, literature: bool = True) -> pd.DataFrame:
    """turboshaft-moe's Tables 2-3 from a run's metric rows (concatenate several runs' rows to merge them).

    One row per (target, method): ``val_mean``/``test_mean`` (RMAE %, averaged over
    trajectories), ``_sd``, ``_median``, ``_iqr`` across trajectories, each averaged over
    repetitions; ``_diverged`` (mean count per repetition) of ``_trajectories``;
    ``n_repeats`` and ``n_failed``. Literature rows follow each target's block with
    ``source`` = LITERATURE.
    """
    ok = _ok_rows(metrics, list(TURBOSHAFT_MOE_METRICS) + ["diverged", "n_segments"], list(TURBOSHAFT_MOE_SPLITS),
                  "turboshaft-moe layout")
    means = ok.groupby(["target", "method", "split", "metric"], sort=False)["value"].mean()
    reps = ok[ok["metric"] == "rmae"].groupby(["target", "method"])["repetition"].nunique()
    failed = _failed(metrics, ["target", "method"])
    rows = []
    targets = list(dict.fromkeys(ok["target"]))
    lit = read_literature("literature-turboshaft-moe.csv") if literature else None
    for target in targets:
        methods = ok.loc[ok["target"] == target, "method"].unique()
        for method in _method_order(methods, TURBOSHAFT_MOE_ORDER):
            row = {"target": target, "method": method, "source": THIS_RUN}
            for split, prefix in TURBOSHAFT_MOE_SPLITS.items():
                for metric, suffix in {**TURBOSHAFT_MOE_METRICS, "diverged": "diverged", "n_segments": "trajectories"}.items():
                    row[f"{prefix}_{suffix}"] = float(means.get((target, method, split, metric), np.nan))
            row["n_repeats"] = int(reps.get((target, method), 0))
            row["n_failed"] = int(failed.get((target, method), 0))
            rows.append(row)
        if lit is not None:
            for r in lit[lit["target"] == target].itertuples(index=False):
                row = {"target": target, "method": r.method, "source": LITERATURE, "n_repeats": 1, "n_failed": 0}
                for prefix in ("val", "test"):
                    for suffix in ("mean", "sd", "median", "iqr"):
                        row[f"{prefix}_{suffix}"] = float(getattr(r, f"{prefix}_{suffix}"))
                    row[f"{prefix}_diverged"] = row[f"{prefix}_trajectories"] = np.nan
                rows.append(row)
    return pd.DataFrame(rows, columns=TURBOSHAFT_MOE_COLUMNS)


def turboshaft_moe_paired(metrics: pd.DataFrame, split: str = "test", metric: str = "rmae") -> pd.DataFrame:
    """Paired tests between the two best methods of each target (lowest mean ``metric`` on ``split``).

    Ideal rows are left out (they are not available at run time), as in the paper, whose
    test compares the two best run-time cascades. Pairs are repetitions with the same
    index (same seed, same training trajectories); fewer than 2 pairs gives no test.
    """
    ok = _ok_rows(metrics, [metric], [split], "turboshaft-moe paired test")
    ok = ok[~ok["method"].map(is_ideal)]
    rows = []
    for target, block in ok.groupby("target", sort=False):
        table = block.pivot_table(index="repetition", columns="method", values="value", aggfunc="first")
        if table.shape[1] < 2:
            continue
        best, second = table.mean().sort_values().index[:2]
        pair = table[[best, second]].dropna()
        row = {"target": target, "split": split, "metric": metric, "best": best, "second": second,
               "mean_difference": float((pair[second] - pair[best]).mean()) if len(pair) else np.nan,
               "t_pvalue": np.nan, "wilcoxon_pvalue": np.nan, "n_pairs": len(pair), "note": ""}
        # no test from fewer than 2 pairs or from copies (a difference that never varies): the note says why
        row["t_pvalue"], row["wilcoxon_pvalue"], row["note"] = paired_pvalues(pair[second], pair[best])
        rows.append(row)
    return pd.DataFrame(rows, columns=["target", "split", "metric", "best", "second", "mean_difference", "t_pvalue",
                                       "wilcoxon_pvalue", "n_pairs", "note"])


def _num(x: float) -> str:
    if not np.isfinite(x):
        return "n/a"
    return f"{x:.2e}" if abs(x) >= 1e4 else f"{x:.2f}"


def _best_mask(values: pd.Series, eligible: pd.Series) -> pd.Series:
    col = values[eligible & np.isfinite(values)]
    mask = pd.Series(False, index=values.index)
    if len(col) >= 2:
        mask[col.idxmin()] = True
    return mask


def turboshaft_moe_markdown(table: pd.DataFrame, paired: pd.DataFrame | None = None, dataset: str = "") -> str:
    """Markdown of ``turboshaft_moe_table``: one table per target, best run-time value per column in bold."""
    if table.empty:
        raise DataError("turboshaft-moe layout: the table is empty")
    head = ["method", "source", "val mean ± SD", "val median", "val IQR", "test mean ± SD", "test median", "test IQR",
            "diverged (val / test)", "n"]
    out = []
    for target, block in table.groupby("target", sort=False):
        ours = block["source"] == THIS_RUN
        eligible = ours & ~block["method"].map(is_ideal)
        bold = {c: _best_mask(block[c], eligible) for c in
                ("val_mean", "val_median", "val_iqr", "test_mean", "test_median", "test_iqr")}
        out.append(f"### {target}: RMAE (%) over trajectories{f' — {dataset}' if dataset else ''}\n")
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for i, r in block.iterrows():
            def cell(c: str, text: str) -> str:
                return f"**{text}**" if bold[c][i] else text

            name = f"*{r.method}*" if is_ideal(r.method) else r.method
            div = "—" if r.source != THIS_RUN else (
                f"{r.val_diverged:.3g} / {r.test_diverged:.3g} of {r.val_trajectories:.0f} / {r.test_trajectories:.0f}"
                if np.isfinite(r.val_trajectories) and np.isfinite(r.test_trajectories) else "n/a")
            out.append("| " + " | ".join([
                name, r.source,
                cell("val_mean", f"{_num(r.val_mean)} ± {_num(r.val_sd)}"), cell("val_median", _num(r.val_median)),
                cell("val_iqr", _num(r.val_iqr)),
                cell("test_mean", f"{_num(r.test_mean)} ± {_num(r.test_sd)}"), cell("test_median", _num(r.test_median)),
                cell("test_iqr", _num(r.test_iqr)), div, "—" if r.source != THIS_RUN else str(r.n_repeats),
            ]) + " |")
        out.append("")
    out.append(
        "RMAE: each trajectory's MAE divided by mean |y| over the training data, in %; mean ± SD, median and IQR across "
        "the trajectories of the validation / test flights, averaged over n repetitions; diverged: trajectories per "
        "repetition that left the model's envelope. Rows marked [ideal] (italics) are fed the measured intermediate "
        "(WF), which is NOT available at run time, and are not bold. Literature rows: turboshaft-moe paper, Tables 2-3, "
        "on confidential flight data, NOT comparable with this synthetic dataset."
    )
    if paired is not None and not paired.empty:
        out.append("")
        out.append("Paired tests between the two best run-time methods (over repetitions):")
        for p in paired.itertuples(index=False):
            if p.note:
                out.append(f"- {p.target}, {p.split} {p.metric}: {p.second} vs {p.best}: {p.note}")
            else:
                out.append(f"- {p.target}, {p.split} {p.metric}: {p.second} - {p.best} = {p.mean_difference:+.3g} "
                           f"(paired t p = {p.t_pvalue:.3g}, Wilcoxon p = {p.wilcoxon_pvalue:.3g}, n = {p.n_pairs})")
    return "\n".join(out) + "\n"


# -- egt-hybrid (formerly seed 000) --------------------------------------------------------------
def egt_hybrid_table(metrics: pd.DataFrame, literature: bool = True, split: str = "test") -> pd.DataFrame:
    """egt-hybrid's Tables 8-9: rows target x Delta x model; MAE, MAPE, PPMCC mean and 95% t half-width.

    ``<metric>_ci`` is the half-width of the Student-t 95% interval over repetitions (nan
    with one repetition). Literature rows (``source`` = LITERATURE) follow each target.
    """
    ok = _ok_rows(metrics, list(EGT_HYBRID_METRICS), [split], "egt-hybrid layout", single=("mode",))
    if "window" not in ok.columns:
        ok = ok.assign(window=0.0)
    rows = []
    lit = read_literature("literature-egt-hybrid.csv") if literature else None
    for target in dict.fromkeys(ok["target"]):
        block = ok[ok["target"] == target]
        for window in sorted(block["window"].unique()):
            wblock = block[block["window"] == window]
            for method in _method_order(wblock["method"].unique(), PAPERS["egt-hybrid"].method_order):
                mrows = wblock[wblock["method"] == method]
                row = {"target": target, "window": float(window), "method": method, "source": THIS_RUN,
                       "n_repeats": int(mrows["repetition"].nunique())}
                for m in EGT_HYBRID_METRICS:
                    v = mrows.loc[mrows["metric"] == m, "value"].dropna().to_numpy(dtype=float)
                    if v.size:
                        mean, low, high = t_interval(v)
                        row[m], row[f"{m}_ci"] = mean, (high - low) / 2
                    else:
                        row[m] = row[f"{m}_ci"] = np.nan
                rows.append(row)
        if lit is not None:
            for r in lit[lit["target"] == target].itertuples(index=False):
                rows.append({"target": target, "window": float(r.window), "method": r.method, "source": LITERATURE,
                             "n_repeats": 30, **{c: float(getattr(r, c)) for m in EGT_HYBRID_METRICS for c in (m, f"{m}_ci")}})
    return pd.DataFrame(rows, columns=EGT_HYBRID_COLUMNS)


def egt_hybrid_markdown(table: pd.DataFrame, dataset: str = "", units: Mapping[str, str] | None = None) -> str:
    """Markdown of ``egt_hybrid_table``: one table per target, rows Delta x model, cells mean ± CI.

    `units` ({target: unit}, the run's ``info["units"]``) head the MAE column and the title
    (``MAE [degC]``); without one the MAE header has no unit.
    """
    if table.empty:
        raise DataError("egt-hybrid layout: the table is empty")
    out = []
    for target, block in table.groupby("target", sort=False):
        unit = (units or {}).get(str(target), "")
        head = ["Δ [s]", "model", "source", axis_label("MAE", unit), "MAPE [%]", "PPMCC [-]", "n"]
        out.append(f"### {axis_label(str(target), unit)}{f' — {dataset}' if dataset else ''}\n")
        out.append("| " + " | ".join(head) + " |")
        out.append("|" + "---|" * len(head))
        for r in block.sort_values(["window", "source"], kind="stable").itertuples(index=False):
            cells = [f"{getattr(r, m):.3g} ± {getattr(r, m + '_ci'):.2g}" if np.isfinite(getattr(r, m + "_ci"))
                     else (f"{getattr(r, m):.3g}" if np.isfinite(getattr(r, m)) else "n/a") for m in EGT_HYBRID_METRICS]
            out.append("| " + " | ".join([f"{r.window:g}", r.method, r.source, *cells, str(r.n_repeats)]) + " |")
        out.append("")
    out.append("mean ± half-width of the Student-t 95% interval over n repetitions, test part. Literature rows: egt-hybrid "
               "paper, Tables 8-9, on confidential vessel data, NOT comparable with the synthetic dataset.")
    return "\n".join(out) + "\n"
