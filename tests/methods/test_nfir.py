"""The ``nfir`` method: lagged-input features, agreement with scikit-learn's KernelRidge, BIBO and causality."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from sklearn.kernel_ridge import KernelRidge
from sklearn.preprocessing import StandardScaler

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import SegmentPredictions, grid_points
from enginebench.methods.nfir import NFIR
from enginebench.methods.nfir_memory import (
    bounded_stride, estimate_memory, lag_feature_names, lagged_inputs, memory_ladder, nfir_lags,
)

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


def test_a_missing_stride_keeps_the_lag_count_bounded(data):
    train, _ = data
    assert [bounded_stride(h, 16) for h in (0, 1, 15, 16, 30, 31, 1000)] == [1, 1, 1, 2, 2, 3, 67]
    fitted = NFIR(max_lags=4).fit(train, {"horizon": 4.5, "gamma": 0.5, "lambda": 1e-2}, np.random.default_rng(0))
    assert fitted.lags.tolist() == [0, 3, 6, 9] and fitted.stride == 3  # 9 samples of 0.5 s in at most 4 lags
    assert NFIR(max_lags=4).describe(fitted)["horizon_samples"] == 9


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


def test_predict_grid_over_derived_horizons_equals_each_point_to_1e_9(data):
    """The shared-work grid path (per lag set the distances once, per gamma one solver call for every lambda)
    predicts what fitting each point alone predicts, over every derived horizon and gamma."""
    train, test = data
    m = NFIR(gamma_grid=(-3, 0, 4), lambda_grid=(-3, 0, 4), max_rows=120)
    grid = grid_points(m.search_space(train))
    assert len({p["horizon"] for p in grid}) >= 2 and len(grid) >= 32
    view = test.without_targets()
    out = m.predict_grid(train, view, grid, np.random.default_rng(5))
    scale = np.abs(np.concatenate([s.y for s in test.segments])).max()
    for i, params in enumerate(grid):
        alone = np.concatenate(m.predict(m.fit(train, params, np.random.default_rng(5)), view))
        np.testing.assert_allclose(out[i], alone, rtol=0, atol=1e-9 * scale)


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
    with pytest.raises(MethodError, match=r"hyperparameter\(s\) horizon missing"):
        NFIR().fit(train, {"stride": 1, "gamma": 1.0, "lambda": 1.0}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="option max_lags must be a whole number >= 2"):
        NFIR(max_lags=1)
    with pytest.raises(MethodError, match=r"option strides must be a non-empty list or None \(derive"):
        NFIR(strides=6)
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


# -- horizons derived from the data --------------------------------------------------------------
def lowpass(x: np.ndarray, tau: float) -> np.ndarray:
    """First-order discrete low-pass with a time constant of ``tau`` samples and unit gain."""
    from scipy.signal import lfilter

    a = np.exp(-1.0 / tau)
    return lfilter([1 - a], [1, -a], x, axis=0)


def first_order_dataset(tau: float, dt: float, n_seg: int = 4, n: int = 400, seed: int = 0) -> Dataset:
    """y = a first-order lag (tau samples) of a smooth input u plus 0.3 u^2: memory ~ 3 tau samples."""
    rng = np.random.default_rng(seed)
    frames = []
    for s in range(n_seg):
        u = lowpass(rng.normal(0, 3.0, n), 5.0)
        y = lowpass(u + 0.3 * u ** 2, tau) + rng.normal(0, 0.01, n)
        frames.append(pd.DataFrame({"segment": f"s{s}", "time": np.arange(n) * dt, "u": u, "y": y + 20.0}))
    return Dataset("lag", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "y": "output"}), dt)


def test_memory_ladder_and_the_estimate_on_known_first_order_systems():
    assert memory_ladder(1).tolist() == [0, 1] and memory_ladder(20).tolist() == [0, 1, 2, 4, 8, 16, 20]
    rng = np.random.default_rng(1)
    u = lowpass(rng.normal(size=(20000, 1)), 20.0)
    for tau in (3.0, 10.0, 40.0):
        est = estimate_memory([u], [np.arange(20000)], [lowpass(u, tau)], 16)
        assert est.grid[0] <= 3 * tau <= est.grid[-1], (tau, est)  # the grid brackets the 95 % settling time
        assert len(est.grid) == 3 and est.cap == 5000 and not est.warnings()
    # a static map of a slowly wandering input has no memory, however long the input's own correlation
    w = np.cumsum(rng.normal(size=(5000, 1)), axis=0)
    est = estimate_memory([w], [np.arange(5000)], [np.tanh(w / 20)], 16)
    assert est.samples == 0 and est.grid == (0, 1, 2)


def test_derived_horizons_are_the_same_samples_at_1_ms_and_10_s():
    """Only the data's samples matter: the grid in samples, the lags and the predictions are identical."""
    preds, grids = [], []
    for dt in (1e-3, 10.0):
        sim = make_samples(first_order_dataset(6.0, dt), ["y"], "simulation")
        m = NFIR(max_rows=200)
        space = m.search_space(sim)
        grids.append(np.round(space["horizon"] / dt).astype(int).tolist())
        params = {"horizon": space["horizon"][1], "gamma": 0.1, "lambda": 1e-3}
        fitted = m.fit(sim, params, np.random.default_rng(0))
        preds.append(np.concatenate(m.predict(fitted, sim.without_targets())))
        d = m.describe(fitted)
        assert d["horizons_derived"]["grid_samples"] == grids[-1] and d["horizon_samples"] == grids[-1][1]
        assert d["horizons_derived"]["memory_s"] == pytest.approx(d["horizons_derived"]["memory_samples"] * dt)
        assert "stride" not in space and len(d["lags_samples"]) <= 16
    # a first-order lag's squared error left after h samples falls to 5 % near h = 1.5 tau = 9
    assert grids[0] == grids[1] and grids[0][0] <= 9 <= grids[0][-1]
    np.testing.assert_allclose(preds[0], preds[1], rtol=1e-10)


def _selected_test_rmse(m: NFIR, train, val, test) -> float:
    grid = grid_points(m.search_space(train))
    out = m.predict_grid(train, val.without_targets(), grid, np.random.default_rng(0))
    best = grid[int(np.argmin(np.mean((out - val.y[None]) ** 2, axis=(1, 2))))]
    fitted = m.fit(train, best, np.random.default_rng(0))
    return float(np.sqrt(np.mean((np.concatenate(m.predict(fitted, test.without_targets())) - test.y) ** 2)))


def test_a_record_sampled_every_few_seconds_keeps_its_memory():
    """The reported failure: at dt = 5 s turboshaft-moe's horizons (2-8 s) are one sample, so NFIR was a static map and no
    better than the training mean. The derived horizons see the system's 30-sample memory."""
    sim = make_samples(first_order_dataset(10.0, 5.0, n_seg=5, n=300), ["y"], "simulation")
    edges = np.cumsum([len(s) for s in sim.segments])
    train, val, test = (sim.take(np.arange(a, b)) for a, b in ((0, edges[2]), (edges[2], edges[3]), (edges[3], edges[4])))
    small = {"gamma_grid": (-3, -1, 3), "lambda_grid": (-6, -2, 3), "max_rows": 400}
    old = NFIR(horizons=[2.0, 4.0, 8.0], strides=[6, 12], **small)
    assert {tuple(nfir_lags(h, s, 5.0)) for h in (2.0, 4.0, 8.0) for s in (6, 12)} == {(0,)}  # static
    derived = _selected_test_rmse(NFIR(**small), train, val, test)
    static = _selected_test_rmse(old, train, val, test)
    mean = float(np.sqrt(np.mean((test.y - train.y.mean()) ** 2)))
    assert derived < 0.3 * mean and derived < 0.5 * static


def test_static_mode_rows_give_the_same_memory_as_whole_trajectories():
    ds = first_order_dataset(6.0, 1.0)
    sim, static = make_samples(ds, ["y"], "simulation"), make_samples(ds, ["y"], "static")
    rows = np.sort(np.random.default_rng(0).choice(len(static), 800, replace=False))  # a random row subsample
    a, b = NFIR().memory(sim), NFIR().memory(static.take(rows))
    assert a.grid == b.grid and b.rows == 800


def test_memory_warnings_reach_describe():
    rng = np.random.default_rng(0)
    n = 80
    frames = []
    for k in range(4):
        u = lowpass(rng.normal(size=n), 3.0)
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": np.arange(n) * 1.0, "u": u,
                                    "y": lowpass(u, 200.0), "z": rng.normal(size=n)}))
    ds = Dataset("drift", pd.concat(frames, ignore_index=True),
                 Schema.from_roles({"u": "input", "y": "output", "z": "output"}), 1.0)
    params = {"horizon": 1.0, "gamma": 0.1, "lambda": 1e-3}
    slow = make_samples(ds, ["y"], "simulation")  # a 200-sample time constant in 80-sample records
    m = NFIR()
    d = m.describe(m.fit(slow, params, np.random.default_rng(0)))
    assert d["horizons_derived"]["memory_samples"] == d["horizons_derived"]["cap_samples"] == 20
    assert d["horizons_derived"]["grid_samples"] == [10, 20]
    assert any("reached its cap of 20 samples" in w for w in d["warnings"])
    noise = make_samples(ds, ["z"], "simulation")  # an output the input does not explain
    d = m.describe(m.fit(noise, params, np.random.default_rng(0)))
    assert any("NFIR may not beat the training mean" in w for w in d["warnings"])
    assert d["horizons_derived"]["memory_samples"] == 0
    explicit = NFIR(horizons=[1.0])
    assert "warnings" not in explicit.describe(explicit.fit(noise, params, np.random.default_rng(0)))


def test_nan_target_is_named_before_the_memory_estimate(data):
    train, _ = data
    seg = train.segments[2]
    y = seg.y.copy()
    y[11, 0] = np.nan
    bad = replace(train, segments=(*train.segments[:2], replace(seg, y=y)))
    with pytest.raises(MethodError, match=r"segment 's2' has nan/inf in target 'y' at row 11; clean or drop it"):
        NFIR().search_space(bad)
