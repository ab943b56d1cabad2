"""``joint_targets = true``: methods that model several outputs at once run one job for all targets; the
tables still show each target, ARX's joint coefficients equal its per-target ones at the same orders, the
joint selection weighs targets by their scale, and the trajectory figures find the joint job."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import scipy.signal

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.jobs import JOINT
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.methods.arx import ARX
from enginebench.results.metrics import grid_scores
from enginebench.results.store import RunStore


def two_outputs(seed: int = 0, n_records: int = 4, n: int = 300) -> Dataset:
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_records):
        u = rng.normal(size=(n, 2))
        y1 = scipy.signal.lfilter([0, 0.5], [1, -0.7], u[:, 0]) + 0.01 * rng.normal(size=n)
        y2 = 1000 * scipy.signal.lfilter([0.2, 0.1], [1, -0.5, 0.1], u[:, 1] - u[:, 0]) + 5 * rng.normal(size=n)
        frames.append(pd.DataFrame({SEGMENT: f"r{k}", TIME: np.arange(n) * 0.1, "u1": u[:, 0], "u2": u[:, 1],
                                    "y1": y1, "y2": y2}))
    schema = Schema((Column("u1", "input"), Column("u2", "input"), Column("y1", "output", "V"),
                     Column("y2", "output", "mV")))
    return Dataset("two", pd.concat(frames, ignore_index=True), schema, 0.1, {})


def spec(path, **changes):
    raw = {"name": "joint", "dataset": str(path), "targets": "all", "mode": "simulation", "repetitions": 1,
           "train_size": 0, "init_samples": 10, "split": {"kind": "records", "train": ["r0", "r1", "r2"], "test": ["r3"]},
           "selection": {"kind": "kfold", "folds": 2, "criterion": "rmse"}, "joint_targets": True,
           "methods": {"naive-mean": {}, "arx": {"max_order": 4}}}
    raw.update(changes)
    return from_dict(raw, origin="test")


@pytest.fixture(scope="module")
def joint_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("joint")
    path = write_dataset(two_outputs(), root / "two.parquet")
    return run_experiment(spec(path), RunStore(root / "runs"), workers=1).run


def test_a_joint_method_runs_one_job_for_all_targets_and_the_table_shows_each(joint_run):
    metas = joint_run.job_metas()
    arx = [m for m in metas.values() if m["method"] == "arx"]
    assert [m["target"] for m in arx] == [JOINT]
    assert sorted(m["target"] for m in metas.values() if m["method"] == "naive-mean") == ["y1", "y2"]
    m = joint_run.metrics()
    rmse = m[(m["metric"] == "rmse") & (m["split"] == "test")].set_index(["method", "target"])["value"]
    assert set(rmse.index) == {("arx", "y1"), ("arx", "y2"), ("naive-mean", "y1"), ("naive-mean", "y2")}
    assert rmse[("arx", "y1")] < 0.2 * rmse[("naive-mean", "y1")] and rmse[("arx", "y2")] < rmse[("naive-mean", "y2")]
    assert joint_run.config()["joint_targets"] is True


def test_joint_arx_coefficients_equal_the_per_target_ones():
    raw = RawSegments.from_dataset(two_outputs(1))
    both = SamplePool(raw, ["y1", "y2"], "simulation").materialize()
    params = {"na": 3, "nb": 2, "nk": 1}
    joint = ARX().fit(both, params, np.random.default_rng(0))
    for k, target in enumerate(("y1", "y2")):
        one = ARX().fit(SamplePool(raw, [target], "simulation").materialize(), params, np.random.default_rng(0))
        np.testing.assert_array_equal(joint.a[k], one.a[0])
        np.testing.assert_array_equal(joint.b[k], one.b[0])
        assert joint.c[k] == one.c[0]


def test_joint_selection_weighs_each_target_by_its_scale():
    raw = RawSegments.from_dataset(two_outputs(2))
    data = SamplePool(raw, ["y1", "y2"], "simulation").materialize()
    y = data.y
    # point 0 is off by 0.5 SD on y1 only, point 1 by 0.4 SD on y2 only: in SD units point 1 is better,
    # although its error in y2's unit (mV) is a thousand times larger
    sd = y.std(axis=0)
    preds = np.stack([y + [0.5 * sd[0], 0.0], y + [0.0, 0.4 * sd[1]]])
    scores = grid_scores(preds, data, "rmse")
    assert scores[1] < scores[0]
    np.testing.assert_allclose(scores, [np.sqrt(0.25 / 2), np.sqrt(0.16 / 2)])


def test_the_trajectory_figures_draw_each_target_from_the_joint_job(joint_run):
    from enginebench.reports.trajectories import simulate_run

    sims, notes = simulate_run(joint_run, trajectories=1)
    assert not notes
    by_target = {s.target: s for s in sims}
    assert set(by_target) == {"y1", "y2"} and all("arx" in s.sims for s in sims)
    m = joint_run.metrics()
    for target, s in by_target.items():
        err = np.concatenate(s.sims["arx"]) - np.concatenate(s.truth)
        stored = m[(m["metric"] == "rmse") & (m["split"] == "test") & (m["method"] == "arx") & (m["target"] == target)]
        assert np.sqrt(np.mean(err ** 2)) == pytest.approx(float(stored["value"].iloc[0]), rel=1e-9)


def test_without_joint_targets_every_method_runs_per_target(tmp_path):
    path = write_dataset(two_outputs(), tmp_path / "two.parquet")
    run = run_experiment(spec(path, joint_targets=False, methods={"arx": {"max_order": 2}}), RunStore(tmp_path / "r"),
                         workers=1).run
    assert sorted(m["target"] for m in run.job_metas().values()) == ["y1", "y2"]


def test_a_joint_neural_state_space_job_simulates_every_target_from_one_network(tmp_path):
    """neural-ss and gru model all outputs in one network: one job, a prediction per target equal to the
    network fitted on the two-target training samples directly (the joint job hands it every target)."""
    pytest.importorskip("torch")
    from enginebench.registry import get

    path = write_dataset(two_outputs(n=120), tmp_path / "two.parquet")
    options = {"hidden": 8, "layers": 1, "steps": 20, "batch_size": 8}
    run = run_experiment(spec(path, methods={"neural-ss": options}), RunStore(tmp_path / "runs"), workers=1).run
    metas = run.job_metas()
    assert [m["target"] for m in metas.values()] == [JOINT]
    assert [m["params"]["nx"] for m in metas.values()] == [16]  # 8 states per target, two targets (at most 16)
    m = run.metrics()
    test_rmse = m[(m["metric"] == "rmse") & (m["split"] == "test")]
    assert sorted(test_rmse["target"]) == ["y1", "y2"]
    assert np.isfinite(test_rmse["value"]).all()
    assert get("neural-ss").joint_targets and get("gru").joint_targets


def test_joint_narx_models_equal_the_per_target_ones_at_the_same_point():
    """narx fits one model per target in a joint job: with the exact solver each equals the model a job of that
    target alone fits at the same point (bit for bit), and the joint free run (both targets' models in one
    batch) predicts what each target's own free run predicts, to rounding."""
    from enginebench.methods.narx import NARX

    raw = RawSegments.from_dataset(two_outputs(3, n_records=3, n=200))
    both = SamplePool(raw, ["y1", "y2"], "simulation", init_samples=10).materialize()
    params = {"lags": 3, "nk": 0, "gamma": 0.1, "lambda": 1e-6}
    joint = NARX().fit(both, params, np.random.default_rng(0))
    assert joint.solver == "exact"
    predicted = NARX().predict(joint, both.without_targets())
    for k, target in enumerate(("y1", "y2")):
        alone = SamplePool(raw, [target], "simulation", init_samples=10).materialize()
        one = NARX().fit(alone, params, np.random.default_rng(0))
        np.testing.assert_array_equal(joint.models[k].beta, one.models[0].beta)
        np.testing.assert_array_equal(joint.models[k].a, one.models[0].a)
        np.testing.assert_array_equal(joint.models[k].centres, one.models[0].centres)
        own = NARX().predict(one, alone.without_targets())
        for seg_joint, seg_one in zip(predicted, own):
            # the same arithmetic per model, summed in BLAS blocks of another width: rounding, fed back over
            # 190 steps, stays below 1e-8 of the signal (a wrong target or window would be off by its size)
            scale = np.abs(seg_one).max()
            np.testing.assert_allclose(seg_joint[:, k], seg_one[:, 0], rtol=0, atol=1e-8 * scale)
