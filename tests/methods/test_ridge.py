"""The ridge baseline: conformance, agreement with a reference solve, one SVD for the whole grid, and selection."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.linear_model import Ridge as SkRidge
from sklearn.preprocessing import StandardScaler

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.experiments.selection import select
from enginebench.experiments.spec import Selection
from enginebench.methods.ridge import ALPHA_BOUND, Ridge
from enginebench.registry import get

RNG = np.random.default_rng(0)


def _dataset(seed: int, n: int = 90, y=None, x=None) -> Dataset:
    """Two segments of four inputs on unequal scales (two nearly collinear) and two linear-plus-noise outputs
    (or the inputs ``x`` and first output ``y`` given)."""
    rng = np.random.default_rng(seed)
    if x is None:
        x = rng.normal(size=(n, 4)) * [300.0, 0.01, 5.0, 1.0] + [1000.0, 0.5, 15.0, 0.0]
        x[:, 3] = x[:, 2] / 5.0 + 1e-3 * rng.normal(size=n)  # nearly collinear with x3: the penalty matters
    y1 = 0.02 * x[:, 0] + 400 * x[:, 1] - x[:, 2] + rng.normal(0, 0.5, n) if y is None else y
    y2 = -3.0 * x[:, 3] + 0.001 * x[:, 0] + rng.normal(0, 0.1, n)
    half = n // 2
    frame = pd.DataFrame({"segment": ["a"] * half + ["b"] * (n - half),
                          "time": np.r_[np.arange(half), np.arange(n - half)].astype(float),
                          "x1": x[:, 0], "x2": x[:, 1], "x3": x[:, 2], "x4": x[:, 3], "y1": y1, "y2": y2})
    roles = {"x1": "input", "x2": "input", "x3": "input", "x4": "input", "y1": "output", "y2": "output"}
    return Dataset(name="linear", frame=frame, schema=Schema.from_roles(roles), dt=1.0)


TRAIN = make_samples(_dataset(1), ["y1", "y2"])
TEST = make_samples(_dataset(2, n=40), ["y1", "y2"]).without_targets()


def _predict(method: Ridge, train, test, alpha: float) -> np.ndarray:
    return np.concatenate(method.predict(method.fit(train, {"alpha": alpha}, RNG), test))


def test_registered_in_static_and_window_modes():
    assert get("ridge") is Ridge and Ridge.modes == {"static", "window"}  # conformance: test_conformance_registry.py


@pytest.mark.parametrize("alpha", [1e-6, 1e-2, 0.3, 10.0, 1e3])
def test_fit_equals_sklearn_ridge_and_the_augmented_least_squares(alpha):
    scaler = StandardScaler().fit(TRAIN.X)
    Xs, Xe = scaler.transform(TRAIN.X), scaler.transform(TEST.X)
    n = len(Xs)
    sk = SkRidge(alpha=alpha * n, solver="svd").fit(Xs, TRAIN.y).predict(Xe)
    # the augmented system [s(X); sqrt(alpha n) I] w = [y - mean; 0], solved by lstsq
    yc = TRAIN.y - TRAIN.y.mean(axis=0)
    A = np.vstack([Xs, np.sqrt(alpha * n) * np.eye(Xs.shape[1])])
    w = np.linalg.lstsq(A, np.vstack([yc, np.zeros((Xs.shape[1], 2))]), rcond=None)[0]
    reference = Xe @ w + TRAIN.y.mean(axis=0)
    ours = _predict(Ridge(), TRAIN, TEST, alpha)
    np.testing.assert_allclose(sk, reference, rtol=1e-9, atol=0)
    np.testing.assert_allclose(ours, reference, rtol=1e-9, atol=1e-9 * np.abs(reference).max())


def test_penalty_is_relative_to_the_training_rows():
    """The same alpha on the rows repeated twice (n doubled, the Gram doubled) gives the same model."""
    twice = TRAIN.take(np.r_[np.arange(len(TRAIN)), np.arange(len(TRAIN))])
    np.testing.assert_allclose(_predict(Ridge(), twice, TEST, 0.5), _predict(Ridge(), TRAIN, TEST, 0.5), rtol=1e-10)


def test_predict_grid_equals_fitting_each_alpha_alone():
    method = Ridge()
    grid = [{"alpha": a} for a in np.logspace(-6, 4, 11)]
    out = method.predict_grid(TRAIN, TEST, grid, RNG)
    assert out.shape == (len(grid), len(TEST), 2)
    for i, point in enumerate(grid):
        alone = _predict(method, TRAIN, TEST, point["alpha"])
        np.testing.assert_allclose(out[i], alone, rtol=1e-10, atol=1e-10 * np.abs(alone).max())
    assert not np.allclose(out[0], out[-1])  # the penalty changes the predictions
    assert not method.keeps_grid_models()  # the selected model is refitted


def test_joint_targets_equal_each_target_alone():
    assert Ridge.joint_targets
    joint = _predict(Ridge(), TRAIN, TEST, 0.1)
    for j, target in enumerate(("y1", "y2")):
        alone = _predict(Ridge(), make_samples(_dataset(1), [target]), make_samples(_dataset(2, n=40), [target]), 0.1)
        np.testing.assert_allclose(joint[:, [j]], alone, rtol=1e-10)


def test_scale_safe_features_and_targets():
    """Features times 1e-200 and targets times 1e200 predict the unscaled predictions times 1e200."""
    rng = np.random.default_rng(3)
    x, noise = rng.normal(size=(60, 4)), rng.normal(size=60)

    def samples(scale_x: float, scale_y: float, rows: slice):
        xs = x[rows] * scale_x
        ds = _dataset(5, n=len(xs), x=xs.copy(), y=(x[rows] @ [1.0, -2.0, 0.5, 0.0] + 0.1 * noise[rows]) * scale_y)
        return make_samples(ds, ["y1"])

    plain = _predict(Ridge(), samples(1.0, 1.0, slice(0, 40)), samples(1.0, 1.0, slice(40, 60)), 1e-2)
    scaled = _predict(Ridge(), samples(1e-200, 1e200, slice(0, 40)), samples(1e-200, 1e200, slice(40, 60)), 1e-2)
    assert np.all(np.isfinite(scaled))
    np.testing.assert_allclose(scaled / 1e200, plain, rtol=1e-9)


def _shrink_problem(validation_slope: float):
    """Training y = 3 + 2 x; validation on the same x with y = 3 + 2 mean(x) + slope (x - mean(x)).

    With one standardised feature the ridge slope is 2 / (1 + alpha) (alpha relative to the rows), so the validation
    error is zero at alpha = 2 / slope - 1 and larger at every other alpha."""
    x = np.linspace(-1.0, 3.0, 41)
    frame = pd.DataFrame({"segment": "s", "time": np.arange(len(x), dtype=float), "x": x})
    schema = Schema.from_roles({"x": "input", "y": "output"})
    train = make_samples(Dataset("shrink", frame.assign(y=3 + 2 * x), schema, 1.0), ["y"])
    truth = 3 + 2 * x.mean() + validation_slope * (x - x.mean())
    return train, make_samples(Dataset("shrink", frame.assign(y=truth), schema, 1.0), ["y"])


def test_selection_picks_the_known_optimum():
    train, validation = _shrink_problem(validation_slope=1.0)  # optimum alpha = 1
    chosen, record = select(Ridge(alpha_grid=(-3, 3, 13)), train, Selection(kind="validation"), RNG,
                            validation=validation)
    assert chosen["alpha"] == pytest.approx(1.0, rel=1e-12)
    assert record["best_score"] < 1e-12
    assert "extended" not in record


def test_selection_extends_past_the_grid_edge_up_to_the_bound():
    """A validation target at the training mean wants the largest penalty: the search runs to the declared bound."""
    train, validation = _shrink_problem(validation_slope=0.0)
    chosen, record = select(Ridge(alpha_grid=(-3, 3, 13)), train, Selection(kind="validation"), RNG,
                            validation=validation)
    assert chosen["alpha"] == pytest.approx(ALPHA_BOUND[1], rel=1e-9)
    assert max(record["extended"]["alpha"]) == pytest.approx(ALPHA_BOUND[1], rel=1e-9)
    assert Ridge().search_bounds(train) == {"alpha": ALPHA_BOUND}


@pytest.mark.parametrize("params, message", [
    ({"alpha": -1.0}, "hyperparameter 'alpha' must be one positive finite number, got -1.0"),
    ({"alpha": "big"}, "hyperparameter 'alpha' must be one positive finite number, got 'big'"),
    ({"alpha": 1.0, "gamma": 2.0}, "unknown hyperparameter(s) gamma; it has 'alpha'"),
    ({}, "hyperparameter 'alpha' missing from {}; give 'alpha'"),
])
def test_bad_hyperparameters_are_one_line_errors(params, message):
    with pytest.raises(MethodError) as err:
        Ridge().fit(TRAIN, params, RNG)
    assert str(err.value) == f"method 'ridge': {message}"


def test_bad_option_and_empty_training_part():
    with pytest.raises(MethodError, match="alpha_grid"):
        Ridge(alpha_grid=(4, -6))
    with pytest.raises(MethodError, match="the training samples are empty; give at least one training row"):
        Ridge().fit(TRAIN.take(np.array([], dtype=int)), {"alpha": 1.0}, RNG)


def test_describe_names_the_features():
    fitted = Ridge().fit(TRAIN, {"alpha": 0.1}, RNG)
    info = Ridge().describe(fitted)
    assert info["alpha"] == 0.1
    assert list(info["weights (standardised features)"]) == list(TRAIN.feature_names)
    np.testing.assert_allclose(info["intercept"], TRAIN.y.mean(axis=0))
