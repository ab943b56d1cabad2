"""Learning curves: test error against the months of training data a method was given.

The egt-hybrid paper claims the hybrid model "can be reliably used already after a few months worth
of measurements, in contrast with pure DDMs that would require at least half a year".
A learning curve checks such a claim under the experiment's own protocol: for each
amount N (in months), the training part of every split is cut to its first N months
(by the time column, from the first training sample), and the experiment's methods
run on that restricted training period and are scored on the unchanged test part,
with the experiment's repetitions, subsampling and model selection.

Rows per amount (``rows``):

* ``"proportional"`` (default): the training subsample keeps the experiment's
  sampling density, ``train_size x (rows in the first N months) / (rows in the whole
  training period)`` (at least ``MIN_TRAIN_ROWS``), so more months means more rows,
  as in a real measurement campaign; ``train_size = 0`` uses every row;
* ``"fixed"``: ``train_size`` rows for every amount (all rows while fewer exist), so
  only the coverage of operating conditions grows.

The curve is one plan over the runner: the training amount is one more job coordinate
(a problem per (target, window, split, amount), its split named ``published@3mo``, its
own ``train_size``), so the jobs are the runner's own (``jobs.run_job``), run by any of
its executors (local pool or Dask), written to one run of the store, and an interrupted
curve resumes with ``enginebench run --resume RUN`` like any run. Metric rows get the
columns ``train_months`` and ``n_train``, and their split reads ``test@3mo`` so that
``enginebench table`` keeps the amounts apart.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import pandas as pd

from enginebench import registry
from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.splits import make_splits
from enginebench.errors import SpecError
from enginebench.experiments import environment
from enginebench.experiments.engine import (
    check_protocol, check_workers, context_units, execute, load_dataset, physical_model_for, plan,
)
from enginebench.experiments.executors import check_executor
from enginebench.experiments.jobs import Context, Job, Problem
from enginebench.experiments.recorded_options import method_options
from enginebench.experiments.spec import ExperimentSpec, from_dict
from enginebench.results.run_folder import Run
from enginebench.results.stats import t_interval
from enginebench.results.store import RunStore

MONTH_S = 365.25 / 12.0 * 86400.0
"""One month of the time axis, seconds (a mean calendar month)."""
ROW_POLICIES = ("proportional", "fixed")
MIN_TRAIN_ROWS = 50
"""Fewest training rows an amount gets under the proportional policy."""
SUMMARY_FILE = "learning_curve.parquet"
PLOT_FILE = "learning_curve.png"

ProgressFn = Callable[[int, int, Job], None]


@dataclass(frozen=True)
class Amount:
    """One point of the curve: N months of training data and what they hold."""

    months: float
    train_size: int
    """Training subsample per repetition (0 = every row of the period)."""
    available_rows: dict[str, int]
    """Split name -> rows of the training part within the first N months."""
    hours: dict[str, float]
    """Split name -> logged hours of the training part within the first N months."""
    whole: bool = False
    """True when N months reach past the end of every training part (the amount is all of it)."""

    @property
    def label(self) -> str:
        """'3mo': the amount as split and part names show it."""
        return at_amount("", self.months).removeprefix("@")


def at_amount(name: str, months: float) -> str:
    """A split or part name at an amount of training data: ``("test", 3.0) -> "test@3mo"``.

    The amount travels as data (a problem's ``coordinates``, the metric rows' ``train_months``
    column); this only names it, for job keys and the stored rows' ``split``, and the summary
    finds a part's rows by naming it from their ``train_months``, never by reading a name back.
    """
    return f"{name}@{months:g}mo"


def parse_months(text: str) -> list[float]:
    """'0.5,1,2' -> [0.5, 1.0, 2.0]: positive, distinct, increasing after sorting."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise SpecError(f"--months {text!r}: give comma-separated numbers of months, e.g. 0.5,1,2,3,6") from None
    if not values or any(not math.isfinite(v) or v <= 0 for v in values):
        raise SpecError(f"--months {text!r}: every amount must be a positive number of months")
    if len(set(values)) != len(values):
        raise SpecError(f"--months {text!r}: an amount is listed twice")
    return sorted(values)


def first_months(ds: Dataset, months: float, min_rows: int = 1) -> Dataset:
    """The rows of ``ds`` within its first ``months`` months (time from its earliest sample).

    A segment cut by the boundary keeps its first part; parts shorter than
    ``min_rows`` (e.g. shorter than the evaluation window) are dropped.
    """
    if not months > 0:  # math.inf: the whole part, short pieces dropped
        raise SpecError(f"learning curve: months must be positive, got {months}")
    t = ds.frame[TIME].to_numpy(dtype=float)
    if t.size == 0:
        return ds
    keep = t < t.min() + months * MONTH_S
    cut = ds.rows(keep)
    sizes = cut.frame.groupby(SEGMENT, sort=False).size()
    short = sizes.index[sizes < min_rows]
    return cut.rows(~cut.frame[SEGMENT].isin(short).to_numpy()) if len(short) else cut


def _amount_size(policy: str, train_size: int, available: int, total: int) -> int:
    if train_size <= 0:
        return 0
    if policy == "fixed" or total == 0:
        return train_size
    return max(MIN_TRAIN_ROWS, int(round(train_size * available / total)))


@dataclass
class CurvePlan:
    """A learning curve prepared as one runner context: the sizes of its amounts and the problems of all of them."""

    spec: ExperimentSpec
    months: list[float]
    rows: str
    amounts: list[Amount]
    context: Context

    def n_jobs(self) -> int:
        return len(plan(self.context))


def _training_problems(spec: ExperimentSpec, split_name: str, train: Dataset, amount: Amount, pm: object,
                       parts: dict) -> dict[tuple[str, float, str], Problem]:
    """The problems of one split at one amount: the training part cut to its first months, the parts shared."""
    raw = RawSegments.from_dataset(train, outputs=spec.targets, internals=[])
    name = at_amount(split_name, amount.months)
    return {(target, window, name): Problem(
        train=SamplePool(raw, [target], spec.mode, window, physical_model=pm),
        parts=parts[(target, window, split_name)], train_size=amount.train_size,
        coordinates={"train_months": amount.months}, label=at_amount("", amount.months))
        for target in spec.targets for window in spec.windows}


def prepare_curve(spec: ExperimentSpec, months: Sequence[float], rows: str = "proportional") -> CurvePlan:
    """Load the data and methods once, size every amount of training data and build the runner context of the
    curve: one problem per (target, window, split, amount), split names ``published@3mo`` (fails early on bad input).
    """
    if rows not in ROW_POLICIES:
        raise SpecError(f"learning curve: rows must be one of {', '.join(ROW_POLICIES)}, got {rows!r}")
    if spec.mode == "simulation":
        raise SpecError("learning curve: simulation-mode experiments are not supported (whole trajectories "
                        "cannot be cut at a month boundary); use a static or window experiment")
    methods = {}
    for name in spec.methods:
        method = registry.get(name)(**spec.method_options.get(name, {}))
        method.check_mode(spec.mode)
        methods[name] = method
    ds, dataset_hash, spec = load_dataset(spec)
    pm = physical_model_for(ds)
    splits = make_splits(ds, **spec.split)
    min_rows = int(round(max(spec.windows) / ds.dt)) + 1
    parts = {}
    for split in splits:
        raws = {name: RawSegments.from_dataset(part, outputs=spec.targets, internals=[])
                for name, part in split.parts().items()}
        for target in spec.targets:
            for window in spec.windows:
                parts[(target, window, split.name)] = {
                    name: SamplePool(raw, [target], spec.mode, window, physical_model=pm) for name, raw in raws.items()}
    usable = {s.name: len(first_months(s.train, math.inf, min_rows)) for s in splits}
    amounts, problems = [], {}
    for m in sorted(months):
        cut = {}
        for split in splits:
            cut[split.name] = first_months(split.train, m, min_rows)
            if len(cut[split.name]) == 0:
                raise SpecError(f"learning curve: the first {m:g} month(s) of split {split.name!r} hold no usable "
                                f"training segment (need {min_rows} consecutive rows); ask for more months")
        available = {name: len(part) for name, part in cut.items()}
        hours = {name: n * ds.dt / 3600.0 for name, n in available.items()}
        size = max(_amount_size(rows, spec.train_size, available[s.name], usable[s.name]) for s in splits)
        whole = all(available[s.name] == usable[s.name] for s in splits)
        amount = Amount(months=float(m), train_size=size, available_rows=available, hours=hours, whole=whole)
        amounts.append(amount)
        for split in splits:
            problems.update(_training_problems(spec, split.name, cut.pop(split.name), amount, pm, parts))
    ctx = Context(spec=spec, dataset=ds.name, problems=problems, methods=methods, dataset_hash=dataset_hash,
                  finish=write_summary)
    check_protocol(spec, problems)
    return CurvePlan(spec=spec, months=[a.months for a in amounts], rows=rows, amounts=amounts, context=ctx)


def write_summary(run: Run) -> None:
    """Store the curve's summary table in the run (``SUMMARY_FILE``), once every job is in."""
    run.write_table(SUMMARY_FILE, summarize_curve(run.metrics()))


@dataclass
class CurveResult:
    run: Run
    amounts: list[Amount]
    n_jobs: int
    n_failed: int


def curve_config(spec: ExperimentSpec, months: Sequence[float], rows: str) -> tuple[dict, str]:
    """The run's resolved config (the experiment plus the curve settings) and its hash."""
    config = {**spec.to_dict(), "learning_curve": {"months": [float(m) for m in sorted(months)], "rows": rows,
                                                   "month_s": MONTH_S}}
    digest = hashlib.sha256(json.dumps({**config, "name": None, "description": None}, sort_keys=True,
                                       default=str).encode()).hexdigest()
    return config, digest


def curve_settings(config: dict, origin: str) -> tuple[ExperimentSpec, list[float], str, str]:
    """A stored learning-curve run's (experiment, months, rows policy, config hash), to resume it."""
    settings = config.get("learning_curve")
    try:
        months = [float(m) for m in settings["months"]]
        rows = str(settings["rows"])
    except (TypeError, KeyError, ValueError):
        raise SpecError(f"{origin}: its [learning_curve] table needs months (a list of numbers) and rows") from None
    spec = from_dict({k: v for k, v in config.items() if k != "learning_curve"}, origin=origin)
    return spec, months, rows, curve_config(spec, months, rows)[1]


def run_learning_curve(
    spec: ExperimentSpec,
    months: Sequence[float],
    store: RunStore,
    *,
    rows: str = "proportional",
    workers: int | None = None,
    plugins: tuple[str, ...] = (),
    progress: ProgressFn | None = None,
    executor: str = "local",
    scheduler: str | None = None,
) -> CurveResult:
    """Run ``spec``'s methods once per amount of training data: one plan over the runner, stored as one run.

    The run resumes like any other (``enginebench run --resume RUN``) and runs on any executor.
    """
    workers = check_workers(workers)
    check_executor(executor, scheduler)
    curve = prepare_curve(spec, months, rows)
    spec = curve.context.spec  # targets = "all" resolved
    config, digest = curve_config(spec, months, rows)
    run = store.create(f"{spec.name}-learning-curve", config, digest, environment.capture(spec.seed, workers),
                       curve.n_jobs())
    run.update_info(kind="learning-curve", dataset_hash=curve.context.dataset_hash, units=context_units(curve.context),
                    method_options=method_options(curve.context), amounts=[{"months": a.months, "train_size": a.train_size, "available_rows": a.available_rows,
                              "hours": a.hours, "whole_training_period": a.whole} for a in curve.amounts])
    result = execute(curve.context, run, workers=workers, plugins=plugins, progress=progress, executor=executor,
                     scheduler=scheduler)
    return CurveResult(run=run, amounts=curve.amounts, n_jobs=result.n_jobs, n_failed=result.n_failed)


CURVE_KEYS = ["target", "mode", "window", "method", "train_months"]


def summarize_curve(metrics: pd.DataFrame, metric: str = "mae", part: str = "test", level: float = 0.95) -> pd.DataFrame:
    """Mean and Student-t interval of ``metric`` on ``part`` per (target, window, method, months).

    Also the mean training rows per repetition (``n_train``) and the failed repetitions.
    """
    if "train_months" not in metrics.columns:
        raise SpecError("this run is not a learning curve (its rows carry no train_months); "
                        "use 'enginebench table' for ordinary runs")
    months = metrics["train_months"]
    named = months.map({m: at_amount(part, m) for m in months.dropna().unique()})  # each row's part at its amount
    scored = metrics[metrics["split"].astype(str) == named]
    ok = scored[(scored["status"] == "ok") & (scored["metric"] == metric)].dropna(subset=["value"])
    failed = (metrics[metrics["status"] != "ok"].drop_duplicates(CURVE_KEYS + ["repetition"])
              .groupby(CURVE_KEYS).size())
    rows = []
    for key, group in ok.groupby(CURVE_KEYS, sort=True):
        v = group["value"].to_numpy(dtype=float)
        mean, low, high = t_interval(v, level=level)
        rows.append((*key, float(group["n_train"].mean()), metric, mean, low, high, len(v),
                     int(failed.get(key, 0))))
    columns = [*CURVE_KEYS, "n_train", "metric", "mean", "ci_low", "ci_high", "n_repeats", "n_failed"]
    return pd.DataFrame(rows, columns=columns)


def curve_table(summary: pd.DataFrame) -> str:
    """Plain-text table: one line per (target, window, months), one column per method (mean ± half-width)."""
    if summary.empty:
        return "no finished repetitions to summarise\n"
    methods = list(dict.fromkeys(summary["method"]))
    metric = summary["metric"].iloc[0]
    head = f"{'target':<28} {'window':>6} {'months':>7} {'rows':>7}" + "".join(f" {m + ' ' + metric:>22}" for m in methods)
    lines = [head, "-" * len(head)]
    for (target, window, months), block in summary.groupby(["target", "window", "train_months"], sort=True):
        cells = []
        for m in methods:
            r = block[block["method"] == m]
            if r.empty:
                cells.append(f" {'n/a':>22}")
                continue
            r = r.iloc[0]
            half = (r["ci_high"] - r["ci_low"]) / 2
            text = f"{r['mean']:.4g}" + (f" ± {half:.2g}" if np.isfinite(half) else "") + f" (n={r['n_repeats']})"
            cells.append(f" {text:>22}")
        rows_used = block["n_train"].mean()
        lines.append(f"{target:<28} {window:>6g} {months:>7g} {rows_used:>7.0f}" + "".join(cells))
    lines.append("")
    lines.append(f"{metric} on the test part: mean ± half-width of the Student-t 95% interval over repetitions (n); "
                 "rows = training rows per repetition")
    return "\n".join(lines) + "\n"


def plot_curve(summary: pd.DataFrame, path: str | Path) -> Path | None:
    """Write the curve as a PNG (rows: targets, columns: windows); None when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.ticker import FixedLocator, NullLocator
    except ImportError:
        return None
    targets = sorted(summary["target"].unique())
    windows = sorted(summary["window"].unique())
    months = sorted(summary["train_months"].unique())
    fig, axes = plt.subplots(len(targets), len(windows), figsize=(3.8 * len(windows), 3.0 * len(targets)),
                             squeeze=False)
    for (i, target), (j, window) in ((a, b) for a in enumerate(targets) for b in enumerate(windows)):
        ax = axes[i][j]
        block = summary[(summary["target"] == target) & (summary["window"] == window)]
        for method, line in block.groupby("method", sort=False):
            line = line.sort_values("train_months")
            err = np.nan_to_num((line["ci_high"] - line["ci_low"]).to_numpy() / 2)
            ax.errorbar(line["train_months"], line["mean"], yerr=err, marker="o", capsize=3, label=method)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(FixedLocator(months))
        ax.xaxis.set_minor_locator(NullLocator())
        ax.set_xticklabels([f"{m:g}" for m in months])
        ax.set_xlabel("months of training data")
        ax.set_ylabel(f"test {block['metric'].iloc[0] if len(block) else ''}")
        ax.set_title(f"{target}, window {window:g} s", fontsize=9)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
