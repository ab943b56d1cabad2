"""Per-record results: each segment's RMSE/NRMSE/MAE equal direct formulas; the table over records gives each
record's mean over repetitions and the Student-t interval over records (n = records)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from enginebench.results.metrics import per_segment
from enginebench.results.records import record_frame, record_table


def test_per_segment_metrics_equal_direct_formulas():
    rng = np.random.default_rng(0)
    t = [rng.normal(size=50), rng.normal(size=30) * 3 + 1, np.full(5, 2.0)]
    p = [x + rng.normal(size=len(x)) * 0.1 for x in t]
    got = per_segment(t, p)
    for i, (a, b) in enumerate(zip(t, p)):
        assert got["rmse"][i] == pytest.approx(np.sqrt(np.mean((a - b) ** 2)), rel=1e-12)
        assert got["mae"][i] == pytest.approx(np.mean(np.abs(a - b)), rel=1e-12)
        assert got["n"][i] == len(a)
    assert got["nrmse"][1] == pytest.approx(np.sqrt(np.mean((t[1] - p[1]) ** 2)) / t[1].std(), rel=1e-12)
    assert np.isnan(got["nrmse"][2])  # a constant record has no NRMSE


def _meta(method, rep, values, status="ok"):
    return {"method": method, "repetition": rep, "window": 0.0, "status": status,
            "segments": {"test": {"ids": ["r1", "r2", "r3"],
                                  "y": {"rmse": values, "nrmse": values, "mae": values, "n": [10, 10, 10]}}}}


def test_the_table_averages_repetitions_per_record_then_summarises_over_records():
    metas = {"a0": _meta("a", 0, [1.0, 2.0, 4.0]), "a1": _meta("a", 1, [3.0, 2.0, 6.0]),
             "b0": _meta("b", 0, [0.5, 0.5, 0.8]), "bad": _meta("b", 1, [9.0, 9.0, 9.0], status="failed")}
    table = record_table(record_frame(metas), "rmse")
    a = table[table["method"] == "a"].iloc[0]
    assert [a["r1"], a["r2"], a["r3"]] == [2.0, 2.0, 5.0]
    per = np.array([2.0, 2.0, 5.0])
    half = scipy.stats.t.ppf(0.975, 2) * per.std(ddof=1) / np.sqrt(3)
    assert a["mean"] == pytest.approx(3.0) and a["low"] == pytest.approx(3.0 - half) and a["n_records"] == 3
    assert a["worst"] == "r3"
    assert table["method"].tolist() == ["b", "a"]  # best mean first; the failed job is left out
    b = table[table["method"] == "b"].iloc[0]
    assert b["r1"] == 0.5


def test_the_verdict_names_the_best_method_its_margin_and_its_wins():
    from enginebench.results.records import verdict

    metas = {"a": _meta("a", 0, [1.0, 2.0, 4.0]), "b": _meta("b", 0, [0.5, 2.5, 0.8]),
             "n": _meta("naive-mean", 0, [3.0, 3.0, 3.0])}
    table = record_table(record_frame(metas), "rmse")
    line = verdict(table, ["r1", "r2", "r3"])
    assert line == "best: b (mean 1.267; best on 2 of 3 records); next a 2.333 (+84%); naive-mean 3"
