"""Tables that never mislead: bound-crossing intervals, identical repetitions, failed and diverged
counts in every format, Holm-adjusted p-values, the simulation defaults, and data near 1e308."""

from __future__ import annotations

import html
import io
import math
import warnings

import numpy as np
import pandas as pd
import pytest
import scipy.stats
from click.testing import CliRunner
from rich.console import Console

from enginebench.cli.main import cli
from enginebench.cli.table import paired_lines
from enginebench.datasets.io import write_dataset
from enginebench.experiments.runner import run_experiment
from enginebench.method import Method, SegmentPredictions
from enginebench.registry import register
from enginebench.results import tables
from enginebench.results.compare import compare_metrics
from enginebench.results.stats import holm
from enginebench.results.store import RunStore
from helpers import make_toy, toy_spec


def _long(values: dict[str, dict[str, list[float]]], mode: str = "static", failed: dict[str, list[int]] | None = None,
          counts: dict[str, tuple[list[float], list[float]]] | None = None) -> pd.DataFrame:
    """Stored metric rows: values[method][metric] = one value per repetition; failed[method] = failed repetitions;
    counts[method] = (diverged segments, evaluated segments) per successful repetition."""
    base = {"dataset": "d", "target": "y", "mode": mode, "window": 0.0, "family": "x"}
    rows = []
    for method, by_metric in values.items():
        for metric, vs in by_metric.items():
            rows += [{**base, "method": method, "repetition": r, "split": "test", "metric": metric, "value": v,
                      "status": "ok"} for r, v in enumerate(vs)]
    for method, reps in (failed or {}).items():
        rows += [{**base, "method": method, "repetition": r, "split": "-", "metric": "failed", "value": np.nan,
                  "status": "failed"} for r in reps]
    for method, (diverged, segments) in (counts or {}).items():
        for metric, vs in (("diverged", diverged), ("n_segments", segments)):
            rows += [{**base, "method": method, "repetition": r, "split": "test", "metric": metric, "value": v,
                      "status": "ok"} for r, v in enumerate(vs)]
    return pd.DataFrame(rows)


def _rich_text(summary: pd.DataFrame, metrics=None) -> str:
    console = Console(file=io.StringIO(), width=250, color_system=None)
    console.print(tables.to_rich(summary, metrics))
    return console.file.getvalue()


def _every_format(summary: pd.DataFrame, metrics=None) -> dict[str, str]:
    """The wide formats as a reader sees them (HTML entities decoded)."""
    return {"md": tables.to_markdown(summary, metrics), "latex": tables.to_latex(summary, metrics),
            "html": html.unescape(tables.to_html(summary, metrics)), "term": _rich_text(summary, metrics)}


# ----------------------------------------------------------------- intervals across a metric's bound
RUNAWAY = {"mae": [5.0, 6.0, 4.0, 5000.0], "ppmcc": [0.9, 0.95, -0.5, 0.92], "mape": [1.0, 1.2, 0.9, 1.1],
           "rmae": [2.0, 2.1, 1.9, 2.05]}
GOOD = {"mae": [1.0, 1.1, 0.9, 1.05], "ppmcc": [0.99, 0.98, 0.985, 0.99], "mape": [0.5, 0.6, 0.4, 0.55],
        "rmae": [1.0, 1.1, 0.9, 1.0]}


def test_an_interval_crossing_its_bound_is_replaced_by_the_bootstrap_and_flagged_in_every_format():
    summary = tables.summarize(_long({"runaway": RUNAWAY, "good": GOOD}))
    row = summary[(summary["method"] == "runaway") & (summary["metric"] == "mae")].iloc[0]
    v = np.array(RUNAWAY["mae"])
    half = scipy.stats.t.ppf(0.975, 3) * v.std(ddof=1) / 2
    assert v.mean() - half < 0  # the t interval would say MAE may be negative
    assert row["interval"] == "bootstrap" and min(v) <= row["ci_low"] <= row["mean"] <= row["ci_high"] <= max(v)
    assert row["note"] == (f"interval crosses the metric's bound (mae >= 0): the Student-t interval "
                           f"[{v.mean() - half:.4g}, {v.mean() + half:.4g}] is replaced by the bootstrap percentile interval")
    ppmcc = summary[(summary["method"] == "runaway") & (summary["metric"] == "ppmcc")].iloc[0]
    assert ppmcc["interval"] == "bootstrap" and -1 <= ppmcc["ci_low"] and ppmcc["ci_high"] <= 1
    assert ppmcc["note"].startswith("interval crosses the metric's bound (ppmcc lies in [-1, 1])")
    fine = summary[summary["method"] == "good"]
    assert (fine["interval"] == "t").all() and (fine["note"] == "").all()
    note = "† the Student-t interval crosses the metric's bound (mae >= 0; ppmcc lies in [-1, 1])"
    for fmt, text in _every_format(summary).items():
        flat = " ".join(text.split())
        mark = r"\dag{}" if fmt == "latex" else "†"
        runaway = next(line for line in text.splitlines() if "runaway" in line)
        assert runaway.count(mark) == 2, fmt  # mae and ppmcc
        assert " ".join(note.split()).replace("†", mark) in flat.replace("$", ""), fmt
        good = next(line for line in text.splitlines() if "good" in line)
        assert mark not in good, fmt
    md_row = next(line for line in tables.to_markdown(summary).splitlines() if "| runaway |" in line)
    cells = [c.strip() for c in md_row.strip("|").split("|")]
    assert cells[6] == f"{row['mean']:.4g} [{row['ci_low']:.3g}, {row['ci_high']:.3g}] †"  # mae
    assert "interval crosses the metric's bound (mae >= 0)" in tables.to_csv(summary)


# ----------------------------------------------------------------- identical repetitions
def test_identical_repetitions_carry_no_interval_and_no_test_anywhere():
    frame = _long({"naive-mean": {"mae": [0.1719, 0.1719]}, "krls": {"mae": [0.0512, 0.0512]}})
    summary = tables.summarize(frame)
    assert summary["ci_low"].isna().all() and summary["ci_high"].isna().all()
    assert (summary["note"] == "identical repetitions: every repetition gave the same value, so there is no interval "
                               "(n = 2)").all()
    for fmt, text in _every_format(summary, ["mae"]).items():
        assert "± 0" not in text and "±0" not in text, fmt
        assert ("\\ddag{}" if fmt == "latex" else "‡") in text and "identical repetitions" in text, fmt
    assert "| 0.1719 ‡ |" in tables.to_markdown(summary, ["mae"])
    tests = tables.paired_tests(frame, "mae")
    assert tests["t_pvalue"].isna().all() and tests["wilcoxon_pvalue"].isna().all()
    assert tests["note"].iloc[0] == "identical repetitions (each side gave the same value every time): no test"
    text = paired_lines(tests, "mae")
    assert "p = 0" not in text and "identical repetitions" in text and "n = 2" in text
    # comparing two runs made of copies: a difference, but no interval of width 0 and no p = 0
    other = _long({"naive-mean": {"mae": [0.2, 0.2]}, "krls": {"mae": [0.0512, 0.0512]}})
    for paired in (True, False):
        table, _ = compare_metrics(frame, other, paired=paired)
        row = table[table["method"] == "naive-mean"].iloc[0]
        assert row["difference"] == pytest.approx(0.2 - 0.1719)
        assert math.isnan(row["diff_low"]) and math.isnan(row["t_pvalue"]) and "no test" in row["test_note"]


# ----------------------------------------------------------------- failed and diverged counts
def test_failed_and_diverged_counts_appear_in_every_format_and_simulation_defaults():
    sim = {"rmse": [1.0, 1.2, 0.9], "nrmse": [0.5, 0.6, 0.45], "fit": [50.0, 40.0, 55.0], "rmae": [3.0, 3.5, 2.9],
           "mae": [0.8, 0.9, 0.7]}
    naive = {"rmse": [2.0, 2.1, 1.9, 2.05], "nrmse": [1.0, 1.05, 0.95, 1.02], "fit": [0.0, -5.0, 5.0, -2.0],
             "rmae": [9.0, 9.5, 8.5, 9.1], "mae": [1.5, 1.6, 1.4, 1.5]}
    frame = _long({"sim": sim, "naive-mean": naive}, mode="simulation", failed={"sim": [3]},
                  counts={"sim": ([1, 0, 2], [4, 4, 4]), "naive-mean": ([0] * 4, [4] * 4)})
    summary = tables.summarize(frame)
    row = summary[(summary["method"] == "sim") & (summary["metric"] == "rmse")].iloc[0]
    assert (row["n_failed"], row["n_diverged"], row["n_segments"], row["n_repeats"]) == (1, 3, 12, 3)
    assert tables.default_metrics(summary) == ("rmse", "nrmse", "fit", "rmae")
    md = tables.to_markdown(summary)
    assert md.splitlines()[0] == "| target | mode | Delta [s] | split | method | n | failed | diverged | rmse | nrmse [-] | fit [%] | rmae [%] |"
    for fmt, text in _every_format(summary).items():
        line = next(x for x in text.splitlines() if "sim" in x and "simulation" not in x.replace("sim ", "")
                    or "| sim |" in x or "<td>sim</td>" in x or " sim " in x)
        assert "3/12" in line and "0/16" in text, fmt
        flat = " ".join(text.split())
        assert "diverged: diverged segments / evaluated segments, summed over the successful repetitions" in flat, fmt
        assert "failed: repetitions that failed, left out of every statistic" in flat, fmt
        assert "nrmse = rmse / standard deviation of the measured output (dimensionless); fit = 100 (1 - nrmse), in" in flat
    csv = pd.read_csv(io.StringIO(tables.to_csv(summary)))
    assert set(csv[csv["method"] == "sim"]["n_diverged"]) == {3} and set(csv[csv["method"] == "sim"]["n_failed"]) == {1}
    # no divergence and no failure: neither column, and static runs keep their defaults
    quiet = tables.summarize(_long({"good": GOOD, "other": RUNAWAY}, counts={"good": ([0] * 4, [2] * 4)}))
    assert tables.to_markdown(quiet).splitlines()[0] == "| target | mode | Delta [s] | split | method | n | mae | mape [%] | ppmcc [-] | rmae [%] |"


# ----------------------------------------------------------------- Holm
def test_paired_p_values_come_with_their_holm_adjustment():
    rng = np.random.default_rng(5)
    base = rng.normal(1.0, 0.1, 8)
    frame = _long({"best": {"mae": list(base)}, "a": {"mae": list(base + 0.05 + rng.normal(0, 0.05, 8))},
                   "b": {"mae": list(base + 0.02 + rng.normal(0, 0.05, 8))}, "c": {"mae": list(base + rng.normal(0, 0.1, 8))}})
    tests = tables.paired_tests(frame, "mae")
    assert len(tests) == 3 and tests["versus"].nunique() == 1
    p = tests["t_pvalue"].to_numpy()
    order = np.argsort(p)
    ref = np.maximum.accumulate(np.minimum(1, (3 - np.arange(3)) * p[order]))
    np.testing.assert_allclose(tests["t_pvalue_holm"].to_numpy()[order], ref)
    np.testing.assert_allclose(tests["wilcoxon_pvalue_holm"], holm(tests["wilcoxon_pvalue"]))
    text = paired_lines(tests, "mae")
    assert text.splitlines()[0].endswith("p = unadjusted p-value, Holm = adjusted for the 3 tests listed (Holm-Bonferroni):")
    r = tests.iloc[0]
    assert f"paired t p = {r.t_pvalue:.2g}, Holm {r.t_pvalue_holm:.2g}; Wilcoxon p = {r.wilcoxon_pvalue:.2g}" in text


# ----------------------------------------------------------------- non-finite stored values
@pytest.mark.filterwarnings("error")
def test_infinite_values_stored_by_older_versions_leave_the_table_readable():
    frame = _long({"m": {"rmse": [1.0, np.inf, 2.0], "mae": [1e307, 1.7e308, 1.6e308]}, "naive-mean": {"rmse": [3.0] * 3,
                                                                                              "mae": [0.0, 1.0, 2.0]}})
    summary = tables.summarize(frame)
    row = summary[(summary["method"] == "m") & (summary["metric"] == "rmse")].iloc[0]
    assert row["n_repeats"] == 2 and row["mean"] == 1.5
    big = summary[(summary["method"] == "m") & (summary["metric"] == "mae")].iloc[0]
    assert math.isfinite(big["mean"]) and big["n_repeats"] == 3
    assert "| m |" in tables.to_markdown(summary, ["mae", "rmse"])
    # skill against a baseline whose error is 0 is undefined: left out, no division warning
    assert not (summary["metric"] == "skill_mae").any() or summary["n_repeats"].min() >= 0


# ----------------------------------------------------------------- end to end
@register
class HonestScaled(Method):
    """A static model whose predictions follow an input: finite, correlated, never exact."""

    name = "test-honest-scaled"
    family = "data-driven"

    def fit(self, train, params, rng):
        y = train.y[:, 0]
        x = train.X[:, 0]
        slope = np.cov(x, y / 1e300)[0, 1] / np.var(x, ddof=1) * 1e300
        return float(np.mean(y / 1e300) * 1e300), float(slope), float(np.mean(x))

    def predict(self, fitted, data):
        mean, slope, xm = fitted
        return [(mean + slope * (s.X[:, :1] - xm)) for s in data.segments]


def test_a_target_near_1e300_runs_without_warnings_and_every_table_reads_it(tmp_path, monkeypatch):
    ds = make_toy()
    frame = ds.frame.copy()
    frame["y"] = frame["y"] * 1e300
    path = write_dataset(ds.with_frame(frame), tmp_path / "big.parquet")
    spec = toy_spec(path, repetitions=2, methods={"naive-mean": {}, "test-honest-scaled": {}})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning anywhere in metrics or summaries fails the job or the test
        result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
        assert result.n_failed == 0
        metrics = result.run.metrics()
        values = metrics[metrics["split"] == "test"]
        assert not np.isinf(values["value"].to_numpy(dtype=float)).any()
        mae = values[(values["metric"] == "mae") & (values["method"] == "naive-mean")]["value"]
        assert (mae > 1e299).all() and np.isfinite(mae).all()
        summary = tables.summarize(metrics)
        tables.to_markdown(summary)
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    for fmt in ("term", "md", "latex", "csv", "html"):
        out = CliRunner().invoke(cli, ["table", result.run.id, "--format", fmt])
        assert out.exit_code == 0 and "Warning" not in out.output, (fmt, out.output)


@register
class Runaway(Method):
    """A simulator that diverges on the second test segment of every odd repetition, wildly."""

    name = "test-runaway"
    family = "data-driven"
    modes = frozenset({"simulation"})

    def fit(self, train, params, rng):
        return float(train.y.mean()), int(rng.integers(0, 2))

    def predict(self, fitted, data):
        mean, wild = fitted
        arrays = [np.full((len(s.rows), 1), mean + (1e4 * k * wild)) for k, s in enumerate(data.segments)]
        return SegmentPredictions(arrays, [bool(wild and k == 1) for k in range(len(arrays))])


def test_the_terminal_table_of_a_diverging_simulation_shows_the_count(tmp_path, monkeypatch):
    ds = make_toy(n=40)
    ds = ds.with_frame(ds.frame, published_split={"train": ["s0", "s1"], "test": ["s2", "s3"]})
    path = write_dataset(ds, tmp_path / "sim.parquet")
    spec = toy_spec(path, mode="simulation", repetitions=4, train_size=0,
                    methods={"naive-mean": {}, "test-runaway": {}})
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    counts = run.metrics()
    wild = counts[(counts["method"] == "test-runaway") & (counts["metric"] == "diverged")]["value"].sum()
    assert wild >= 1
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    monkeypatch.setenv("COLUMNS", "200")  # rich's terminal width
    out = CliRunner().invoke(cli, ["table", run.id])
    assert out.exit_code == 0, out.output
    line = next(x for x in out.output.splitlines() if "test-runaway" in x)
    assert f"{int(wild)}/8" in line and "rmse" in out.output and "nrmse" in out.output and "fit" in out.output


@pytest.mark.parametrize("better, flagged", [(0.0, True), (0.015, True), (0.02, True), (0.025, False), (0.1, False)])
def test_a_method_within_2_percent_of_the_training_mean_is_flagged_as_no_better(better, flagged):
    """Flagged when its error is at least 0.98 x the training mean's: 1.5 % better is flagged, 2.5 % better is not."""
    summary = pd.DataFrame([{"dataset": "d", "target": "y", "mode": "simulation", "window": 0.0, "split": "test",
                             "method": method, "metric": "rmse", "mean": mean}
                            for method, mean in ((tables.BASELINE, 2.0), ("arx", 2.0 * (1.0 - better)))])
    notes = tables.worse_than_baseline(summary)
    if flagged:
        assert notes == [f"no better than the training mean (within 2 %): arx (rmse {2.0 * (1.0 - better):.4g} vs 2; "
                         "y, Delta 0 s, test): it has learnt next to nothing here"]
    else:
        assert notes == []
