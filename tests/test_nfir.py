"""The ``nfir`` method: lagged-input features, agreement with scikit-learn's KernelRidge, BIBO and causality."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from sklearn.kernel_ridge import KernelRidge
from sklearn.preprocessing import StandardScaler

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.samples import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.methods.base import SegmentPredictions, grid_points
from enginebench.methods.nfir import NFIR, lag_feature_names, lagged_inputs, nfir_lags

DT = 0.5


def fir_dataset(n_seg: int = 4, n: int = 80, seed: int = 0) -> Dataset:
    """y(t) = u1(t) + 0.5 u1(t-2) + sin(u2(t-4)) + noise: a finite impulse response of the inputs."""
    rng = np.random.default_rng(seed)
    frames = []
    for s in range(n_seg):
        u1 = np.cumsum(rng.normal(0, 0.3, n))
        u2 = rng.uniform(-2, 2, n)
        lag = lambda x, k: np.r_[np.full(k, x[0]), x[:-k]]  # noqa: E731
        y = u1 + 0.5 * lag(u1, 2) + np.sin(lag(u2, 4)) + rng.normal(0, 0.01, n)
        frames.append(pd.DataFrame({"segment": f"s{s}", "time": np.arange(n) * DT, "u1": u1, "u2": u2, "y": y + 5.0}))
    schema = Schema.from_roles({"u1": "input", "u2": "input", "y": "output"})
    return Dataset("fir", pd.concat(frames, ignore_index=True), schema, DT)


@pytest.fixture(scope="module")
def data():
    ds = fir_dataset()
    sim = make_samples(ds, ["y"], "simulation")
    train = sim.take(np.arange(sum(len(s) for s in sim.segments[:3])))
    test = sim.take(np.arange(sum(len(s) for s in sim.segments[:3]), len(sim)))
    return train, test


PARAMS = {"horizon": 2.0, "stride": 2, "gamma": 0.5, "lambda": 1e-2}


# -- features ----------------------------------------------------------------------------------
def test_lags_reach_the_horizon_in_strides():
    assert nfir_lags(4.0, 6, 1 / 12).tolist() == [0, 6, 12, 18, 24, 30, 36, 42, 48]
    assert nfir_lags(0.0, 3, 0.5).tolist() == [0]
    assert nfir_lags(2.0, 3, 0.5).tolist() == [0, 3]  # 4 samples of horizon, stride 3


@pytest.mark.parametrize("horizon, stride, fragment", [
    (-1.0, 1, "horizon must be a number of seconds >= 0"),
    (1.0, 0, "stride must be a positive whole number of samples"),
    (1.0, 1.5, "stride must be a positive whole number of samples"),
])
def test_bad_lags_are_refused(horizon, stride, fragment):
    with pytest.raises(MethodError, match=fragment):
        nfir_lags(horizon, stride, 0.5)


def test_lagged_inputs_pad_with_the_first_row():
    U = np.column_stack([np.arange(6.0), 10 * np.arange(6.0)])
    X = lagged_inputs(U, np.array([0, 2]))
    expected = np.array([[0, 0, 0, 0], [1, 0, 10, 0], [2, 0, 20, 0], [3, 1, 30, 10], [4, 2, 40, 20], [5, 3, 50, 30]], float)
    np.testing.assert_array_equal(X, expected)
    assert lag_feature_names(["a", "b"], np.array([0, 2])) == ("a[t]", "a[t-2]", "b[t]", "b[t-2]")


# -- agreement with a reference ------------------------------------------------------------------
def test_fit_matches_sklearn_kernel_ridge_on_lagged_features(data):
    train, test = data
    m = NFIR(max_rows=0)
    fitted = m.fit(train, PARAMS, np.random.default_rng(0))
    pred = np.concatenate(m.predict(fitted, test.without_targets()))

    lags = nfir_lags(PARAMS["horizon"], PARAMS["stride"], DT)
    Xtr = np.vstack([lagged_inputs(s.U, lags) for s in train.segments])
    Xte = np.vstack([lagged_inputs(s.U, lags) for s in test.segments])
    sc = StandardScaler().fit(Xtr)
    y = train.y[:, 0]
    ref = KernelRidge(alpha=PARAMS["lambda"], kernel="rbf", gamma=PARAMS["gamma"] / Xtr.shape[1])
    ref.fit(sc.transform(Xtr), y - y.mean())
    np.testing.assert_allclose(pred[:, 0], ref.predict(sc.transform(Xte)) + y.mean(), rtol=1e-7, atol=1e-8)
    assert fitted.krls.gamma == pytest.approx(PARAMS["gamma"] / 6)  # 2 inputs x lags 0, 2, 4


def test_predict_grid_equals_fitting_each_point(data):
    train, test = data
    m = NFIR(horizons=[0.0, 2.0], strides=[2], gamma_grid=(-1, 0, 2), lambda_grid=(-3, -1, 2), max_rows=150)
    grid = grid_points(m.search_space(train))
    assert len(grid) == 8 and set(grid[0]) == {"horizon", "stride", "gamma", "lambda"}
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(3))
    for i, params in enumerate(grid):
        fitted = m.fit(train, params, np.random.default_rng(3))  # the same 150 kernel rows are drawn
        assert fitted.n_rows == 150
        np.testing.assert_allclose(out[i], np.concatenate(m.predict(fitted, test.without_targets())), rtol=1e-7, atol=1e-9)


def test_fit_is_deterministic_under_a_seed(data):
    train, test = data
    m = NFIR(max_rows=100)
    a = np.concatenate(m.predict(m.fit(train, PARAMS, np.random.default_rng(7)), test.without_targets()))
    b = np.concatenate(m.predict(m.fit(train, PARAMS, np.random.default_rng(7)), test.without_targets()))
    c = np.concatenate(m.predict(m.fit(train, PARAMS, np.random.default_rng(8)), test.without_targets()))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)  # another seed draws other kernel rows


# -- structure: inputs only, causal, bounded -------------------------------------------------------
def test_simulation_predicts_every_row_and_flags_nothing(data):
    train, test = data
    m = NFIR()
    preds = m.predict(m.fit(train, PARAMS, np.random.default_rng(0)), test.without_targets())
    assert isinstance(preds, SegmentPredictions)
    assert [p.shape for p in preds] == [(len(s.U), 1) for s in test.segments]
    assert not preds.diverged.any()


def test_outputs_never_enter_the_prediction(data):
    train, test = data
    m = NFIR()
    fitted = m.fit(train, PARAMS, np.random.default_rng(0))
    base = np.concatenate(m.predict(fitted, test.without_targets()))
    other = replace(test, segments=tuple(replace(s, y=s.y * 0 + 1e6, y0=s.y0 * 0 - 1e6) for s in test.segments))
    np.testing.assert_array_equal(np.concatenate(m.predict(fitted, other)), base)


def test_prediction_is_causal(data):
    train, test = data
    m = NFIR()
    fitted = m.fit(train, PARAMS, np.random.default_rng(0))
    seg = test.segments[0]
    r = 30
    U = seg.U.copy()
    U[r + 1:] += 5.0  # change only the future of row r
    changed = replace(test, segments=(replace(seg, U=U, X=U[seg.rows]),))
    a = m.predict(fitted, replace(test, segments=(seg,)).without_targets())[0]
    b = m.predict(fitted, changed.without_targets())[0]
    np.testing.assert_array_equal(a[: r + 1], b[: r + 1])
    assert not np.allclose(a[r + 1:], b[r + 1:])


def test_bibo_bound_and_decay_to_the_training_mean_far_from_data(data):
    train, test = data
    m = NFIR()
    fitted = m.fit(train, PARAMS, np.random.default_rng(0))
    seg = test.segments[0]
    for amplitude in (1e2, 1e6):
        U = seg.U * amplitude
        far = replace(test, segments=(replace(seg, U=U, X=U[seg.rows]),))
        pred = m.predict(fitted, far.without_targets())[0][:, 0]
        bound = abs(fitted.krls.y_mean[0]) + np.abs(fitted.krls.alpha).sum()  # |K| <= 1
        assert np.all(np.abs(pred) <= bound)
    np.testing.assert_allclose(pred[10:], fitted.krls.y_mean[0], atol=1e-9)  # every kernel value underflows


def test_first_row_sees_the_first_sample_held(data):
    train, test = data
    m = NFIR()
    fitted = m.fit(train, PARAMS, np.random.default_rng(0))
    seg = test.segments[0]
    held = np.repeat(seg.U[:1], len(seg.U), axis=0)
    const = replace(test, segments=(replace(seg, U=held, X=held[seg.rows]),))
    a = m.predict(fitted, replace(test, segments=(seg,)).without_targets())[0][0]
    b = m.predict(fitted, const.without_targets())[0]
    np.testing.assert_allclose(b[:, 0], b[0, 0], rtol=0, atol=1e-12)  # constant input, constant output
    np.testing.assert_allclose(a, b[0], rtol=0, atol=1e-12)


def test_static_mode_uses_the_segments_own_history():
    ds = fir_dataset(n_seg=3, n=60)
    sim, static = make_samples(ds, ["y"], "simulation"), make_samples(ds, ["y"], "static")
    m = NFIR()
    a = m.predict(m.fit(sim, PARAMS, np.random.default_rng(0)), sim.without_targets())
    rows = np.array([5, 70, 150])
    sub = static.take(rows)  # static rows drawn at random keep their segment's raw inputs
    b = np.concatenate(m.predict(m.fit(static, PARAMS, np.random.default_rng(0)), sub.without_targets()))
    np.testing.assert_allclose(b, np.concatenate(list(a))[rows], rtol=1e-10)


# -- errors --------------------------------------------------------------------------------------
def test_window_mode_and_bad_options_are_refused(data):
    train, _ = data
    with pytest.raises(MethodError, match="does not support mode 'window'"):
        NFIR().check_mode("window")
    with pytest.raises(MethodError, match="option horizons must be a non-empty list"):
        NFIR(horizons=[])
    with pytest.raises(MethodError, match="option max_rows must be an integer >= 0"):
        NFIR(max_rows=-1)
    with pytest.raises(MethodError, match="option inputs names nope, which are not run-time inputs"):
        NFIR(inputs=["nope"]).fit(train, PARAMS, np.random.default_rng(0))
    with pytest.raises(MethodError, match=r"hyperparameter\(s\) stride missing"):
        NFIR().fit(train, {"horizon": 1.0, "gamma": 1.0, "lambda": 1.0}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="hyperparameter 'lambda' must be a positive finite number"):
        NFIR().fit(train, {**PARAMS, "lambda": 0.0}, np.random.default_rng(0))


def test_nan_input_is_named(data):
    train, _ = data
    seg = train.segments[1]
    U = seg.U.copy()
    U[7, 1] = np.nan
    bad = replace(train, segments=(train.segments[0], replace(seg, U=U, X=U[seg.rows])))
    with pytest.raises(MethodError, match=r"segment 's1' has nan/inf in input 'u2' at row 7"):
        NFIR().fit(bad, PARAMS, np.random.default_rng(0))
