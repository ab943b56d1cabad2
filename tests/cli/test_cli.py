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
    assert {"dataset", "target", "mode", "Delta [s]", "method", "split", "metric", "mean", "ci_low", "ci_high",
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
from enginebench.method import Method

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


NOISY_PLUGIN = '''
import warnings
import numpy as np
from enginebench.method import Method

class Warner(Method):
    """Training mean, with a warning."""
    name = "warner"
    family = "baseline"
    def fit(self, train, params, rng):
        warnings.warn("careful with this one")
        return np.mean(train.y, axis=0)
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]

class Breaker(Warner):
    """Always fails."""
    name = "breaker"
    def fit(self, train, params, rng):
        raise ValueError("boom " + "x" * 250)
'''


def _run_with_plugin(runner, tmp_path, toy_parquet, source: str, methods: list[str], workers: int = 1):
    """`enginebench run` of a two-repetition toy experiment with ``methods``, the plugin file written from ``source``;
    (the plugin's path, the CLI result)."""
    plugin = tmp_path / "plugin.py"
    plugin.write_text(source)
    exp = tmp_path / "exp.toml"
    exp.write_text(f'dataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 60\n'
                   '[selection]\nkind = "none"\n' + "".join(f"[methods.{m}]\n" for m in methods))
    return plugin, runner.invoke(cli, ["run", str(exp), "-j", str(workers), "-q", "--plugin", str(plugin)])


def test_table_and_runs_show_list_failure_reasons_and_warnings(runner, tmp_path, toy_parquet):
    """Issue 12 item 6: the reasons are in view under every table, not only inside job files."""
    plugin, out = _run_with_plugin(runner, tmp_path, toy_parquet, NOISY_PLUGIN, ["naive-mean", "warner", "breaker"])
    assert out.exit_code == 1, out.output  # every job of breaker failed
    reason = "ValueError: boom " + "x" * 250
    failed = f"failed (2 jobs): breaker: {reason[:197]}..."  # short under a table, whole in `runs show`
    warned = "warning (2 jobs): warner: UserWarning: careful with this one"
    term = runner.invoke(cli, ["table", "latest"])
    assert term.exit_code == 0 and failed in term.output.splitlines() and warned in term.output.splitlines()
    md = runner.invoke(cli, ["table", "latest", "--format", "md"])
    assert md.output.rstrip().splitlines()[-2:] == [failed, warned]
    csv = runner.invoke(cli, ["table", "latest", "--format", "csv"])
    # the toy's u2 is a random walk: its test record leaves the training range, said first (experiments/coverage.py)
    data_notes = [x for x in csv.stderr.splitlines() if " beyond the training range: " in x]
    assert failed not in csv.stdout and csv.stderr.splitlines()[len(data_notes):] == [failed, warned]
    assert data_notes[0].startswith("inputs beyond the training range: u2 in 1 of 1 test records (most: s3, ")
    pd.read_csv(__import__("io").StringIO(csv.stdout))  # still a CSV
    shown = runner.invoke(cli, ["runs", "show", "latest"])
    assert f"  failed (2 jobs): breaker: {reason}" in shown.output.splitlines()
    assert "  " + warned in shown.output.splitlines()
    assert f"plugin file: {plugin.resolve()}" in shown.output


def test_output_paths_are_checked_before_any_work(runner, tmp_path, toy_parquet):
    """Issue 14 item 2: a missing folder for -o is one error line, for every command that writes a file."""
    exp = tmp_path / "exp.toml"
    exp.write_text(f'dataset = "{toy_parquet}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 60\n'
                   '[selection]\nkind = "none"\n[methods.naive-mean]\n')
    assert runner.invoke(cli, ["run", str(exp), "-j", "1", "-q"]).exit_code == 0
    missing = tmp_path / "missing_dir" / "x.csv"
    for args in (["table", "latest", "--format", "csv", "-o", missing], ["compare", "latest", "latest", "-o", missing],
                 ["layout", "latest", "-o", missing], ["publish", "latest", "-o", missing],
                 ["calibrate", "pm", "-o", missing]):
        out = runner.invoke(cli, [str(a) for a in args])
        assert out.exit_code == 2, (args, out.output)
        assert out.output == (f"error: cannot write {missing}: folder {missing.parent} does not exist; create it or "
                              "choose another path (--output)\n"), args
    out = runner.invoke(cli, ["learning-curve", str(exp), "--plot", str(missing.with_suffix(".png")), "-q"])
    assert out.exit_code == 2 and "(--plot)" in out.output
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = runner.invoke(cli, ["report", "latest", "-o", str(blocker / "rep"), "--no-figures"])
    assert out.exit_code == 2 and out.output.startswith(f"error: cannot create the folder {blocker / 'rep'} (")
    good = tmp_path / "t.csv"
    assert runner.invoke(cli, ["table", "latest", "--format", "csv", "-o", str(good)]).exit_code == 0
    assert good.read_text().startswith("dataset,") and [p.name for p in tmp_path.glob(".t.csv*")] == []


def test_usage_errors_are_one_error_line(runner):
    out = runner.invoke(cli, ["table", "--format", "pdf"])
    assert out.exit_code == 2
    assert out.output == ("error: Invalid value for '--format': 'pdf' is not one of 'term', 'md', 'latex', 'csv', "
                          "'html'; see 'cli table --help'\n")
    out = runner.invoke(cli, ["runs"])  # a group alone still shows its help
    assert "Usage: " in out.output and "Commands:" in out.output


KILLER_PLUGIN = '''
import os
import numpy as np
from enginebench.method import Method

class Killer(Method):
    """Ends its worker process, as the kernel's out-of-memory killer would."""
    name = "killer"
    family = "baseline"
    def fit(self, train, params, rng):
        os._exit(9)
    def predict(self, fitted, data):
        return [np.zeros((len(s), 1)) for s in data.segments]
'''


def test_a_worker_that_dies_is_one_line_naming_memory_and_resume(runner, tmp_path, toy_parquet):
    """A killed worker process (BrokenProcessPool) is one error line with exit 2 that says what to do from the
    command line; the Python script's main guard, which only enginebench.api.run's callers need, is not in it."""
    _, out = _run_with_plugin(runner, tmp_path, toy_parquet, KILLER_PLUGIN, ["killer"], workers=2)
    assert out.exit_code == 2, out.output
    line = out.output.strip()
    assert line.startswith("error: a worker process died (") and "\n" not in line
    assert line.endswith("; the jobs finished before are stored and `enginebench run --resume RUN` computes the "
                         "rest; the machine may have run out of memory (fewer workers, `-j`, need less)")
