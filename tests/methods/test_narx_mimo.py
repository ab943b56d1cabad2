"""narx with ``shared_kernel = true``: one kernel for every output (a MIMO NARX, each output reading every
output's past). With one output it is the single-output narx; its batched free run equals a plain per-step
reference; it recovers a system whose second output is driven by the first output's past, which one kernel
per output (reading only its own past and the inputs) cannot; grid batching equals fit-then-predict."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.schema import Column, Schema
from enginebench.method import grid_points
from enginebench.methods.freerun import training_trajectories
from enginebench.methods.narx import NARX
from enginebench.methods.narx_model import free_run, mimo_free_run, standardise
from enginebench.samples import Samples

PARAMS = {"lags": 2, "nk": 0, "gamma": 0.1, "lambda": 1e-7}


def coupled(u: np.ndarray) -> np.ndarray:
    """y1(t) = 0.6 y1(t-1) + tanh(u(t-1));  y2(t) = 0.3 y2(t-1) + 0.5 y1(t-1)^2 - 0.4 y1(t-2)."""
    y = np.zeros((len(u), 2))
    for t in range(2, len(u)):
        y[t, 0] = 0.6 * y[t - 1, 0] + np.tanh(u[t - 1])
        y[t, 1] = 0.3 * y[t - 1, 1] + 0.5 * y[t - 1, 0] ** 2 - 0.4 * y[t - 2, 0]
    return y


def dataset(n_records: int, n: int, seed: int, amplitude: float = 1.5) -> Dataset:
    rng = np.random.default_rng(seed)
    frames = []
    for k in range(n_records):
        u = rng.uniform(-amplitude, amplitude, n)
        y = coupled(u)
        frames.append(pd.DataFrame({SEGMENT: f"r{k}", TIME: np.arange(n) * 0.1, "u": u, "y1": y[:, 0],
                                    "y2": 10.0 * y[:, 1] + 3.0}))
    schema = Schema((Column("u", "input"), Column("y1", "output"), Column("y2", "output")))
    return Dataset("coupled", pd.concat(frames, ignore_index=True), schema, 0.1, {})


def raw(n_records: int, n: int, seed: int, amplitude: float = 1.5) -> RawSegments:
    return RawSegments.from_dataset(dataset(n_records, n, seed, amplitude))


def samples(r: RawSegments, targets: list[str], init: int = 0) -> Samples:
    return SamplePool(r, targets, "simulation", init_samples=init).materialize()


@pytest.fixture(scope="module")
def data() -> tuple[Samples, Samples]:
    return samples(raw(3, 200, 0), ["y1", "y2"]), samples(raw(2, 300, 1), ["y1", "y2"], init=5)


@pytest.fixture(scope="module")
def shared(data):
    return NARX(shared_kernel=True).fit(data[0], PARAMS, np.random.default_rng(0))


def test_with_one_output_the_shared_kernel_is_the_single_output_model():
    train = samples(raw(3, 200, 0), ["y1"])
    std = standardise(training_trajectories("narx", train), 0.5)
    point = [(3, 2, 0, 0.3, 1e-6)]
    mimo = NARX(shared_kernel=True)._mimo_models(std, 1, point, np.random.default_rng(0))[0][0]
    one = NARX()._models(std, 1, point, np.random.default_rng(0))[0][0][0]
    np.testing.assert_array_equal(mimo.centres, one.centres)
    np.testing.assert_allclose(mimo.beta[:, 0], one.beta, rtol=1e-9, atol=1e-9 * np.abs(one.beta).max())
    np.testing.assert_allclose(mimo.a[:, 0, 0], one.a, rtol=0, atol=1e-9)
    np.testing.assert_allclose(mimo.b[..., 0], one.b, rtol=0, atol=1e-9)
    rng = np.random.default_rng(3)
    U = [rng.normal(size=(120, 1)), rng.normal(size=(90, 1))]
    W = [rng.normal(size=(4, 1)), rng.normal(size=(4, 1))]
    a = mimo_free_run([mimo], U, W, [120, 90])[0, :, :, 0]
    b = free_run([one], U, W, [120, 90])[0]
    np.testing.assert_allclose(a[0], b[0], rtol=0, atol=1e-8)
    np.testing.assert_allclose(a[1, :90], b[1, :90], rtol=0, atol=1e-8)


def reference_run(fit, U: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The MIMO free run written out step by step: z(t) from every output's last ka values and the inputs."""
    m = fit.mimo
    k = m.k
    ys = [list(row) for row in (window - fit.y_mean) / fit.y_std]
    us = (U - fit.u_mean) / fit.u_std

    def y_at(t, p):
        return ys[max(t, 0)][p]

    def u_at(t, j):
        return us[max(t, 0), j]

    box = fit.kernel_box()
    for t in range(len(window), len(U)):  # the kernel reads its regressors clipped to the training range
        z = [np.clip(y_at(t - i, p), box.y_lo[p], box.y_hi[p]) for p in range(k) for i in range(m.ka, 0, -1)]
        z += [np.clip(u_at(t - m.nk - l, j), box.u_lo[j], box.u_hi[j]) for j in range(us.shape[1])
              for l in range(m.kb)]
        kern = np.exp(-m.gamma / m.d * ((m.centres - np.array(z)) ** 2).sum(axis=1)) @ m.beta
        new = []
        for o in range(k):
            lin = m.c0[o] + sum(m.a[i - 1, p, o] * y_at(t - i, p) for i in range(1, m.na + 1) for p in range(k))
            lin += sum(m.b[j, l, o] * u_at(t - m.nk - l, j) for j in range(us.shape[1]) for l in range(m.nb))
            new.append(lin + kern[o])
        ys.append(new)
    return np.array(ys) * fit.y_std + fit.y_mean


def test_the_batched_free_run_equals_the_step_by_step_reference(data, shared):
    _, test = data
    assert shared.mimo is not None and shared.models == () and shared.mimo.beta.shape[1] == 2
    pred = NARX(shared_kernel=True).predict(shared, test.without_targets())
    assert not pred.diverged.any()
    for seg, p in zip(test.segments, pred):
        np.testing.assert_allclose(p, reference_run(shared, seg.U, seg.y_init)[5:], rtol=0, atol=1e-9)


def test_beyond_the_training_range_the_shared_kernel_reads_its_edge(data):
    """``kernel_box = true``, inputs at three times the training amplitude: the batched run equals the reference
    with the kernel's regressors clipped to the training range (and the C step equals the run), and the clip
    changes the run."""
    shared = NARX(shared_kernel=True, kernel_box=True).fit(data[0], PARAMS, np.random.default_rng(0))
    far = samples(raw(2, 300, 2, amplitude=4.5), ["y1", "y2"], init=5)
    view = far.without_targets()
    pred = NARX(shared_kernel=True).predict(shared, view)
    loose = NARX(shared_kernel=True).predict(replace(shared, box=None), view)
    for k, seg in enumerate(far.segments):
        np.testing.assert_allclose(pred[k], reference_run(shared, seg.U, seg.y_init)[5:], rtol=0, atol=1e-9)
        assert np.abs(loose[k] - pred[k]).max() > 1e-3
    from enginebench.methods.export.harness import compiler, run_c

    if compiler() is not None:
        model = NARX(shared_kernel=True).c_model(shared)
        for seg, p in zip(view.segments, pred):
            Y, _, diverged = run_c(model, seg.U, seg.y_init, len(seg.y_init))
            assert not diverged
            np.testing.assert_allclose(Y[len(seg.y_init):], p, rtol=0, atol=1e-9 * np.abs(p).max())


def test_an_output_driven_by_another_outputs_past_is_recovered_only_with_the_shared_kernel(data, shared):
    train, test = data
    own = NARX().fit(train, PARAMS, np.random.default_rng(0))
    truth = np.concatenate([s.y for s in test.segments])
    err_shared = np.concatenate(list(NARX(shared_kernel=True).predict(shared, test.without_targets()))) - truth
    err_own = np.concatenate(list(NARX().predict(own, test.without_targets()))) - truth
    rel_shared = np.sqrt((err_shared ** 2).mean(axis=0)) / truth.std(axis=0)
    rel_own = np.sqrt((err_own ** 2).mean(axis=0)) / truth.std(axis=0)
    # measured: shared 0.048 / 0.094 of each output's spread; y2's own kernel, reading its own past and u(t),
    # u(t-1) but not y1(t-1), y1(t-2), is no better than its mean (1.13)
    assert rel_shared.max() < 0.15
    assert rel_own[1] > 0.8 and rel_own[1] > 5 * rel_shared[1]


def test_predict_grid_batches_shared_kernel_candidates_like_fit_then_predict(data):
    train, test = samples(raw(2, 100, 5), ["y1", "y2"]), data[1]
    m = NARX(shared_kernel=True)
    grid = grid_points({"lags": np.array([1, 2]), "nk": np.array([0]), "gamma": np.array([0.1, 1.0]),
                        "lambda": np.array([1e-5, 1e-2])})
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert out.shape == (len(grid), len(test), 2)
    for i, p in enumerate(grid):
        one = np.concatenate(m.predict(m.fit(train, p, np.random.default_rng(0)), test.without_targets()))
        np.testing.assert_allclose(out[i], one, rtol=0, atol=1e-9)


def test_describe_names_the_shared_model(shared):
    d = NARX(shared_kernel=True).describe(shared)
    assert d["shared_kernel"] is True and d["regressors"] == 2 * 2 + 2 and d["linear_part"]["stable"]


def test_the_c_step_of_a_shared_kernel_model_simulates_what_predict_does(data, shared):
    from enginebench.methods.export.harness import compiler, run_c

    if compiler() is None:
        pytest.skip("no C compiler (gcc or cc) on this machine")
    test = data[1].without_targets()
    model = NARX(shared_kernel=True).c_model(shared)
    for seg, pred in zip(test.segments, NARX(shared_kernel=True).predict(shared, test)):
        Y, _, diverged = run_c(model, seg.U, seg.y_init, len(seg.y_init))
        assert not diverged
        np.testing.assert_allclose(Y[len(seg.y_init):], pred, rtol=0, atol=1e-9 * np.abs(pred).max())


def test_a_shared_kernel_model_is_stored_and_read_back_bit_for_bit(data, shared):
    import json

    from enginebench.results.model_store import _decode, _Encoder

    enc = _Encoder(("enginebench.",))
    back = _decode(json.loads(json.dumps(enc.encode(shared))), enc.arrays, ("enginebench.",))
    test = data[1].without_targets()
    for a, b in zip(NARX(shared_kernel=True).predict(shared, test), NARX(shared_kernel=True).predict(back, test)):
        assert a.tobytes() == b.tobytes()


def test_a_joint_experiment_runs_one_shared_kernel_job_and_tables_each_target(tmp_path):
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.jobs import JOINT
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    path = write_dataset(dataset(4, 200, 2), tmp_path / "c.parquet")
    spec = from_dict({"name": "mimo", "dataset": str(path), "targets": "all", "mode": "simulation",
                      "repetitions": 1, "train_size": 0, "init_samples": 5, "joint_targets": True,
                      "split": {"kind": "records", "train": ["r0", "r1", "r2"], "test": ["r3"]},
                      "selection": {"kind": "kfold", "folds": 2, "criterion": "rmse"},
                      "methods": {"narx": {"shared_kernel": True, "na": [2], "nb": [2], "gamma_grid": [-1, -1, 1],
                                           "lambda_grid": [-7, -7, 1]}}}, origin="test")
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    metas = [m for m in run.job_metas().values() if m["method"] == "narx"]
    assert [m["target"] for m in metas] == [JOINT] and metas[0]["status"] == "ok"
    m = run.metrics()
    rmse = m[(m["metric"] == "rmse") & (m["split"] == "test") & (m["method"] == "narx")]
    assert sorted(rmse["target"]) == ["y1", "y2"]
