"""Backward elimination ranks the variables that carry the signal first."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.ranking import rank_features
from enginebench.experiments.spec import Selection
from enginebench.methods.krls import KRLS


def signal_dataset(n: int = 300) -> Dataset:
    rng = np.random.default_rng(1)
    strong, weak, noise = rng.uniform(-2, 2, (3, n))
    y = 3 * np.sin(strong) + 0.8 * weak + rng.normal(0, 0.05, n)
    frame = pd.DataFrame({"segment": "a", "time": np.arange(n, dtype=float), "noise": noise, "weak": weak,
                          "strong": strong, "y": y})
    schema = Schema((Column("noise", "input"), Column("weak", "input"), Column("strong", "input"), Column("y", "output")))
    return Dataset("signal", frame, schema, 1.0)


def test_ranking_orders_strong_weak_noise():
    train = make_samples(signal_dataset(), ["y"])
    method = KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 3))
    table = rank_features(method, train, Selection(kind="bootstrap", resamples=2), np.random.default_rng(0))
    assert list(table["variable"]) == ["strong", "weak", "noise"]
    assert list(table["rank"]) == [1, 2, 3]
    # removing the noise first barely hurts; removing 'weak' next hurts more
    assert table.loc[2, "error_after_removal"] < table.loc[1, "error_after_removal"]


def test_a_lagged_series_is_one_variable(toy):
    s = make_samples(toy, ["y"], "window", 2.0)
    groups = s.variables()
    assert list(groups) == ["u1", "u2", "y"]
    assert [s.feature_names[j] for j in groups["y"]] == ["y[t-1]", "y[t-2]"]
    sub = s.select_features(groups["u1"])
    assert sub.feature_names == ("u1[t]", "u1[t-1]", "u1[t-2]") and sub.X.shape[1] == 3


def test_rank_command_stores_rankings_in_the_run(toy_parquet, tmp_path, monkeypatch):
    from enginebench.cli.main import cli

    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    exp = tmp_path / "exp.toml"
    exp.write_text(f'''
name = "rank-toy"
dataset = "{toy_parquet}"
targets = ["y"]
mode = "window"
windows = [1]
repetitions = 1
train_size = 150
[selection]
resamples = 1
[methods.naive-mean]
[methods.krls]
gamma_grid = [-1, -1, 1]
lambda_grid = [-2, -2, 1]
''')
    runner = CliRunner()
    assert runner.invoke(cli, ["run", str(exp), "-j", "1", "-q"]).exit_code == 0
    out = runner.invoke(cli, ["rank", "latest"])
    assert out.exit_code == 0, out.output
    assert "y__w1__published__krls" in out.output
    stored = list((tmp_path / "runs").glob("*/rankings/y__w1__published__krls.parquet"))
    assert len(stored) == 1
    ranking = pd.read_parquet(stored[0])
    assert set(ranking["variable"]) == {"u1", "u2", "y"}
    bad = runner.invoke(cli, ["rank", "latest", "--methods", "sindy"])
    assert bad.exit_code == 2 and "did not run method(s) sindy" in bad.output
