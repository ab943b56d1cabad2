"""The learning curve is a plan over the runner: it resumes like any run, and resume preparation is the store's."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from helpers import toy_spec

from enginebench.cli.main import cli
from enginebench.errors import StoreError
from enginebench.experiments.engine import plan
from enginebench.experiments.learning_curve import PLOT_FILE, SUMMARY_FILE, prepare_curve, run_learning_curve, summarize_curve
from enginebench.experiments.runner import run_experiment
from enginebench.results.store import RunStore

MONTHS = [0.00005, 0.001]  # ~131 s and ~2630 s of the toy's time axis: its first segment, then every training row


def curve_spec(path):
    return toy_spec(path, repetitions=2, train_size=0, selection={"kind": "none"},
                    methods={"naive-mean": {}, "krls": {"gamma_grid": [0, 0, 1], "lambda_grid": [-2, -2, 1]}})


def values(metrics: pd.DataFrame) -> pd.DataFrame:
    kept = metrics[~metrics["metric"].str.startswith("time_")]
    return kept.sort_values(["split", "method", "repetition", "metric"]).reset_index(drop=True)[
        ["split", "method", "repetition", "metric", "value", "train_months", "n_train"]]


class Stop(Exception):
    pass


def test_the_amount_is_a_job_coordinate_of_the_runners_plan(toy_parquet):
    curve = prepare_curve(curve_spec(toy_parquet), MONTHS)
    jobs = plan(curve.context)
    assert curve.n_jobs() == len(jobs) == 2 * 2 * 2  # amounts x repetitions x methods
    assert {j.split for j in jobs} == {"published@5e-05mo", "published@0.001mo"}
    first, whole = (curve.context.problems[("y", 0.0, f"published@{a.label}")] for a in curve.amounts)
    assert len(first.train) < len(whole.train) and first.parts["test"] is whole.parts["test"]  # test part shared
    assert (first.coordinates, first.label) == ({"train_months": 5e-05}, "@5e-05mo")


def test_an_interrupted_curve_resumes_to_the_same_metrics_and_summary(toy_parquet, tmp_path):
    spec = curve_spec(toy_parquet)
    store = RunStore(tmp_path / "runs")
    reference = run_learning_curve(spec, MONTHS, store, workers=1).run

    def stop_after_three(done, total, job):
        if done == 3:
            raise Stop

    with pytest.raises(Stop):
        run_learning_curve(spec, MONTHS, store, workers=1, progress=stop_after_three)
    interrupted = store.runs()[-1]
    assert interrupted.info()["status"] == "interrupted" and len(interrupted.finished_jobs()) == 3
    assert not (interrupted.path / SUMMARY_FILE).exists()
    seen = []
    result = run_experiment(None, store, workers=1, resume=interrupted, progress=lambda d, t, j: seen.append(j.key))
    assert len(seen) == 5 and result.n_jobs == 8 and result.run.info()["status"] == "finished"
    pd.testing.assert_frame_equal(values(result.run.metrics()), values(reference.metrics()))
    pd.testing.assert_frame_equal(result.run.read_table(SUMMARY_FILE), summarize_curve(reference.metrics()))


def test_run_resume_finishes_a_curve_from_the_command_line(toy_parquet, tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    store = RunStore(tmp_path / "runs")

    def stop_after_one(done, total, job):
        raise Stop

    with pytest.raises(Stop):
        run_learning_curve(curve_spec(toy_parquet), MONTHS, store, workers=1, progress=stop_after_one)
    (run,) = store.runs()
    out = CliRunner().invoke(cli, ["run", "--resume", run.id, "-j", "1", "-q"])
    assert out.exit_code == 0, out.output
    assert run.info()["status"] == "finished" and len(run.finished_jobs()) == 8 and not run.holds_lock()
    assert set(run.read_table(SUMMARY_FILE)["train_months"]) == set(MONTHS)
    # it ends as `learning-curve` does: the curve's table, and the plot drawn in the run folder
    assert "Learning curve of toy-exp" in out.output and "mae on the test part" in out.output
    pytest.importorskip("matplotlib")
    assert f"plot: {run.path / PLOT_FILE}" in out.output and (run.path / PLOT_FILE).stat().st_size > 0


def curve_toml(path, tmp_path):
    """The toy experiment as a file for the `learning-curve` command."""
    exp = tmp_path / "curve.toml"
    exp.write_text(f'name = "toy-exp"\ndataset = "{path}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 0\n'
                   '[selection]\nkind = "none"\n[methods.naive-mean]\n')
    return exp


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_an_interrupted_learning_curve_command_prints_how_to_resume_it(toy_parquet, tmp_path, monkeypatch, how):
    import os
    import signal

    from enginebench.experiments import learning_curve as lc

    real = lc.execute

    def stop(done, total, job):
        if how == "ctrl-c":
            raise KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGTERM)  # as `timeout` or a batch scheduler does

    monkeypatch.setattr(lc, "execute", lambda ctx, run, **kw: real(ctx, run, **{**kw, "progress": stop}))
    previous = signal.getsignal(signal.SIGTERM)
    try:
        out = CliRunner().invoke(cli, ["learning-curve", str(curve_toml(toy_parquet, tmp_path)), "--methods",
                                       "naive-mean", "--months", ",".join(map(str, MONTHS)), "-j", "1", "-q",
                                       "--store", str(tmp_path / "runs")])
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert out.exit_code != 0
    (run,) = RunStore(tmp_path / "runs").runs()
    assert run.info()["status"] == "interrupted"
    assert (f"interrupted: 1 of 4 jobs of run {run.id} are stored; finish it with "
            f"`enginebench run --resume {run.id}`") in out.output


def test_prepare_resume_cleans_up_locks_and_lists_damaged_and_finished_jobs(toy_parquet, tmp_path):
    store = RunStore(tmp_path / "runs")
    run = run_experiment(toy_spec(toy_parquet, repetitions=1), store, workers=1).run
    keys = sorted(run.finished_jobs())
    stale = run.jobs_dir / ".half-written.parquet.tmp"
    stale.write_bytes(b"cut short")
    damaged = run.jobs_dir / f"{keys[0]}.parquet"
    damaged.write_bytes(damaged.read_bytes()[:100])
    state = run.prepare_resume()
    try:
        assert run.holds_lock() and not stale.exists()
        assert set(state.damaged) == {keys[0]} and state.finished == frozenset(keys[1:])
    finally:
        run.unlock()
    (run.path / "environment.json").unlink()
    with pytest.raises(StoreError, match=f"run {run.id} cannot be resumed: environment.json .*damaged"):
        run.prepare_resume()
    assert not run.holds_lock()


def test_a_resume_that_fails_before_its_jobs_releases_the_lock(toy_parquet, tmp_path):
    store = RunStore(tmp_path / "runs")
    run = run_experiment(toy_spec(toy_parquet, repetitions=1), store, workers=1).run
    text = (run.path / "config.toml").read_text()
    (run.path / "config.toml").write_text(text.replace("repetitions = 1", "repetitions = 2"))
    with pytest.raises(StoreError, match="no longer matches its config hash"):
        run_experiment(None, store, workers=1, resume=run)
    assert not run.holds_lock() and not (run.path / "run.lock").exists()
    assert np.isfinite(run.metrics()["value"]).any()


def test_a_learning_curve_run_records_the_units_of_its_columns(toy_parquet, tmp_path):
    """Like an experiment's run (``runner.context_units``): the toy's y is in degC, its inputs in V and bar."""
    from enginebench.results.units import run_units

    spec = toy_spec(toy_parquet, repetitions=1, train_size=0, selection={"kind": "none"}, methods={"naive-mean": {}})
    run = run_learning_curve(spec, [0.001], RunStore(tmp_path / "runs"), workers=1).run
    assert run_units(run.info()) == {"u1": "V", "u2": "bar", "y": "degC"}
