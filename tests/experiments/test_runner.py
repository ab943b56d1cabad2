"""The protocol engine end to end on a small synthetic dataset: plan, run, store, summarise."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from enginebench.experiments.engine import plan
from enginebench.experiments.runner import prepare, run_experiment
from enginebench.experiments.spec import from_dict, load_spec
from enginebench.results.store import RunStore
from helpers import interrupt_after, toy_spec
from enginebench.results.summary import SUMMARY_COLUMNS, summarize
from enginebench.results.tables import to_csv, to_html, to_latex, to_markdown


def test_plan_covers_every_coordinate_once(toy_parquet):
    spec = toy_spec(toy_parquet, mode="window", windows=[0, 2])
    jobs = plan(prepare(spec))
    assert len(jobs) == 3 * 2 * 2  # repetitions x windows x methods
    assert len({j.key for j in jobs}) == len(jobs)


def test_run_stores_every_job_and_is_deterministic(toy_parquet, tmp_path):
    spec = toy_spec(toy_parquet)
    store = RunStore(tmp_path / "runs")
    a = run_experiment(spec, store, workers=1)
    b = run_experiment(spec, store, workers=1)
    assert a.n_failed == 0 and a.n_jobs == 6
    assert len(list((a.run.path / "jobs").glob("*.parquet"))) == 6
    assert not list((a.run.path / "jobs").glob(".*"))  # no temporary files left
    ma, mb = (r.run.metrics().sort_values(["method", "repetition", "metric"]) for r in (a, b))
    keep = ~ma["metric"].str.startswith("time_")
    assert np.array_equal(ma.loc[keep, "value"].to_numpy(), mb.loc[keep, "value"].to_numpy(), equal_nan=True)
    info = a.run.info()
    assert info["status"] == "finished" and info["finished_jobs"] == 6
    env = a.run.environment()
    assert env["seed"] == 7 and env["packages"]["numpy"]
    meta = a.run.job_meta(f"y__w0__published__krls__r000")
    assert set(meta["params"]) == {"gamma", "lambda"} and meta["search"]["grid_size"] == 9
    assert a.run.config()["train_size"] == 150


def test_process_pool_gives_the_same_metrics_as_serial(toy_parquet, tmp_path):
    spec = toy_spec(toy_parquet, repetitions=2)
    store = RunStore(tmp_path / "runs")
    serial = run_experiment(spec, store, workers=1).run.metrics()
    pooled = run_experiment(spec, store, workers=2).run.metrics()
    key = ["method", "repetition", "split", "metric"]
    s = serial[~serial["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    p = pooled[~pooled["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    np.testing.assert_allclose(s, p, rtol=1e-9, atol=1e-12)  # BLAS threads may differ


def test_workers_share_spilled_raw_data_and_agree_with_serial(toy_parquet, tmp_path, monkeypatch):
    """Raw arrays spilled to a memory-mapped file (as at full size) give the serial run's metrics."""
    import pickle

    from enginebench.experiments import engine

    spec = toy_spec(toy_parquet, repetitions=2, mode="window", windows=[0, 2])
    ctx = prepare(spec)
    before = len(pickle.dumps(ctx))
    engine.spill_problems(ctx, tmp_path, min_bytes=0)
    pools = [p for prob in ctx.problems.values() for p in (prob.train, *prob.parts.values())]
    assert all(p.raw.spill_file for p in pools)
    assert len({id(p.raw) for p in pools}) == 2  # one shared copy per split part (train, test), not per window
    assert len(pickle.dumps(ctx)) < before / 5  # workers receive file names, not data
    monkeypatch.setattr(engine, "SPILL_MIN_BYTES", 0)
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(engine.tempfile, "tempdir", str(scratch))
    spills = []
    real_spill = engine.spill_problems
    monkeypatch.setattr(engine, "spill_problems", lambda c, d, min_bytes=None: (spills.append(d), real_spill(c, d, min_bytes)))
    store = RunStore(tmp_path / "runs")
    serial = run_experiment(spec, store, workers=1).run.metrics()
    pooled = run_experiment(spec, store, workers=2).run.metrics()
    key = ["method", "window", "repetition", "split", "metric"]
    s = serial[~serial["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    p = pooled[~pooled["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    # selection extends the ridge penalty towards its bound (1e-14) on these noise-free toy records, where the
    # solutions' last digits follow the BLAS's summation order (threads per process): agreement to 1e-7
    np.testing.assert_allclose(s, p, rtol=1e-7, atol=1e-12)
    assert len(spills) == 1 and spills[0].parent == scratch  # only the pooled run spills
    assert not list(scratch.iterdir())  # the spill folder is removed after the run


def test_methods_of_a_repetition_share_the_training_rows(toy_parquet, tmp_path):
    run = run_experiment(toy_spec(toy_parquet, repetitions=2), RunStore(tmp_path), workers=1).run
    n0 = run.job_meta("y__w0__published__krls__r000")["n_train"]
    assert n0 == 150 == run.job_meta("y__w0__published__naive-mean__r000")["n_train"]


def test_summary_matches_hand_statistics(toy_parquet, tmp_path):
    run = run_experiment(toy_spec(toy_parquet, repetitions=4), RunStore(tmp_path), workers=1).run
    metrics = run.metrics()
    summary = summarize(metrics)
    assert list(summary.columns) == SUMMARY_COLUMNS
    row = summary[(summary["method"] == "krls") & (summary["metric"] == "mae")].iloc[0]
    v = metrics[(metrics["method"] == "krls") & (metrics["metric"] == "mae")]["value"].to_numpy()
    half = 3.182446305284263 * v.std(ddof=1) / 2  # t_{0.975, 3} * s / sqrt(4)
    assert row["mean"] == pytest.approx(v.mean())
    assert row["ci_high"] - row["mean"] == pytest.approx(half)
    assert row["median"] == pytest.approx(np.median(v)) and row["n_repeats"] == 4
    skill = summary[(summary["method"] == "krls") & (summary["metric"] == "skill_mae")].iloc[0]
    base = metrics[(metrics["method"] == "naive-mean") & (metrics["metric"] == "mae")].sort_values("repetition")["value"].to_numpy()
    mine = metrics[(metrics["method"] == "krls") & (metrics["metric"] == "mae")].sort_values("repetition")["value"].to_numpy()
    assert skill["mean"] == pytest.approx(np.mean(1 - mine / base))
    assert skill["mean"] > 0.5  # KRLS beats the constant on this smooth relation


def test_table_formats(toy_parquet, tmp_path):
    run = run_experiment(toy_spec(toy_parquet), RunStore(tmp_path), workers=1).run
    summary = summarize(run.metrics())
    md = to_markdown(summary)
    assert md.splitlines()[0] == "| target | mode | Delta [s] | split | method | n | mae | mape [%] | ppmcc [-] | rmae [%] |"
    krls_line = next(line for line in md.splitlines() if "| krls |" in line)
    assert krls_line.count("**") >= 6  # krls is best on mae, mape, ppmcc, rmae
    assert r"\toprule" in to_latex(summary) and r"\textbf{" in to_latex(summary)
    assert "<table" in to_html(summary) and "<b>" in to_html(summary)
    csv = pd.read_csv(__import__("io").StringIO(to_csv(summary)))
    for col in ["dataset", "target", "mode", "Delta [s]", "method", "split", "metric", "mean", "ci_low", "ci_high",
                "sd", "median", "iqr", "n_repeats"]:
        assert col in csv.columns


class Exploding:
    pass


def test_failed_jobs_are_counted_not_averaged(toy_parquet, tmp_path):
    from enginebench.method import Method
    from enginebench.registry import register

    @register
    class NaNMethod(Method):
        name = "test-nan"
        family = "data-driven"

        def fit(self, train, params, rng):
            return None

        def predict(self, fitted, data):
            return [np.full((len(s), 1), np.nan) for s in data.segments]

    spec = toy_spec(toy_parquet, methods={"naive-mean": {}, "test-nan": {}})
    result = run_experiment(spec, RunStore(tmp_path), workers=1)
    assert result.n_failed == 3
    meta = result.run.job_meta("y__w0__published__test-nan__r000")
    assert meta["status"] == "failed"
    assert meta["reason"] == ("FloatingPointError: test-nan returned non-finite predictions for 1 segment(s) "
                              "of the test part (first: s3)")
    summary = summarize(result.run.metrics())
    failing = summary[summary["method"] == "test-nan"]  # listed with its failures, never averaged in
    assert set(failing["n_repeats"]) == {0} and set(failing["n_failed"]) == {3} and failing["mean"].isna().all()
    assert set(summary[summary["method"] == "naive-mean"]["n_failed"]) == {0}


def test_builtin_specs_parse():
    spec = load_spec("gas-turbine-nox")
    assert spec.methods == ("naive-mean", "ridge", "krls") and spec.repetitions == 30
    assert spec.method_options["krls"]["gamma_grid"] == [-4, 4, 41]


@pytest.mark.parametrize("raw, message", [
    ({"dataset": "x", "targets": ["y"]}, "test: missing required key 'methods'"),
    ({"dataset": "x", "targets": ["y"], "methods": ["krls"], "colour": 1}, "test: unknown key(s) colour;"),
    ({"dataset": "x", "targets": ["y"], "methods": ["krls"], "mode": "psychic"},
     "test: mode 'psychic' is not one of static, window, simulation"),
    ({"dataset": "x", "targets": ["y"], "methods": ["krls"], "windows": [10]},
     "test: windows > 0 need mode = 'window' (mode is 'static')"),
    ({"dataset": "x", "targets": ["y"], "methods": ["krls"], "repetitions": 0},
     "test: 'repetitions' must be an integer >= 1, got 0"),
    ({"dataset": "x", "targets": ["y"], "methods": ["krls"], "selection": {"kind": "cv"}},
     "test: selection kind 'cv' is not one of bootstrap, kfold, validation, none"),
])
def test_spec_errors(raw, message):
    from enginebench.errors import SpecError

    with pytest.raises(SpecError) as err:
        from_dict(raw, origin="test")
    assert str(err.value).startswith(message)


def test_bootstrap_interval_option_in_summaries(toy_parquet, tmp_path):
    from enginebench.results.stats import bootstrap_interval

    run = run_experiment(toy_spec(toy_parquet, repetitions=5, interval="bootstrap"), RunStore(tmp_path), workers=1).run
    metrics = run.metrics()
    summary = summarize(metrics, interval="bootstrap", seed=3)
    row = summary[(summary["method"] == "krls") & (summary["metric"] == "mae")].iloc[0]
    assert row["interval"] == "bootstrap"
    v = metrics[(metrics["method"] == "krls") & (metrics["metric"] == "mae")]["value"].to_numpy()
    assert row["ci_low"] >= v.min() - 1e-12 and row["ci_high"] <= v.max() + 1e-12
    assert "bootstrap percentile" in to_markdown(summary)


def test_an_interrupted_run_resumes_to_the_same_metrics(toy_parquet, tmp_path):
    spec = toy_spec(toy_parquet, repetitions=3)
    store = RunStore(tmp_path / "runs")
    reference = run_experiment(spec, store, workers=1).run.metrics()

    interrupted = interrupt_after(spec, store, workers=1)
    assert interrupted.info()["status"] == "interrupted" and len(interrupted.finished_jobs()) == 2
    before = {k: (interrupted.jobs_dir / f"{k}.parquet").stat().st_mtime_ns for k in interrupted.finished_jobs()}
    seen = []
    result = run_experiment(spec, store, workers=1, resume=interrupted, progress=lambda d, t, j: seen.append(j.key))
    assert len(seen) == 4 and not set(seen) & set(before)  # only the missing jobs ran
    assert {k: (interrupted.jobs_dir / f"{k}.parquet").stat().st_mtime_ns for k in before} == before
    assert result.run.info()["status"] == "finished" and len(result.run.finished_jobs()) == 6
    key = ["method", "repetition", "split", "metric"]
    a = reference[~reference["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    b = result.run.metrics()
    b = b[~b["metric"].str.startswith("time_")].sort_values(key)["value"].to_numpy()
    assert np.array_equal(a, b, equal_nan=True)


def test_killed_process_resumes_from_the_command_line(toy_parquet, tmp_path):
    """SIGKILL mid-run: finished jobs stay readable, --resume completes the rest."""
    import os
    import signal
    import subprocess
    import sys
    import time

    exp = tmp_path / "exp.toml"
    exp.write_text(f'''
name = "kill-me"
dataset = "{toy_parquet}"
targets = ["y"]
repetitions = 8
train_size = 150
[selection]
resamples = 2
[methods.naive-mean]
[methods.krls]
gamma_grid = [-2, 0, 5]
lambda_grid = [-3, -1, 5]
''')
    env = {**os.environ, "ENGINEBENCH_STORE": str(tmp_path / "runs")}
    cmd = [sys.executable, "-c", "from enginebench.cli.main import main; main()"]
    # cwd outside the checkout: there `python -c` would import the source folder enginebench/
    proc = subprocess.Popen([*cmd, "run", str(exp), "-j", "1", "-q"], env=env, cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    jobs_dir = None
    deadline = time.time() + 120
    while time.time() < deadline:
        found = list((tmp_path / "runs").glob("*/jobs/*.parquet"))
        if len(found) >= 3:
            jobs_dir = found[0].parent
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate()
    assert jobs_dir is not None, f"the run never wrote three jobs: {err.decode()[-500:]}"
    store = RunStore(tmp_path / "runs")
    (run,) = store.runs()
    n_before = len(run.finished_jobs())
    assert 3 <= n_before < 16
    run.metrics()  # every finished job file is readable
    out = subprocess.run([*cmd, "run", "--resume", run.id, "-j", "1", "-q"], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert len(run.finished_jobs()) == 16 and run.info()["status"] == "finished"
    assert not list(jobs_dir.glob(".*"))  # no temporary file left behind


def test_worker_thread_limit_reaches_every_blas_library():
    """A fresh worker process: numpy's and scipy's OpenBLAS (and OpenMP, torch) all run 1 thread
    (each library otherwise starts with one thread per core)."""
    import concurrent.futures
    import multiprocessing

    from helpers import thread_limits_after_worker_setup

    with concurrent.futures.ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        limits = pool.submit(thread_limits_after_worker_setup, 1).result()
    assert any("scipy" in path for path, _ in limits), limits  # scipy's OpenBLAS is among them
    assert all(n == 1 for _, n in limits), limits
