"""``boost-fir``: predictions equal scikit-learn's HistGradientBoosting on the same lagged inputs, the
horizons come from the data's memory, importances find the input that drives the output, conformance."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.errors import MethodError
from enginebench.methods.boost_fir import BoostFIR
from enginebench.methods.nfir_memory import lagged_inputs
from helpers import linear_raw, sim_samples


def test_predictions_equal_scikit_learn_on_the_same_lagged_inputs():
    from sklearn.ensemble import HistGradientBoostingRegressor

    train, test = sim_samples(linear_raw(3, 200, seed=1)), sim_samples(linear_raw(1, 150, seed=2), 5)
    m = BoostFIR(max_iter=30)
    fitted = m.fit(train, {"horizon": 3.0}, np.random.default_rng(7))
    lags = np.arange(0, 4)
    X = np.vstack([lagged_inputs(s.U, lags, s.rows) for s in train.segments])
    seed = int(np.random.default_rng(7).integers(0, 2**31 - 1, size=1)[0])
    ref = HistGradientBoostingRegressor(max_iter=30, early_stopping=False, random_state=seed).fit(X, train.y[:, 0])
    got = np.concatenate(m.predict(fitted, test.without_targets()))
    Xe = np.vstack([lagged_inputs(s.U, lags, s.rows) for s in test.segments])
    np.testing.assert_array_equal(got[:, 0], ref.predict(Xe))


def test_importance_ranks_the_driving_input_first():
    rng = np.random.default_rng(0)
    import pandas as pd

    from enginebench.datasets.dataset import Dataset
    from enginebench.datasets.pools import RawSegments, SamplePool
    from enginebench.datasets.schema import Schema

    n = 600
    u1, u2 = rng.normal(size=n), rng.normal(size=n)
    y = np.tanh(u1) + 0.5 * np.r_[0.0, u1[:-1]]  # u2 does nothing
    ds = Dataset("d", pd.DataFrame({"segment": "s0", "time": np.arange(n), "u1": u1, "u2": u2, "y": y}),
                 Schema.from_roles({"u1": "input", "u2": "input", "y": "output"}), 1.0)
    train = SamplePool(RawSegments.from_dataset(ds), ["y"], "simulation").materialize()
    fitted = BoostFIR(max_iter=50).fit(train, {"horizon": 2.0}, np.random.default_rng(0))
    imp = BoostFIR().describe(fitted)["importance"]["targets"]["y"]
    assert list(imp["by_input"]) == ["u1", "u2"]
    assert imp["by_input"]["u1"] > 10 * max(imp["by_input"]["u2"], 1e-3)
    assert next(iter(imp["top_features"])) == "u1[t]"


def test_derived_horizons_come_from_the_memory_estimate():
    train = sim_samples(linear_raw(3, 300))
    m = BoostFIR()
    space = m.search_space(train)
    assert space["horizon"].tolist() == [h * train.dt for h in m.memory(train).grid]


def test_bad_hyperparameters_are_one_line():
    train = sim_samples(linear_raw(2, 100))
    with pytest.raises(MethodError, match="method 'boost-fir': hyperparameter\\(s\\) horizon missing"):
        BoostFIR().fit(train, {}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="learning_rate"):
        BoostFIR(learning_rate=0)


def test_the_memory_estimate_is_computed_once_per_training_set_when_fold_fits_alternate(monkeypatch):
    """Selection fits each horizon on every fold's training set in turn: the estimate of each set is kept, so
    three training sets fitted at two horizons each are estimated three times, and the estimates are the ones a
    fresh method computes."""
    import enginebench.methods.input_history as history

    calls = []
    real = history.estimate_memory
    monkeypatch.setattr(history, "estimate_memory", lambda *a, **k: calls.append(1) or real(*a, **k))
    sets = [sim_samples(linear_raw(2, 120 + 10 * k, seed=k)) for k in range(3)]
    m = BoostFIR(max_iter=5)
    fits = [m.fit(train, {"horizon": h}, np.random.default_rng(0)) for h in (1.0, 2.0) for train in sets]
    assert len(calls) == 3
    for fitted, train in zip(fits, sets * 2):
        assert fitted.memory == BoostFIR().memory(train)
