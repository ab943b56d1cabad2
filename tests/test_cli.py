"""The command line: useful help, one readable error line with exit code 2, real runs."""

from __future__ import annotations

import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli


@pytest.fixture
def runner(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    return CliRunner()


@pytest.mark.parametrize("verb", [[], ["run"], ["datasets"], ["datasets", "import"], ["methods"], ["table"], ["runs"], ["compare"], ["guard"], ["publish"], ["rank"]])
def test_help_works_for_every_verb(runner, verb):
    result = runner.invoke(cli, [*verb, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage: " in result.output


@pytest.mark.parametrize("args, message", [
    (["run", "no-such-experiment"], "error: unknown experiment 'no-such-experiment'; built-ins: "),
    (["methods", "show", "nope"], "error: unknown method 'nope'; available: "),
    (["datasets", "show", "nope"], "error: unknown dataset 'nope'; built-ins: gas-turbine-emissions"),
    (["datasets", "show", "gas-turbine-emissions"], "error: dataset 'gas-turbine-emissions' is not imported yet"),
    (["datasets", "import", "gas-turbine-emissions", "--from", "/nonexistent"],
     "error: /nonexistent: not a directory; pass the folder holding gt_2011.csv ... gt_2015.csv"),
    (["table", "latest"], "error: no runs in "),
    (["run", "missing.toml"], "error: missing.toml: experiment file not found"),
])
def test_errors_are_one_line_with_exit_code_2(runner, args, message):
    result = runner.invoke(cli, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert lines[0].startswith(message), lines[0]


def test_bad_experiment_file(runner, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('dataset = "x"\ntargets = ["y"]\nmethods = ["krls"]\nmode = "sideways"\n')
    result = runner.invoke(cli, ["run", str(bad)])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: {bad}: mode 'sideways' is not one of static, window, simulation"
    broken = tmp_path / "broken.toml"
    broken.write_text('dataset = "x\n')
    result = runner.invoke(cli, ["run", str(broken)])
    assert result.exit_code == 2 and result.output.startswith(f"error: {broken}: invalid TOML: ")


def test_run_then_table_in_every_format(runner, tmp_path, toy_parquet):
    exp = tmp_path / "exp.toml"
    exp.write_text(f'''
name = "cli-toy"
dataset = "{toy_parquet}"
targets = ["y"]
repetitions = 2
train_size = 100
[selection]
resamples = 1
[methods.naive-mean]
[methods.krls]
gamma_grid = [-2, 0, 2]
lambda_grid = [-3, -1, 2]
''')
    result = runner.invoke(cli, ["run", str(exp), "-j", "1", "-q"])
    assert result.exit_code == 0, result.output
    assert "krls" in result.output and "run " in result.output
    for fmt, marker in [("md", "| target |"), ("latex", r"\toprule"), ("html", "<table"), ("term", "krls")]:
        out = runner.invoke(cli, ["table", "latest", "--format", fmt])
        assert out.exit_code == 0 and marker in out.output, out.output
    csv_path = tmp_path / "t.csv"
    out = runner.invoke(cli, ["table", "latest", "--format", "csv", "-o", str(csv_path)])
    assert out.exit_code == 0
    frame = pd.read_csv(csv_path)
    assert {"dataset", "target", "mode", "window", "method", "split", "metric", "mean", "ci_low", "ci_high",
            "sd", "median", "iqr", "n_repeats"} <= set(frame.columns)
    assert set(frame["method"]) == {"naive-mean", "krls"}
    listed = runner.invoke(cli, ["runs", "list"])
    assert "cli-toy" in listed.output and "finished" in listed.output
    overridden = runner.invoke(cli, ["run", str(exp), "-j", "1", "-q", "--methods", "naive-mean", "--repeats", "1"])
    assert overridden.exit_code == 0, overridden.output
    assert "krls" not in overridden.output.split("run ")[0]


def test_plugin_file_adds_a_method(runner, tmp_path):
    plugin = tmp_path / "my_plugin.py"
    plugin.write_text('''
import numpy as np
from enginebench.methods.base import Method

class Median(Method):
    """Training median of the target."""
    name = "median"
    family = "baseline"
    summary = "training median"
    def fit(self, train, params, rng):
        return np.median(train.y, axis=0)
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
''')
    out = runner.invoke(cli, ["methods", "list", "--plugin", str(plugin)])
    assert out.exit_code == 0 and "median" in out.output
    bad = tmp_path / "bad_plugin.py"
    bad.write_text("raise RuntimeError('boom')\n")
    out = runner.invoke(cli, ["methods", "list", "--plugin", str(bad)])
    assert out.exit_code == 2 and out.output.strip() == f"error: plugin file {bad}: RuntimeError: boom (raised while importing it); fix the plugin"


@pytest.mark.shared_data
def test_gas_turbine_import_and_show(runner, gas_turbine_dir):
    out = runner.invoke(cli, ["datasets", "import", "gas-turbine-emissions", "--from", str(gas_turbine_dir)])
    assert out.exit_code == 0, out.output
    assert out.output.startswith("imported gas-turbine-emissions: 36733 rows in 5 segment(s)")
    shown = runner.invoke(cli, ["datasets", "show", "gas-turbine-emissions"])
    assert "published split: train: 2011, 2012, 2013; test: 2014, 2015" in shown.output
    assert "licence: CC BY 4.0" in shown.output


def test_runs_show_and_rm(runner, tmp_path, toy_parquet):
    exp = tmp_path / "exp.toml"
    exp.write_text(f'dataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 80\n'
                   '[selection]\nkind = "none"\n[methods.naive-mean]\n')
    assert runner.invoke(cli, ["run", str(exp), "-j", "1", "-q"]).exit_code == 0
    shown = runner.invoke(cli, ["runs", "show", "latest"])
    assert shown.exit_code == 0, shown.output
    assert "finished (2/2 jobs, 0 failed)" in shown.output and "naive-mean" in shown.output
    run_id = shown.output.split()[1].rstrip(":")
    gone = runner.invoke(cli, ["runs", "rm", run_id, "--yes"])
    assert gone.exit_code == 0 and gone.output.strip() == f"deleted {run_id}"
    missing = runner.invoke(cli, ["runs", "show", run_id])
    assert missing.exit_code == 2 and missing.output.startswith(f"error: no run {run_id!r}")
