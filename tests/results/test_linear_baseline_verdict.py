"""A method that does not beat the linear baseline (ridge; arx in simulation) is said so, in exact words, under the
table and in the per-record verdict."""

from __future__ import annotations

import pandas as pd
import pytest

from enginebench.results import tables
from enginebench.results.records import record_frame, record_table, verdict


def _summary(rows, mode: str = "static") -> pd.DataFrame:
    metric = "rmse" if mode == "simulation" else "mae"
    return pd.DataFrame([{"dataset": "d", "target": "NOX", "mode": mode, "window": 0.0, "split": "test",
                          "method": method, "metric": metric, "mean": mean, "interval": "t"} for method, mean in rows])


def test_a_method_worse_than_ridge_is_named_under_the_table():
    summary = _summary([("naive-mean", 11.9), ("ridge", 9.839), ("krls", 12.01), ("mtl-krls", 8.0)])
    assert tables.no_better_than_linear(summary) == [
        "worse than ridge (the linear baseline): krls (mae 12.01 vs 9.839; NOX, Delta 0 s, test): a linear model "
        "does better here"]
    notes = tables.table_notes(summary, pd.DataFrame({"mae": ["x"]}))
    assert notes[-2:] == [
        "worse than the training mean: krls (mae 12.01 vs 11.9; NOX, Delta 0 s, test): its settings do not suit "
        "these data",
        "worse than ridge (the linear baseline): krls (mae 12.01 vs 9.839; NOX, Delta 0 s, test): a linear model "
        "does better here"]


@pytest.mark.parametrize("better, flagged", [(0.0, True), (0.015, True), (0.02, True), (0.025, False)])
def test_within_2_percent_of_ridge_is_no_better(better, flagged):
    """Equal to ridge or up to 2 % below it: "no better" (above it: "worse", as in the test before)."""
    mean = 10.0 * (1.0 - better)
    notes = tables.no_better_than_linear(_summary([("ridge", 10.0), ("krls", mean), ("naive-mean", 20.0)]))
    if flagged:
        assert notes == [f"no better than ridge (the linear baseline, within 2 %): krls (mae {mean:.4g} vs 10; NOX, "
                         "Delta 0 s, test): a linear model does as well here"]
    else:
        assert notes == []


def test_baselines_are_not_flagged_and_arx_is_the_simulation_tables_linear_baseline():
    static = _summary([("naive-mean", 11.9), ("naive-last", 15.0), ("ridge", 9.8)])
    assert tables.no_better_than_linear(static) == []
    assert tables.no_better_than_linear(_summary([("naive-mean", 1.0), ("krls", 2.0)])) == []  # no linear baseline
    simulation = _summary([("naive-mean", 1.0), ("arx", 0.5), ("narx", 0.6), ("nfir", 0.3)], mode="simulation")
    assert tables.no_better_than_linear(simulation) == [
        "worse than arx (the linear baseline): narx (rmse 0.6 vs 0.5; NOX, Delta 0 s, test): a linear model does "
        "better here"]


def _meta(method: str, values: list[float]) -> dict:
    return {"method": method, "repetition": 0, "window": 0.0, "status": "ok",
            "segments": {"test": {"ids": ["r1", "r2", "r3"],
                                  "y": {"rmse": values, "nrmse": values, "mae": values, "n": [10, 10, 10]}}}}


def test_the_per_record_verdict_names_ridge_and_who_does_not_beat_it():
    metas = {"k": _meta("krls", [1.0, 2.0, 4.0]), "r": _meta("ridge", [1.5, 1.5, 2.0]),
             "p": _meta("pm", [0.5, 1.0, 1.0]), "n": _meta("naive-mean", [3.0, 3.0, 3.0])}
    table = record_table(record_frame(metas), "rmse")
    assert verdict(table, ["r1", "r2", "r3"]) == (
        "best: pm (mean 0.8333; best on 3 of 3 records); next ridge 1.667 (+100%); naive-mean 3; "
        "no better than ridge (the linear baseline): krls")
    metas.pop("p")
    table = record_table(record_frame(metas), "rmse")
    assert verdict(table, ["r1", "r2", "r3"]) == (
        "best: ridge (mean 1.667; best on 2 of 3 records); next krls 2.333 (+40%); naive-mean 3; "
        "no better than ridge (the linear baseline): krls")
    metas.pop("r")
    table = record_table(record_frame(metas), "rmse")
    assert verdict(table, ["r1", "r2", "r3"]) == "best: krls (mean 2.333; best on 2 of 3 records); next naive-mean 3 (+29%); naive-mean 3"
