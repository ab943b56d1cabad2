"""Hybrid strategies: each against a direct solve of its kernel system, residual learning of a known
discrepancy, ``hybrid``'s grid and selection, the distance from the PM, conformance."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench import registry
from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import MethodError
from enginebench.method import grid_points
from enginebench.methods.hybrid import (
    STRATEGIES, Hybrid, KRLSPM, MTLDistanceKRLS, MTLTaskKRLS, ResidualKRLS, ResidualKRLSPM, strategy_label,
)

CLASSES = {"feature": KRLSPM, "residual": ResidualKRLS, "residual-feature": ResidualKRLSPM, "task": MTLTaskKRLS}
RNG = np.random.default_rng(0)


class BiasedPM:
    """y's physics without the sin(u1) term and 20 % off in the u2 gain; calibrates an offset on training rows."""

    name = "biased-pm"
    inputs = ("u1", "u2")
    outputs = ("y",)

    def calibrate(self, segments):
        return {"offset": float(np.mean(np.concatenate([s["y"] - 0.4 * s["u2"] for s in segments])))}

    def simulate(self, params, segment, dt):
        return {"y": 0.4 * segment["u2"] + params["offset"]}


class FixedPM:
    """A PM given as a function of the inputs and time (nothing calibrated)."""

    inputs = ("u1", "u2")
    outputs = ("y",)

    def __init__(self, name, fn):
        self.name, self.fn = name, fn

    def calibrate(self, segments):
        return {}

    def simulate(self, params, segment, dt):
        return {"y": self.fn(segment["u1"], segment["u2"], segment["time"])}


def pm_of_data(u1, u2, t):
    return 3.0 + 2.0 * u2 + 0.3 * u1


def discrepancy(u1, u2):
    return 0.8 * np.sin(1.5 * u1) + 0.3 * u2**2


def useless_pm(u1, u2, t):
    return 10.0 + 3.0 * np.sin(37.3 * t)  # unrelated to the inputs and the target


def synthetic(y_of, n_segments=4, n=60, seed=1, noise=0.0):
    """Segments with inputs u1 (uniform), u2 (random walk) and y = y_of(u1, u2) + noise."""
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(n_segments):
        u1 = rng.uniform(-2, 2, n)
        u2 = np.clip(np.cumsum(rng.normal(0, 0.3, n)), -2, 2)
        parts.append(pd.DataFrame({SEGMENT: f"s{k}", TIME: k * (n + 10.0) + np.arange(n, dtype=float), "u1": u1,
                                   "u2": u2, "y": y_of(u1, u2) + noise * rng.normal(size=n)}))
    schema = Schema((Column("u1", "input", "V"), Column("u2", "input", "bar"), Column("y", "output", "degC")))
    return Dataset("hybrid-test", pd.concat(parts, ignore_index=True), schema, 1.0, {"provenance": "test", "licence": "CC0"})


def split(ds, pm, train=("s0", "s1", "s2"), test=("s3",), mode="static", window=0.0):
    make = lambda ids: make_samples(ds.select_segments(list(ids)), ["y"], mode, window, physical_model=pm)  # noqa: E731
    return make(train), make(test)


@pytest.fixture
def toy_samples(toy):
    return split(toy, BiasedPM(), ("s0", "s1"), ("s3",))


def predictions(method, train, test, params):
    fitted = method.fit(train, params, RNG)
    return np.concatenate(method.predict(fitted, test.without_targets())), fitted


# -- each strategy against a direct solve ---------------------------------------------------------

def _signals(samples):
    return [{"u1": s.U[s.rows, 0], "u2": s.U[s.rows, 1], "time": s.t[s.rows], "y": s.y[:, 0]} for s in samples.segments]


def direct_solve(strategy, train, test, gamma, lam, theta=None):
    """Standardised features, Gaussian kernel, numpy.linalg.solve of the strategy's kernel system."""
    pm = train.physical_model
    params = pm.calibrate(_signals(train))

    def p_at(samples):
        return np.concatenate([pm.simulate(params, {"u1": s.U[s.rows, 0], "u2": s.U[s.rows, 1], "time": s.t[s.rows]},
                                           1.0)["y"] for s in samples.segments])

    p, p_test, y = p_at(train), p_at(test), train.y[:, 0]
    with_pm = strategy != "residual"
    F = np.column_stack([train.X, p]) if with_pm else train.X
    F_test = np.column_stack([test.X, p_test]) if with_pm else test.X
    mean, std = F.mean(axis=0), F.std(axis=0)
    F, F_test = (F - mean) / std, (F_test - mean) / std
    K = np.exp(-gamma * ((F[:, None, :] - F[None, :, :]) ** 2).sum(-1))
    K_test = np.exp(-gamma * ((F_test[:, None, :] - F[None, :, :]) ** 2).sum(-1))
    n, I = len(y), np.eye(len(y))
    if strategy in ("shared", "task"):
        offset = y.mean()
        yc, pc = y - offset, p - offset
        Z = np.zeros((n, n))
        A = np.block([[2 * K + (lam + 2 * theta) * I, -theta * I, -theta * I],
                      [-theta * I, K + theta * I, Z],
                      [-theta * I, Z, K + theta * I]])
        sol = np.linalg.solve(A, np.concatenate([yc + pc, yc, pc]))
        coef = sol[:n] if strategy == "shared" else sol[n:2 * n]
        return K_test @ coef + offset
    target = y - p if strategy.startswith("residual") else y
    offset = target.mean()
    alpha = np.linalg.solve(K + lam * I, target - offset)
    return K_test @ alpha + offset + (p_test if strategy.startswith("residual") else 0.0)


@pytest.mark.parametrize("strategy", STRATEGIES)
@pytest.mark.parametrize("gamma, lam, theta", [(0.3, 0.1, 1.0), (2.0, 1e-3, 0.05), (0.05, 3.0, 30.0)])
def test_each_strategy_equals_a_direct_solve(toy_samples, strategy, gamma, lam, theta):
    train, test = toy_samples
    mtl = strategy in ("shared", "task")
    ref = direct_solve(strategy, train, test, gamma, lam, theta if mtl else None)
    params = {"gamma": gamma, "lambda": lam, **({"theta": theta} if mtl else {})}
    method = MTLDistanceKRLS(predict_with=strategy) if mtl else CLASSES[strategy]()
    ours, _ = predictions(method, train, test, params)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(ours[:, 0], ref, rtol=0, atol=1e-8 * scale)
    # the same model through hybrid, its strategy given as a grid value
    label = strategy_label(strategy, theta if mtl else None)
    via_hybrid, _ = predictions(Hybrid(), train, test, {"strategy": label, "gamma": gamma, "lambda": lam})
    np.testing.assert_allclose(via_hybrid[:, 0], ref, rtol=0, atol=1e-8 * scale)


def test_the_shared_strategy_is_mtl_krls(toy_samples):
    from enginebench.methods.mtl_krls import MTLKRLS

    train, test = toy_samples
    params = {"gamma": 0.3, "lambda": 0.1, "theta": 1.0}
    ours, _ = predictions(MTLDistanceKRLS(), train, test, params)
    paper, _ = predictions(MTLKRLS(), train, test, params)
    np.testing.assert_array_equal(ours, paper)


# -- residual learning ------------------------------------------------------------------------------

def test_residual_krls_recovers_a_known_additive_discrepancy():
    """y = p + g(u) with g smooth: the residual model's prediction minus the PM is g, on unseen segments."""
    ds = synthetic(lambda u1, u2: pm_of_data(u1, u2, 0.0) + discrepancy(u1, u2), n_segments=5, n=80)
    train, test = split(ds, FixedPM("exact-but-for-g", pm_of_data), ("s0", "s1", "s2", "s3"), ("s4",))
    pred, fitted = predictions(ResidualKRLS(), train, test, {"gamma": 0.3, "lambda": 1e-4})
    seg = test.segments[0]
    u1, u2 = seg.U[seg.rows, 0], seg.U[seg.rows, 1]
    g = discrepancy(u1, u2)
    learned = pred[:, 0] - pm_of_data(u1, u2, 0.0)
    assert np.sqrt(np.mean((learned - g) ** 2)) < 0.03 * np.sqrt(np.mean(g**2))
    # it stays as far from the PM as the measurements (it learned all of y - p)
    assert ResidualKRLS().describe(fitted)["pm_share"] == pytest.approx(1.0, abs=1e-3)


# -- hybrid: the grid and the selection -----------------------------------------------------------

def test_hybrid_grid_is_the_union_of_the_strategies_grids(toy_samples):
    train, _ = toy_samples
    method = Hybrid(gamma_grid=(-1, 0, 2), lambda_grid=(-2, 0, 3), theta_grid=(-1, 1, 4))
    space = method.search_space(train)
    assert list(space) == ["strategy", "gamma", "lambda"]
    labels = list(space["strategy"])
    assert len(labels) == 3 + 2 * 4 and labels[8:] == ["feature", "residual", "residual-feature"]
    assert labels[0] == "shared theta=0.1" and labels[7] == "task theta=10.0"
    assert len(grid_points(space)) == (3 + 2 * 4) * 2 * 3
    only = Hybrid(strategies=["residual", "task"], theta_grid=(0, 0, 1)).search_space(train)["strategy"]
    assert list(only) == ["residual", "task theta=1.0"]


def test_hybrid_predict_grid_equals_per_point_fits(toy_samples):
    train, test = toy_samples
    method = Hybrid(gamma_grid=(-1, 0, 2), lambda_grid=(-2, 0, 2), theta_grid=(-1, 1, 2))
    grid = grid_points(method.search_space(train))
    assert len(grid) == 7 * 4 and {method._point(p)[0] for p in grid} == set(STRATEGIES)
    shuffled = [grid[i] for i in np.random.default_rng(3).permutation(len(grid))]  # strategies interleaved
    block = method.predict_grid(train, test.without_targets(), shuffled, RNG)
    assert block.shape == (len(grid), len(test), 1)
    for g, params in enumerate(shuffled):
        single, _ = predictions(method, train, test, params)
        np.testing.assert_allclose(block[g], single, rtol=0, atol=1e-8 * np.abs(single).max(), err_msg=str(params))


def select_on_training_data(method, train, validation):
    """The grid point with the lowest validation MAE (both parts are training data)."""
    grid = grid_points(method.search_space(train))
    block = method.predict_grid(train, validation.without_targets(), grid, RNG)
    return grid[int(np.argmin(np.abs(block - validation.y[None]).mean(axis=(1, 2))))]


def test_selection_keeps_an_exact_pm_through_residual_learning_with_a_large_lambda():
    ds = synthetic(lambda u1, u2: pm_of_data(u1, u2, 0.0), noise=0.05)
    train, validation = split(ds, FixedPM("exact", pm_of_data), ("s0", "s1", "s2"), ("s3",))
    chosen = select_on_training_data(Hybrid(gamma_grid=(-2, 1, 4), lambda_grid=(-3, 3, 7), theta_grid=(-2, 2, 3)),
                                     train, validation)
    assert chosen["strategy"] in ("residual", "residual-feature") and chosen["lambda"] >= 10.0, chosen


def test_selection_learns_from_the_data_when_the_pm_is_useless():
    ds = synthetic(lambda u1, u2: pm_of_data(u1, u2, 0.0) + discrepancy(u1, u2), noise=0.02)
    train, validation = split(ds, FixedPM("useless", useless_pm), ("s0", "s1", "s2"), ("s3",))
    method = Hybrid(gamma_grid=(-2, 1, 4), lambda_grid=(-3, 3, 7), theta_grid=(-2, 2, 3))
    chosen = select_on_training_data(method, train, validation)
    assert method._point(chosen)[0] in ("feature", "task"), chosen


# -- distance from the PM ---------------------------------------------------------------------------

KEYS = {"strategy", "gamma", "lambda", "theta", "pm_share", "rms_from_pm", "rms_pm_error", "pm_params"}


def test_pm_share_is_zero_for_a_model_that_returns_the_pm():
    ds = synthetic(lambda u1, u2: pm_of_data(u1, u2, 0.0))
    train, _ = split(ds, FixedPM("exact", pm_of_data))
    method = ResidualKRLS()
    described = method.describe(method.fit(train, {"gamma": 0.3, "lambda": 0.1}, RNG))
    assert described["pm_share"] == 0.0 and described["rms_from_pm"] == 0.0 and described["rms_pm_error"] == 0.0


@pytest.mark.parametrize("method, params, share", [
    (ResidualKRLS(center_target=False), {"gamma": 0.3, "lambda": 1e9}, 0.0),  # the PM unchanged
    (KRLSPM(), {"gamma": 10.0, "lambda": 1e-6}, 1.0),  # interpolates the measurements
    (MTLDistanceKRLS(), {"gamma": 10.0, "lambda": 1e-6, "theta": 1e6}, 0.5),  # smooths (y + p) / 2
])
def test_pm_share_measures_how_far_the_model_left_the_pm(toy_samples, method, params, share):
    train, _ = toy_samples
    fitted = method.fit(train, params, RNG)
    described = method.describe(fitted)
    assert described["pm_share"] == pytest.approx(share, abs=2e-3)
    p = np.concatenate([BiasedPM().simulate(fitted.pm_params, {"u2": s.U[s.rows, 1]}, 1.0)["y"] for s in train.segments])
    assert described["rms_pm_error"] == pytest.approx(np.sqrt(np.mean((train.y[:, 0] - p) ** 2)), rel=1e-12)
    assert described["rms_from_pm"] == pytest.approx(described["pm_share"] * described["rms_pm_error"], rel=1e-12)


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_every_strategy_describes_the_same_keys(toy_samples, strategy):
    train, _ = toy_samples
    params = {"strategy": strategy_label(strategy, 1.0 if strategy in ("shared", "task") else None),
              "gamma": 0.3, "lambda": 0.1}
    method = Hybrid()
    described = method.describe(method.fit(train, params, RNG))
    assert KEYS <= set(described) and described["strategy"] == strategy
    assert (described["theta"] is None) == (strategy not in ("shared", "task"))
    assert 0.0 < described["pm_share"] < 2.0


def test_hybrid_warns_when_theta_sits_at_the_edge_of_its_grid(toy_samples):
    train, _ = toy_samples
    method = Hybrid(theta_grid=(-2, 2, 5))
    edge = method.describe(method.fit(train, {"strategy": "task theta=100.0", "gamma": 0.3, "lambda": 0.1}, RNG))
    assert edge["warnings"] == ["theta = 100 selected at the upper edge of its grid [0.01 .. 100]; the optimum may "
                                "lie beyond it: widen theta_grid"]
    inside = method.describe(method.fit(train, {"strategy": "task", "theta": 1.0, "gamma": 0.3, "lambda": 0.1}, RNG))
    assert "warnings" not in inside and inside["theta"] == 1.0


# -- window mode, errors, registration, conformance -------------------------------------------------

def test_window_mode_uses_the_pm_at_the_current_row_only(toy):
    train, test = split(toy, BiasedPM(), ("s0", "s1"), ("s3",), mode="window", window=2.0)
    method = KRLSPM()
    fitted = method.fit(train, {"gamma": 0.3, "lambda": 0.1}, RNG)
    assert fitted.model.X_train.shape[1] == train.X.shape[1] + 1
    ref = direct_solve("feature", train, test, 0.3, 0.1)
    np.testing.assert_allclose(np.concatenate(method.predict(fitted, test.without_targets()))[:, 0], ref,
                               rtol=0, atol=1e-8 * np.abs(ref).max())


@pytest.mark.parametrize("params, message", [
    ({"strategy": "magic", "gamma": 1.0, "lambda": 1.0}, "method 'hybrid': strategy 'magic' is not one of shared, task"),
    ({"strategy": "residual theta=1.0", "gamma": 1.0, "lambda": 1.0}, "method 'hybrid': strategy 'residual theta=1.0' is"),
    ({"strategy": "residual", "gamma": 1.0, "lambda": 1.0, "theta": 1.0},
     "method 'hybrid': theta applies to the strategies shared and task, not 'residual'"),
    ({"strategy": "task", "gamma": 1.0, "lambda": 1.0}, "method 'hybrid': strategy 'task' needs theta"),
    ({"strategy": "task theta=1.0", "gamma": 1.0, "lambda": 1.0, "theta": 2.0}, "method 'hybrid': theta given twice"),
    ({"gamma": 1.0, "lambda": 1.0}, "method 'hybrid': hyperparameter strategy missing"),
    ({"strategy": "feature", "gamma": 1.0, "lambda": 1.0, "delta": 1}, "method 'hybrid': unknown hyperparameter(s) delta"),
])
def test_bad_hybrid_grid_points_are_named(toy_samples, params, message):
    train, test = toy_samples
    with pytest.raises(MethodError) as err:
        Hybrid().predict_grid(train, test.without_targets(), [{"strategy": "feature", "gamma": 1.0, "lambda": 1.0}, params],
                              RNG)
    assert str(err.value).startswith(message)


@pytest.mark.parametrize("cls, options, message", [
    (Hybrid, {"strategies": ["residual", "magic"]}, "method 'hybrid': option strategies must be a non-empty list of "
                                                    "distinct names from shared, task, feature, residual, residual-feature"),
    (Hybrid, {"strategies": ["task", "task"]}, "method 'hybrid': option strategies must be a non-empty list of distinct"),
    (Hybrid, {"solver": "falkon"}, "method 'hybrid': strategies shared, task have only the exact solver"),
    (MTLTaskKRLS, {"predict_with": "shared"}, "method 'mtl-krls-task': option predict_with must be 'task'"),
])
def test_bad_options_are_refused(cls, options, message):
    with pytest.raises(MethodError) as err:
        cls(**options)
    assert str(err.value).startswith(message)
    Hybrid(strategies=["feature", "residual"], solver="falkon")  # no MTL strategy: FALKON is fine


def test_a_non_finite_pm_prediction_is_named(toy):
    train, _ = split(toy, FixedPM("broken", lambda u1, u2, t: np.where(t == 5.0, np.nan, u2)), ("s0", "s1"))
    with pytest.raises(MethodError, match=r"^method 'residual-krls': the physical model's prediction of 'y' is "
                                          r"nan/inf at row 5 of segment 's0'"):
        ResidualKRLS().fit(train, {"gamma": 1.0, "lambda": 1.0}, RNG)


def test_needs_a_physical_model(toy):
    train = make_samples(toy, ["y"])
    with pytest.raises(MethodError, match="declares no physical model"):
        Hybrid().fit(train, {"strategy": "residual", "gamma": 1.0, "lambda": 1.0}, RNG)


@pytest.mark.parametrize("name, cls", [("mtl-krls-task", MTLTaskKRLS), ("krls-pm", KRLSPM),
                                       ("residual-krls", ResidualKRLS), ("residual-krls-pm", ResidualKRLSPM),
                                       ("hybrid", Hybrid)])
def test_registered(name, cls):
    """Conformance in both modes: test_conformance_registry.py."""
    assert registry.get(name) is cls and cls.family == "hybrid" and cls.modes == {"static", "window"}
