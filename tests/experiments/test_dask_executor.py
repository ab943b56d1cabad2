"""The Dask executor: same metrics as the local pool, resumable, plugins shipped, clear errors.

The cluster is a LocalCluster of two single-threaded worker *processes* (not threads):
processes are what a real cluster has, so this checks that the context and plugin
classes really travel by pickle and that each worker loads the plugin files itself.
"""

from __future__ import annotations

import socket
import sys

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

distributed = pytest.importorskip("distributed")

from enginebench.cli.main import cli  # noqa: E402
from enginebench.experiments import executor_base, executors  # noqa: E402
from enginebench.experiments.runner import run_experiment  # noqa: E402
from enginebench.results.store import RunStore  # noqa: E402
from helpers import interrupt_after, make_toy, toy_spec  # noqa: E402


def dask_spec(dataset, **changes):
    return toy_spec(dataset, **{"name": "dask-toy", "seed": 11, **changes})

KEY = ["target", "window", "split", "method", "repetition", "metric"]


@pytest.fixture(scope="module")
def scheduler():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", memory_limit=0)
    try:
        yield cluster.scheduler_address
    finally:
        cluster.close()


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from enginebench.datasets.io import write_dataset

    return write_dataset(make_toy(), tmp_path_factory.mktemp("data") / "toy.parquet")


def metric_table(run) -> pd.DataFrame:
    """The stored metric rows without timings, in a fixed order."""
    m = run.metrics()
    m = m[~m["metric"].str.startswith("time_")]
    return m.sort_values(KEY).reset_index(drop=True)[KEY + ["value", "status"]]


@pytest.fixture(scope="module")
def reference(dataset, tmp_path_factory):
    """The local executor's metric table (in-process; one BLAS thread, as in each Dask worker)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        result = run_experiment(dask_spec(dataset), RunStore(tmp_path_factory.mktemp("runs")), workers=1)
    assert result.n_failed == 0
    return result.run


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dask_gives_exactly_the_metrics_of_the_local_executor(dataset, reference, tmp_path, scheduler):
    seen = []
    dask = run_experiment(dask_spec(dataset), RunStore(tmp_path / "runs"), workers=2, executor="dask",
                          scheduler=scheduler, progress=lambda done, total, job: seen.append((done, total)))
    assert dask.n_jobs == 6 and dask.n_failed == 0
    assert seen == [(k, 6) for k in range(1, 7)]
    assert dask.run.info()["status"] == "finished" and len(dask.run.finished_jobs()) == 6
    a, b = metric_table(reference), metric_table(dask.run)
    assert len(a) > 30
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    for rep in range(3):
        key = f"y__w0__published__krls__r{rep:03d}"
        assert dask.run.job_meta(key)["params"] == reference.job_meta(key)["params"]


def test_an_interrupted_dask_run_resumes_on_dask(dataset, reference, tmp_path, scheduler):
    spec = dask_spec(dataset)
    store = RunStore(tmp_path / "runs")

    interrupted = interrupt_after(spec, store, workers=2, executor="dask", scheduler=scheduler)
    assert interrupted.info()["status"] == "interrupted"
    before = set(interrupted.finished_jobs())
    assert len(before) == 2
    seen = []
    result = run_experiment(spec, store, workers=2, resume=interrupted, executor="dask", scheduler=scheduler,
                            progress=lambda d, t, j: seen.append(j.key))
    assert len(seen) == 4 and not set(seen) & before  # only the missing jobs ran
    assert result.run.info()["status"] == "finished" and len(result.run.finished_jobs()) == 6
    pd.testing.assert_frame_equal(metric_table(reference), metric_table(result.run), check_exact=True)


def test_without_a_scheduler_a_local_cluster_of_jobs_workers_is_started(dataset, reference, tmp_path):
    result = run_experiment(dask_spec(dataset), RunStore(tmp_path / "runs"), workers=2, executor="dask")
    assert result.n_failed == 0
    pd.testing.assert_frame_equal(metric_table(reference), metric_table(result.run), check_exact=True)


PLUGIN = '''
import numpy as np
from enginebench.method import Method

class Median(Method):
    """Training median of the target (a plugin class the workers only know from this file)."""
    name = "dask-median"
    family = "baseline"
    def fit(self, train, params, rng):
        return np.median(train.y, axis=0)
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
'''


@pytest.fixture
def runner(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    return CliRunner()


def test_cli_runs_a_plugin_method_on_the_cluster(runner, dataset, tmp_path, scheduler):
    plugin = tmp_path / "dask_median.py"
    plugin.write_text(PLUGIN)
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "cli-dask"\ndataset = "{dataset}"\ntargets = ["y"]\nrepetitions = 2\n'
                   f'train_size = 150\n[methods.naive-mean]\n[methods.dask-median]\n')
    out = runner.invoke(cli, ["run", str(exp), "--plugin", str(plugin), "--scheduler", scheduler, "-q"])
    assert out.exit_code == 0, out.output
    assert "dask-median" in out.output
    (run,) = RunStore(tmp_path / "runs").runs()
    metrics = run.metrics()
    assert set(metrics["status"]) == {"ok"}
    mae = metrics[(metrics["method"] == "dask-median") & (metrics["metric"] == "mae")]["value"]
    assert len(mae) == 2 and np.isfinite(mae).all()


def test_shipped_plugin_copy_is_used_where_the_file_is_missing(tmp_path, monkeypatch):
    """A cluster node without the parent's file system gets the file's text and loads that."""
    monkeypatch.delitem(sys.modules, "enginebench_plugin_gone_plugin", raising=False)
    missing = tmp_path / "elsewhere" / "gone_plugin.py"
    executor_base.load_shipped_plugins(((str(missing), PLUGIN.replace("dask-median", "shipped-median")),))
    module = sys.modules["enginebench_plugin_gone_plugin"]
    assert module.Median.name == "shipped-median" and not missing.exists()
    from enginebench import registry

    assert registry.get("shipped-median") is module.Median
    monkeypatch.delitem(registry._extra, "shipped-median")


def test_unreachable_scheduler_is_one_error_line(runner, tmp_path, monkeypatch):
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT_S", 1.0)
    address = f"tcp://127.0.0.1:{free_port()}"
    out = runner.invoke(cli, ["run", "gas-turbine-nox-quick", "--executor", "dask", "--scheduler", address, "-q"])
    assert out.exit_code == 2, out.output
    lines = out.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot reach the Dask scheduler at ")
    assert address in lines[0] and "within 1 s" in lines[0]
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").iterdir())  # no run was created


def test_missing_dask_names_the_extra(runner, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    out = runner.invoke(cli, ["run", "gas-turbine-nox-quick", "--executor", "dask", "-q"])
    assert out.exit_code == 2, out.output
    assert out.output.strip() == 'error: the dask executor needs dask.distributed: pip install "enginebench[dask]"'


def test_scheduler_needs_the_dask_executor(runner):
    out = runner.invoke(cli, ["run", "gas-turbine-nox-quick", "--executor", "local", "--scheduler", "tcp://x:1", "-q"])
    assert out.exit_code == 2
    assert out.output.strip() == "error: --scheduler tcp://x:1 needs --executor dask (the local executor has no scheduler)"
