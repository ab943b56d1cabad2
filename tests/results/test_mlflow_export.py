"""``enginebench export --mlflow``: a run logged to a local MLflow file store and read back with MlflowClient."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results import tables
from enginebench.results.mlflow_export import flatten, metric_key, resolve_uri, sanitize_key
from enginebench.results.store import RunStore
from helpers import make_toy


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict

    root = tmp_path_factory.mktemp("mlflow-run")
    data = write_dataset(make_toy(), root / "toy.parquet")
    spec = from_dict({"name": "toy-mlflow", "dataset": str(data), "targets": ["y"], "repetitions": 3, "seed": 5,
                      "mode": "window", "windows": [0, 2], "train_size": 120,
                      "selection": {"kind": "bootstrap", "resamples": 2},
                      "methods": {"naive-mean": {}, "krls": {"gamma_grid": [-2, 0, 2], "lambda_grid": [-3, -1, 2]}}},
                     origin="test")
    result = run_experiment(spec, RunStore(root / "runs"), workers=1)
    assert result.n_failed == 0
    return result.run


@pytest.fixture
def file_store_allowed(monkeypatch):
    """Let the exporter set MLFLOW_ALLOW_FILE_STORE itself, and restore the environment afterwards."""
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "x")
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE")


def test_keys_and_uris():
    assert sanitize_key("test/TRQ/w0/moe[ideal]/rmae") == "test/TRQ/w0/moe_ideal_/rmae"
    assert metric_key("test", "T exh", 30.0, "mtl-krls", "mae") == "test/T exh/w30/mtl-krls/mae"
    assert resolve_uri("http://host:5000") == "http://host:5000"
    assert resolve_uri("sqlite:///x.db") == "sqlite:///x.db"
    assert resolve_uri("/tmp/mlruns") == "file:///tmp/mlruns"
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": "x"}) == {"a.b": 1, "a.c": [1, 2], "d": "x"}


def test_export_logs_params_metrics_and_artefacts_that_read_back(run, tmp_path, file_store_allowed):
    pytest.importorskip("mlflow")
    from mlflow.tracking import MlflowClient

    from enginebench.results.mlflow_export import export_run

    result = export_run(run, f"file:{tmp_path / 'mlruns'}")
    client = MlflowClient(result.tracking_uri)
    logged = client.get_run(result.mlflow_run_id)
    assert logged.info.run_name == run.id and logged.data.tags["enginebench.run_id"] == run.id
    assert client.get_experiment(result.experiment_id).name == "toy-mlflow"
    assert logged.info.status == "FINISHED"

    # params: the config, and the hyperparameters each repetition selected
    params = logged.data.params
    cfg = run.config()
    assert json.loads(params["config.method_options.krls.gamma_grid"]) == [-2, 0, 2]
    assert params["config.selection.kind"] == "bootstrap" and json.loads(params["config.seed"]) == cfg["seed"] == 5
    for window in (0, 2):
        chosen = [run.job_meta(f"y__w{window}__published__krls__r{r:03d}")["params"] for r in range(3)]
        for name in ("gamma", "lambda"):
            assert json.loads(params[f"selected/y/w{window}/published/krls/{name}"]) == [c[name] for c in chosen]
            history = client.get_metric_history(result.mlflow_run_id, f"selected/y/w{window}/published/krls/{name}")
            assert sorted((m.step, m.value) for m in history) == [(r, c[name]) for r, c in enumerate(chosen)]

    # metrics: the table's mean and interval, and every repetition's value as a step
    raw = run.metrics()
    summary = tables.summarize(raw)
    metrics = logged.data.metrics
    checked = 0
    for r in summary.itertuples(index=False):
        key = metric_key(r.split, r.target, r.window, r.method, r.metric)
        assert metrics[key + "/mean"] == pytest.approx(r.mean, rel=1e-12)
        if np.isfinite(r.ci_low):
            assert metrics[key + "/ci_low"] == pytest.approx(r.ci_low, rel=1e-12)
            assert metrics[key + "/ci_high"] == pytest.approx(r.ci_high, rel=1e-12)
        checked += 1
    assert checked == len(summary) > 20
    for window in (0, 2):
        for method in ("naive-mean", "krls"):
            mine = raw[(raw["method"] == method) & (raw["window"] == window) & (raw["split"] == "test")
                       & (raw["metric"] == "mae")].sort_values("repetition")
            history = client.get_metric_history(result.mlflow_run_id, f"test/y/w{window}/{method}/mae/repetitions")
            assert sorted((m.step, m.value) for m in history) == list(zip(mine["repetition"], mine["value"]))
            assert metrics[f"test/y/w{window}/{method}/mae/mean"] == pytest.approx(mine["value"].mean(), rel=1e-12)
    skill = client.get_metric_history(result.mlflow_run_id, "test/y/w0/krls/skill_mae/repetitions")
    assert len(skill) == 3  # paired skill per repetition, as the table computes it

    # artefacts: the run's own files, byte for byte, and the long table
    names = {a.path for a in client.list_artifacts(result.mlflow_run_id)}
    assert names == {"config.toml", "environment.json", "run.json", "table.csv", "selected_hyperparameters.csv"}
    local = Path(client.download_artifacts(result.mlflow_run_id, "", str(tmp_path / "dl")))
    assert (local / "config.toml").read_bytes() == (run.path / "config.toml").read_bytes()
    assert (local / "environment.json").read_bytes() == (run.path / "environment.json").read_bytes()
    assert (local / "table.csv").read_text() == tables.to_csv(summary)


def test_export_command_with_report(run, tmp_path, file_store_allowed):
    pytest.importorskip("mlflow")
    from mlflow.tracking import MlflowClient

    store = tmp_path / "mlruns"
    res = CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow", str(store),
                                   "--experiment", "mine", "--report", "--no-figures"])
    assert res.exit_code == 0, res.output
    assert res.output.startswith(f"exported run {run.id} to {store.resolve().as_uri()}: experiment ")
    client = MlflowClient(store.resolve().as_uri())
    exp = client.get_experiment_by_name("mine")
    (found,) = client.search_runs([exp.experiment_id])
    report = {a.path for a in client.list_artifacts(found.info.run_id, "report")}
    assert {"report/index.html", "report/table.csv"} <= report
    # a second export of the same run is a second MLflow run in the same experiment
    assert CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow", str(store),
                                    "--experiment", "mine"]).exit_code == 0
    assert len(client.search_runs([exp.experiment_id])) == 2


def test_missing_mlflow_is_one_line_with_the_install_hint(run, monkeypatch, tmp_path):
    for name in [m for m in sys.modules if m == "mlflow" or m.startswith("mlflow.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "mlflow", None)  # import mlflow -> ImportError
    res = CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow", str(tmp_path / "m")])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        'error: MLflow export needs the mlflow package, which is not installed; pip install "enginebench[mlflow]"']
    assert not (tmp_path / "m").exists()
