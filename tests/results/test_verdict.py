"""The verdict a report opens on: winner, margin over the best baseline with its paired test (Holm), whether anything
beats the training mean, failed jobs and warnings; in exact words, and at the top of both report pages."""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd
import pytest
import scipy.stats

from enginebench.results import tables
from enginebench.results.verdict import verdicts
from helpers import make_toy

VALUES = {"naive-mean": ("baseline", [2.0, 2.2, 2.1, 2.3]), "ridge": ("baseline", [1.0, 1.1, 0.9, 1.2]),
          "krls": ("data-driven", [0.80, 0.95, 0.85, 1.0]), "pm": ("physical", [2.5, 2.4, 2.6, 2.2])}


def _raw(values: dict[str, tuple[str, list[float]]], target: str = "t_cat") -> pd.DataFrame:
    return pd.DataFrame([{"dataset": "d", "target": target, "mode": "static", "window": 0.0, "method": method,
                          "family": family, "repetition": r, "split": "test", "metric": "mae", "value": x,
                          "status": "ok"} for method, (family, v) in values.items() for r, x in enumerate(v)])


def _verdicts(raw: pd.DataFrame, metas=None):
    return verdicts(raw, tables.summarize(raw), tables.paired_tests(raw, "mae"), "mae", metas)


def test_the_winner_its_margin_over_the_best_baseline_the_paired_test_and_the_counts():
    metas = [{"target": "t_cat", "window": 0.0, "status": "ok", "warnings": ["krls: gamma at the edge", "x"]},
             {"target": "t_cat", "window": 0.0, "status": "failed", "reason": "boom"},
             {"target": "(all targets)", "window": 0.0, "status": "ok", "warnings": ["joint: one"]},
             {"target": "t_cat", "window": 5.0, "status": "failed"}]  # another window: not this block's
    [v] = _verdicts(_raw(VALUES), metas)
    assert (v.winner, v.versus) == ("krls", "ridge")
    assert v.t_pvalue == pytest.approx(scipy.stats.ttest_rel(VALUES["ridge"][1], VALUES["krls"][1]).pvalue)
    assert v.text() == ("t_cat: krls best (mae 0.9), 14 % below ridge (paired t p = 0.024, Holm 0.024); "
                        "2 of 3 methods beat the training mean; 1 failed job, 3 warnings")


def test_holm_is_the_tables_adjustment_over_every_test_listed():
    values = dict(VALUES, ridge=("baseline", [0.99, 1.0, 0.98, 1.03]),  # ridge now close to krls
                  pm=("physical", [2.5, 0.7, 3.0, 1.2]))  # and pm's test the weakest: ridge's is adjusted upwards
    raw = _raw(values)
    [v] = _verdicts(raw)
    tests = tables.paired_tests(raw, "mae")
    row = tests[(tests["method"] == "ridge") & (tests["versus"] == "krls")].iloc[0]
    assert v.t_pvalue_holm == row["t_pvalue_holm"] and v.t_pvalue_holm > v.t_pvalue  # adjusted, as in the table
    assert v.text().startswith(f"t_cat: krls best (mae 0.9), {100 * (1 - 0.9 / 1.0):.1f} % below ridge "
                               f"(paired t p = {row['t_pvalue']:.2g}, Holm {row['t_pvalue_holm']:.2g}); ")
    assert v.text() == ("t_cat: krls best (mae 0.9), 10.0 % below ridge (paired t p = 0.073, Holm 0.15); "
                        "3 of 3 methods beat the training mean; 0 failed jobs, 0 warnings")


def test_one_repetition_has_no_paired_test():
    one = {k: (f, v[:1]) for k, (f, v) in VALUES.items()}
    [v] = _verdicts(_raw(one))
    assert v.text() == ("t_cat: krls best (mae 0.8), 20 % below ridge (n = 1: no paired test); "
                        "2 of 3 methods beat the training mean; 0 failed jobs, 0 warnings")


def test_a_baseline_that_wins_is_said_so_with_the_best_other_method_above_it():
    values = {"naive-mean": VALUES["naive-mean"], "ridge": VALUES["ridge"], "pm": VALUES["pm"],
              "krls": ("data-driven", [1.5, 1.7, 1.4, 1.6])}
    [v] = _verdicts(_raw(values))
    assert v.winner_is_baseline and v.versus == "krls"
    p = scipy.stats.ttest_rel(values["krls"][1], VALUES["ridge"][1]).pvalue
    assert v.text().startswith(f"t_cat: ridge (a baseline) best (mae 1.05); the best other method, krls, is 48 % "
                               f"above it (paired t p = {p:.2g}, Holm ")
    assert "; 2 of 3 methods beat the training mean; " in v.text()


def test_nothing_beats_the_training_mean():
    values = {"naive-mean": VALUES["naive-mean"], "pm": VALUES["pm"]}
    [v] = _verdicts(_raw(values))
    assert v.text().startswith("t_cat: naive-mean (a baseline) best (mae 2.15); the best other method, pm, is 13 % "
                               "above it (")
    assert "; 0 of 1 method beat the training mean; " in v.text()


def test_one_verdict_per_target_and_only_on_the_test_part():
    raw = pd.concat([_raw(VALUES), _raw(VALUES, target="nox")], ignore_index=True)
    validation = _raw(VALUES).assign(split="validation")
    found = _verdicts(pd.concat([raw, validation], ignore_index=True))
    assert [v.target for v in found] == ["nox", "t_cat"] or [v.target for v in found] == ["t_cat", "nox"]
    assert all(v.split == "test" for v in found)


def test_a_window_run_names_every_window_delta_0_too():
    raw = pd.concat([_raw(VALUES).assign(mode="window", window=w) for w in (0.0, 30.0)], ignore_index=True)
    found = sorted(_verdicts(raw), key=lambda v: v.window)
    assert [v.text().split(":")[0] for v in found] == ["t_cat, Delta 0 s", "t_cat, Delta 30 s"]
    assert _verdicts(_raw(VALUES))[0].text().startswith("t_cat: ")  # static mode: no window to name


# -- on a real run, at the top of the reports ------------------------------------------

@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    root = tmp_path_factory.mktemp("verdict")
    data = write_dataset(make_toy(), root / "toy.parquet")
    raw = {"name": "toy-verdict", "dataset": str(data), "targets": ["y"], "repetitions": 3, "seed": 3,
           "train_size": 120, "selection": {"kind": "bootstrap", "resamples": 2},
           "methods": {"naive-mean": {}, "ridge": {}, "krls": {"gamma_grid": [-2, 0, 3], "lambda_grid": [-3, -1, 3]}}}
    return run_experiment(from_dict(raw, origin="test"), RunStore(root / "runs"), workers=1).run


def _expected_line(run) -> str:
    raw = run.metrics()
    [v] = verdicts(raw, tables.summarize(raw), tables.paired_tests(raw, "mae"), "mae", run.job_metas().values())
    summary = tables.summarize(raw)
    mae = summary[(summary["metric"] == "mae") & (summary["split"] == "test")].set_index("method")["mean"]
    assert v.winner == mae.idxmin()  # the known winner: the lowest mean mae
    assert v.text().startswith(f"y: {mae.idxmin()} ")
    n_warnings = sum(len(m.get("warnings") or []) for m in run.job_metas().values())
    assert v.text().endswith(f"0 failed jobs, {n_warnings} warning{'s' * (n_warnings != 1)}")
    return v.text()


def _top(page: str) -> str:
    """The page between its title and its first table."""
    assert "<h1>" in page and "<table" in page
    return page[page.index("<h1>"):page.index("<table")]


def test_the_static_report_opens_on_the_verdict(run, tmp_path):
    import html

    from enginebench.reports.static import write_report

    result = write_report(run, tmp_path / "rep", figures=False)
    page = result.index.read_text()
    top = _top(page)
    assert html.escape(_expected_line(run)) in top
    assert top.index("Verdict") < top.index("experiment <b>")  # right after the title
    assert len(re.findall(r'<section id="verdict">', page)) == 1


def test_the_interactive_report_opens_on_the_verdict(run, tmp_path):
    import html

    pytest.importorskip("plotly", reason="plotly is the optional extra 'report'")
    from enginebench.reports.interactive import write_interactive_report

    result = write_interactive_report(run, Path(tmp_path) / "report.html", figures=False)
    page = result.path.read_text()
    assert html.escape(_expected_line(run)) in _top(page[page.index("<body>"):])


def test_table_prints_the_same_verdict_at_its_end(run):
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    out = CliRunner().invoke(cli, ["table", str(run.path), "--width", "400"])
    assert out.exit_code == 0, out.output
    lines = out.output.rstrip().splitlines()
    assert lines[-2:] == ["Verdict (lowest mean mae on the test part; margin over the best baseline):",
                          "  " + _expected_line(run)]
