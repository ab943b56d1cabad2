"""neural-ss and gru: conformance, recovery of a known nonlinear system's free run, determinism, divergence."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from enginebench import registry
from enginebench.errors import MethodError
from enginebench.methods.gru import GRU
from enginebench.methods.neural_ss import NeuralSS
from enginebench.samples import Samples, SegmentSamples

torch.set_num_threads(1)

FAST = {"steps": 400, "hidden": 16, "layers": 1, "batch_size": 32, "horizon": 30, "lr": 5e-3, "lr_final": 1.0,
        "validations": 10}
"""Options of the recovery tests: a small model trained briefly on a first-order system."""
INIT = 10


def _system(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A nonlinear first-order system: y(t+1) = 0.7 y - 0.1 y^3 + 0.8 tanh(2 u), measured with a little noise."""
    u = rng.uniform(-1.0, 1.0, n)
    y = np.zeros(n)
    for t in range(n - 1):
        y[t + 1] = 0.7 * y[t] - 0.1 * y[t] ** 3 + 0.8 * np.tanh(2.0 * u[t])
    return u, y + rng.normal(0.0, 0.01, n)


def _samples(records: list[tuple[np.ndarray, np.ndarray]], init: int = 0) -> Samples:
    """Simulation samples of whole records (``init`` > 0: the first ``init`` samples are the init window)."""
    segs = []
    for i, (u, y) in enumerate(records):
        n = len(u)
        rows = np.arange(init, n)
        U = u[:, None]
        segs.append(SegmentSamples(id=f"r{i}", X=U[rows], rows=rows, U=U, t=np.arange(n, dtype=float),
                                   y=y[rows, None], y0=y[:1], y_init=y[:init, None] if init else None))
    return Samples(segments=tuple(segs), mode="simulation", window=0.0, dt=1.0, feature_names=("u",),
                   input_names=("u",), target_names=("y",), init_samples=init)


@pytest.fixture(scope="module")
def data() -> tuple[Samples, Samples, np.ndarray]:
    rng = np.random.default_rng(7)
    train = _samples([_system(1500, rng), _system(1500, rng)])
    u, y = _system(1000, rng)
    test = _samples([(u, y)], init=INIT)
    return train, test.without_targets(), y[INIT:]


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)))


def test_registered():
    assert registry.get("neural-ss") is NeuralSS and registry.get("gru") is GRU


@pytest.mark.parametrize("cls, nx, tolerance", [(NeuralSS, 2, 0.10), (GRU, 8, 0.10)])
def test_recovers_a_nonlinear_systems_free_run(data, cls, nx, tolerance):
    train, test, y = data
    method = cls(**FAST)
    fitted = method.fit(train, {"nx": nx}, np.random.default_rng(0))
    pred = method.predict(fitted, test)
    yhat = pred[0][:, 0]
    assert yhat.shape == y.shape and not pred.diverged.any()
    rmse, sd = _rmse(yhat, y), float(y.std())
    assert rmse < tolerance * sd, (rmse, sd)  # the mean predicts with an RMSE of one SD
    assert method.describe(fitted)["steps_run"] <= FAST["steps"]


def test_same_seed_same_predictions_other_seed_others(data):
    train, test, _ = data
    method = NeuralSS(**{**FAST, "steps": 30})
    runs = [method.predict(method.fit(train, {"nx": 2}, np.random.default_rng(s)), test)[0] for s in (3, 3, 4)]
    assert np.array_equal(runs[0], runs[1])
    assert not np.array_equal(runs[0], runs[2])


def test_a_blown_up_run_is_held_in_the_envelope_and_flagged(data):
    train, test, _ = data
    method = NeuralSS(**{**FAST, "steps": 30})
    fitted = method.fit(train, {"nx": 2}, np.random.default_rng(0))
    weights = dict(fitted.weights)
    w = weights["linear.weight"].copy()
    w[:2, :2] = 3.0 * np.eye(2)  # an unstable linear skip: the state grows 3x per step
    weights["linear.weight"] = w
    pred = method.predict(replace(fitted, weights=weights), test)
    assert pred.diverged.tolist() == [True]
    values = pred[0]
    assert np.isfinite(values).all()
    assert (values >= fitted.envelope.lower).all() and (values <= fitted.envelope.upper).all()


def test_the_init_window_sets_the_state(data):
    """Two init windows on the same inputs give different starts, and the free run forgets them (stable system)."""
    train, test, _ = data
    method = NeuralSS(**FAST)
    fitted = method.fit(train, {"nx": 2}, np.random.default_rng(0))
    seg = test.segments[0]
    shifted = replace(test, segments=(replace(seg, y_init=seg.y_init + 1.0),))
    a, b = method.predict(fitted, test)[0][:, 0], method.predict(fitted, shifted)[0][:, 0]
    assert abs(a[0] - b[0]) > 1e-3
    assert abs(a[-1] - b[-1]) < 1e-3


def test_options_are_checked_with_one_line_naming_them():
    with pytest.raises(MethodError, match="device"):
        NeuralSS(device="tpu")
    with pytest.raises(MethodError, match="nx"):
        GRU(nx=0)
    with pytest.raises(MethodError, match="val_fraction"):
        NeuralSS(val_fraction=0.7)
    assert NeuralSS().search_space(_samples([(np.zeros(50), np.zeros(50))]))["nx"].tolist() == [8]
    assert NeuralSS(nx=[2, 6]).search_space(_samples([(np.zeros(50), np.zeros(50))]))["nx"].tolist() == [2, 6]
