"""``enginebench export --mlflow``: a run logged to a local MLflow file store and read back with MlflowClient.

Layout checked: one parent run per enginebench run, one child per method (tag
mlflow.parentRunId), params method/family/dataset/mode and the most frequent selected
hyperparameters, the table's numbers under the same metric keys in every child.
"""

from __future__ import annotations

import json
import math
import socket
import sys
from collections import Counter
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.method import Method
from enginebench.registry import register
from enginebench.results import tables
from enginebench.results.mlflow_export import resolve_uri
from enginebench.results.mlflow_layout import (
    build_layout, flatten, key_part, mlflow_key, most_frequent_picks, sanitize_key,
)
from enginebench.results.store import RunStore
from enginebench.results.units import run_units
from helpers import make_toy

pytest.importorskip("mlflow")


@register
class MlflowTestBroken(Method):
    """Fails every fit: its child run has every metric key, as NaN, and status FAILED."""

    name = "mlflow-test-broken"
    family = "hybrid"

    def fit(self, train, params, rng):
        raise RuntimeError("always fails")

    def predict(self, fitted, data):
        raise AssertionError("never fitted")


def _make_run(root: Path, name: str, windows: list[float], methods: dict):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict

    data = write_dataset(make_toy(), root / "toy.parquet")
    spec = from_dict({"name": name, "dataset": str(data), "targets": ["y"], "repetitions": 3, "seed": 5,
                      "mode": "window", "windows": windows, "train_size": 120,
                      "selection": {"kind": "bootstrap", "resamples": 2}, "methods": methods}, origin="test")
    return run_experiment(spec, RunStore(root / "runs"), workers=1)


KRLS = {"gamma_grid": [-2, 0, 2], "lambda_grid": [-3, -1, 2]}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Two windows: every metric key names its cell (mae/y/d0/test)."""
    result = _make_run(tmp_path_factory.mktemp("mlflow-run"), "toy-mlflow", [0, 2], {"naive-mean": {}, "krls": KRLS})
    assert result.n_failed == 0
    return result.run


@pytest.fixture(scope="module")
def single_run(tmp_path_factory):
    """One (target, window, part): plain keys (mae, gamma); one method fails every job."""
    result = _make_run(tmp_path_factory.mktemp("mlflow-single"), "toy-single", [0],
                       {"naive-mean": {}, "krls": KRLS, "mlflow-test-broken": {}})
    assert result.n_failed == 3
    return result.run


@pytest.fixture
def file_store_allowed(monkeypatch):
    """Let the exporter set MLFLOW_ALLOW_FILE_STORE itself, and restore the environment afterwards."""
    monkeypatch.setenv("MLFLOW_ALLOW_FILE_STORE", "x")
    monkeypatch.delenv("MLFLOW_ALLOW_FILE_STORE")


def _client(uri: str):
    from mlflow.tracking import MlflowClient

    return MlflowClient(uri)


def _layout(client, experiment_id: str) -> tuple[list, dict]:
    """(the parent runs, {parent id: its children}) of an experiment, read with MLflow's search API."""
    everything = client.search_runs([experiment_id])
    parents = [r for r in everything if "mlflow.parentRunId" not in r.data.tags]
    children = {p.info.run_id: client.search_runs([experiment_id], f"tags.mlflow.parentRunId = '{p.info.run_id}'")
                for p in parents}
    assert len(everything) == len(parents) + sum(len(c) for c in children.values())
    return parents, children


def _expected_picks(run, window: float, method: str, reps: int = 3) -> dict[str, tuple[float, dict[str, int]]]:
    """Per hyperparameter: the most frequent pick over repetitions (a tie: the earliest repetition's) and its counts."""
    chosen = [run.job_meta(f"y__w{window:g}__published__{method}__r{r:03d}")["params"] for r in range(reps)]
    out = {}
    for name in chosen[0]:
        picks = [c[name] for c in chosen]
        counts = Counter(picks)
        best = max(counts.values())
        out[name] = (next(p for p in picks if counts[p] == best), {json.dumps(v): n for v, n in counts.items()})
    return out


def test_keys_and_uris():
    assert sanitize_key("test/TRQ/w0/moe[ideal]/rmae") == "test/TRQ/w0/moe_ideal_/rmae"
    assert key_part("T exh/a:b") == "T exh_a_b" and key_part("..") == "_" and key_part("") == "_"
    assert mlflow_key("mae", "T exh", "d30", "test@3mo") == "mae/T exh/d30/test_3mo"
    long_a, long_b = mlflow_key("gamma", "x" * 300), mlflow_key("gamma", "x" * 299 + "y")
    assert len(long_a) == len(long_b) == 250 and long_a != long_b and long_a[-9] == "~"
    assert resolve_uri("http://host:5000") == "http://host:5000"
    assert resolve_uri("sqlite:///x.db") == "sqlite:///x.db"
    assert resolve_uri("/tmp/mlruns") == "file:///tmp/mlruns"
    assert flatten({"a": {"b": 1, "c": [1, 2]}, "d": "x"}) == {"a.b": 1, "a.c": [1, 2], "d": "x"}


def test_most_frequent_pick_and_its_tie_break():
    rows = [("m", "y", 0.0, "s", r, "g", json.dumps(v)) for r, v in enumerate([2.0, 1.0, 1.0, 2.0, 3.0])]
    rows += [("m", "y", 0.0, "s", r, "k", json.dumps(v)) for r, v in enumerate([5, 4, 4])]
    frame = pd.DataFrame(rows, columns=["method", "target", "window", "split", "repetition", "name", "value"])
    picks = most_frequent_picks(frame).set_index("name")
    assert json.loads(picks.loc["g", "value"]) == 2.0  # 2.0 and 1.0 twice each: repetition 0 picked 2.0 first
    assert json.loads(picks.loc["g", "counts"]) == {"2.0": 2, "1.0": 2, "3.0": 1} and picks.loc["g", "of"] == 5
    assert json.loads(picks.loc["k", "value"]) == 4 and picks.loc["k", "count"] == 2


def test_parent_and_one_child_per_method_read_back(run, tmp_path, file_store_allowed):
    from enginebench.results.mlflow_export import export_run

    result = export_run(run, f"file:{tmp_path / 'mlruns'}")
    client = _client(result.tracking_uri)
    assert client.get_experiment(result.experiment_id).name == "toy-mlflow"
    (parent,), children = _layout(client, result.experiment_id)
    kids = {c.info.run_name: c for c in children[parent.info.run_id]}
    assert set(kids) == {"naive-mean", "krls"} and parent.info.run_id == result.mlflow_run_id
    assert {m: c.info.run_id for m, c in kids.items()} == result.child_run_ids

    # parent: named after the run, its tags, the experiment's settings as params
    info, cfg = run.info(), run.config()
    assert parent.info.run_name == f"toy-mlflow [{run.id}]" and parent.info.status == "FINISHED"
    tags = parent.data.tags
    assert tags["enginebench.run_id"] == run.id and tags["enginebench.config_hash"] == info["config_hash"]
    assert tags["enginebench.experiment"] == "toy-mlflow" and tags["enginebench.dataset"] == "toy"
    assert tags["mlflow.source.git.commit"] == run.environment()["git_commit"]
    params = parent.data.params
    assert params["mode"] == "window" and json.loads(params["windows"]) == [0, 2]
    assert json.loads(params["repetitions"]) == 3 and params["split.kind"] == "published"
    assert params["selection.kind"] == "bootstrap"
    assert json.loads(params["method_options.krls.gamma_grid"]) == [-2, 0, 2]
    assert json.loads(params["seed"]) == cfg["seed"] == 5
    assert parent.data.metrics == {"n_jobs": 12, "finished_jobs": 12, "failed_jobs": 0}

    # children: method, family, dataset, mode and the most frequent selected hyperparameters
    for method, child in kids.items():
        assert child.info.status == "FINISHED" and child.data.tags["enginebench.run_id"] == run.id
        p = child.data.params
        assert (p["method"], p["dataset"], p["mode"]) == (method, "toy", "window")
    assert kids["naive-mean"].data.params["family"] == "baseline"
    assert kids["krls"].data.params["family"] == "data-driven"
    assert set(kids["naive-mean"].data.params) == {"method", "family", "dataset", "mode"}
    krls = kids["krls"].data
    for window in (0, 2):
        for name, (value, counts) in _expected_picks(run, window, "krls").items():
            assert json.loads(krls.params[f"{name}/y/d{window}"]) == value
            spread = json.loads(krls.tags[f"enginebench.picks.{name}/y/d{window}"])
            assert {json.dumps(json.loads(k)): n for k, n in spread.items()} == counts
    assert {k for k in krls.params if "/" in k} == {"gamma/y/d0", "lambda/y/d0", "gamma/y/d2", "lambda/y/d2"}

    # metrics: the table's numbers, the same keys in every child
    summary = tables.summarize(run.metrics())
    assert kids["krls"].data.metrics.keys() == kids["naive-mean"].data.metrics.keys()
    checked = 0
    for r in summary[summary["metric"] != "diverged"].itertuples(index=False):
        got = kids[r.method].data.metrics
        cell = f"y/d{r.window:g}/{r.split}"
        assert got[f"{r.metric}/{cell}"] == pytest.approx(r.mean, rel=1e-12)
        for bound, want in (("ci_low", r.ci_low), ("ci_high", r.ci_high)):
            have = got[f"{r.metric}_{bound}/{cell}"]
            assert (math.isnan(have) and math.isnan(want)) or have == pytest.approx(want, rel=1e-12)
        assert got[f"n_failed/{cell}"] == 0 and got[f"n_diverged/{cell}"] == 0
        checked += 1
    assert checked == len(summary[summary["metric"] != "diverged"]) > 40
    cells = summary[summary["metric"] != "diverged"][["metric", "window", "split"]].drop_duplicates()
    assert len(kids["krls"].data.metrics) == 3 * len(cells) + 2 * 2  # 3 per (metric, cell) of any method + 2 counts
    raw = run.metrics()
    for window in (0, 2):  # the mean over repetitions, straight from the job files
        for method in ("naive-mean", "krls"):
            mae = raw[(raw["method"] == method) & (raw["window"] == window) & (raw["split"] == "test")
                      & (raw["metric"] == "mae")]["value"]
            assert len(mae) == 3 and kids[method].data.metrics[f"mae/y/d{window}/test"] == pytest.approx(mae.mean())

    # artefacts on the parent: the run's own files, byte for byte, and the long table
    names = {a.path for a in client.list_artifacts(result.mlflow_run_id)}
    assert names == {"config.toml", "environment.json", "run.json", "table.csv", "selected_hyperparameters.csv"}
    local = Path(client.download_artifacts(result.mlflow_run_id, "", str(tmp_path / "dl")))
    assert (local / "config.toml").read_bytes() == (run.path / "config.toml").read_bytes()
    table = tables.to_csv(summary, units=run_units(run.info()))  # as `table --format csv` writes it: units included
    assert (local / "table.csv").read_text() == table and ",mae,degC," in table
    selected = pd.read_csv(local / "selected_hyperparameters.csv")
    assert len(selected) == 2 * 3 * 2  # krls: 2 windows x 3 repetitions x (gamma, lambda)


def test_one_cell_gives_plain_keys_and_a_failed_method_nan(single_run, tmp_path, file_store_allowed):
    from enginebench.results.mlflow_export import export_run

    result = export_run(single_run, tmp_path / "mlruns")
    client = _client(result.tracking_uri)
    (parent,), children = _layout(client, result.experiment_id)
    kids = {c.info.run_name: c.data for c in children[parent.info.run_id]}
    assert set(kids) == {"naive-mean", "krls", "mlflow-test-broken"}
    keys = kids["krls"].metrics.keys()
    assert all(k.keys() == keys for k in (kids["naive-mean"].metrics, kids["mlflow-test-broken"].metrics))
    assert not any("/" in k for k in keys) and {"mae", "mae_ci_low", "mae_ci_high", "n_failed", "n_diverged"} <= keys
    summary = tables.summarize(single_run.metrics()).set_index(["method", "metric"])
    for method in ("naive-mean", "krls"):
        for metric in ("mae", "rmse", "rmae", "skill_mae"):
            assert kids[method].metrics[metric] == pytest.approx(summary.loc[(method, metric), "mean"], rel=1e-12)
            want = summary.loc[(method, metric), "ci_high"]
            assert kids[method].metrics[f"{metric}_ci_high"] == pytest.approx(want, rel=1e-12, nan_ok=True)
    broken = kids["mlflow-test-broken"]
    assert broken.metrics["n_failed"] == 3 and math.isnan(broken.metrics["mae"]) and math.isnan(broken.metrics["rmse"])
    assert broken.params["family"] == "hybrid"
    assert client.get_run(result.child_run_ids["mlflow-test-broken"]).info.status == "FAILED"
    for name, (value, _) in _expected_picks(single_run, 0, "krls").items():
        assert json.loads(kids["krls"].params[name]) == value
    assert set(kids["krls"].params) == {"method", "family", "dataset", "mode", "gamma", "lambda"}


def test_family_falls_back_to_what_the_run_stored(single_run):
    layout = build_layout(single_run, family_of=lambda method: None)
    stored = {m: single_run.job_meta(f"y__w0__published__{m}__r000")["family"] for m in single_run.config()["methods"]}
    assert {c.method: c.params["family"] for c in layout.children} == stored
    assert stored == {"naive-mean": "baseline", "krls": "data-driven", "mlflow-test-broken": "hybrid"}


def test_reexport_is_refused_then_replaced_with_the_report(run, tmp_path, file_store_allowed, monkeypatch):
    store = tmp_path / "mlruns"
    uri = store.resolve().as_uri()
    args = ["export", run.id, "--store", str(run.path.parent), "--mlflow", str(store), "--experiment", "mine"]
    first = CliRunner().invoke(cli, args)
    assert first.exit_code == 0, first.output
    assert first.output.startswith(f"exported run {run.id} to {uri}: experiment ")
    assert "with 2 child runs (naive-mean, krls; " in first.output
    client = _client(uri)
    exp = client.get_experiment_by_name("mine")
    (old,), _ = _layout(client, exp.experiment_id)

    refused = [f"error: run {run.id} is already exported to MLflow experiment 'mine' at {uri} (parent run "
               f"{old.info.run_id}); pass --replace to log it again and delete that export"]
    again = CliRunner().invoke(cli, args)
    assert again.exit_code == 2 and again.output.strip().splitlines() == refused
    with monkeypatch.context() as m:  # with --report: refused before the report is built
        import enginebench.reports.static as report_module

        m.setattr(report_module, "write_report", lambda *a, **k: pytest.fail("report built before the refusal"))
        again = CliRunner().invoke(cli, args + ["--report", "--no-figures"])
    assert again.exit_code == 2 and again.output.strip().splitlines() == refused
    assert len(client.search_runs([exp.experiment_id])) == 3  # nothing added

    res = CliRunner().invoke(cli, args + ["--replace", "--report", "--no-figures"])
    assert res.exit_code == 0, res.output
    assert res.output.strip().splitlines()[-1] == (
        f"replaced the earlier export (deleted parent run {old.info.run_id} and its child runs)")
    (new,), children = _layout(client, exp.experiment_id)
    assert new.info.run_id != old.info.run_id and len(children[new.info.run_id]) == 2
    assert client.get_run(old.info.run_id).info.lifecycle_stage == "deleted"
    report = {a.path for a in client.list_artifacts(new.info.run_id, "report")}
    assert {"report/index.html", "report/table.csv"} <= report


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_bad_uris_are_one_line(run, tmp_path):
    base = ["export", run.id, "--store", str(run.path.parent), "--mlflow"]
    res = CliRunner().invoke(cli, base + ["bogus://nowhere"])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        "error: MLflow cannot use the tracking URI bogus://nowhere: the installed mlflow has no tracking store for the "
        "scheme 'bogus'; give a server (http://HOST:PORT), a local folder or a file: URI"]
    port = _closed_port()
    res = CliRunner().invoke(cli, base + [f"http://127.0.0.1:{port}"])
    assert res.exit_code == 2
    (line,) = res.output.strip().splitlines()
    assert line.startswith(f"error: cannot reach the MLflow server at http://127.0.0.1:{port} (")
    assert line.endswith("); start it (mlflow server) or check the --mlflow URI")


def test_missing_mlflow_is_one_line_with_the_install_hint(run, monkeypatch, tmp_path):
    for name in [m for m in sys.modules if m == "mlflow" or m.startswith("mlflow.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "mlflow", None)  # import mlflow -> ImportError
    res = CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow", str(tmp_path / "m")])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        'error: MLflow export needs the mlflow package, which is not installed; pip install "enginebench[mlflow]"']
    assert not (tmp_path / "m").exists()


def test_an_sqlite_export_keeps_its_artefacts_next_to_the_database_not_in_the_current_folder(run, tmp_path,
                                                                                             monkeypatch):
    """MLflow's default artefact root is ./mlruns of the current folder (where a file store may live)."""
    from enginebench.results.mlflow_export import artifact_location

    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    db = tmp_path / "tracking" / "mlflow.db"
    db.parent.mkdir()
    uri = f"sqlite:///{db}"
    named = tmp_path / "elsewhere"
    cases = [("sq", [], db.parent / "mlflow-artifacts"), ("named", ["--artifacts", str(named)], named)]
    for experiment, extra, root in cases:
        res = CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow", uri,
                                       "--experiment", experiment, *extra])
        assert res.exit_code == 0, res.output
        exp = _client(uri).get_experiment_by_name(experiment)
        assert exp.artifact_location == artifact_location(uri, experiment, named if extra else None)
        assert exp.artifact_location.startswith(root.as_uri() + "/")
        assert any(p.name == "table.csv" for p in root.rglob("*"))
    assert list(work.iterdir()) == []  # no ./mlruns


def test_a_database_store_without_a_place_for_artefacts_is_refused(run):
    from enginebench.results.mlflow_export import artifact_location

    res = CliRunner().invoke(cli, ["export", run.id, "--store", str(run.path.parent), "--mlflow",
                                   "postgresql://nowhere/db"])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == [
        "error: MLflow store postgresql://nowhere/db: a database store has no folder of its own for artefacts, and "
        "MLflow would write them into ./mlruns of the current folder; pass --artifacts DIR (or a URI)"]
    assert artifact_location("http://host:5000", "e") is None and artifact_location("file:///tmp/m", "e") is None
