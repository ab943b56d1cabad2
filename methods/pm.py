"""``pm``: the dataset's own physical model, calibrated by the model's own rule.

The physical model is declared by the dataset (datasets/physical.py). It is calibrated
on the training rows only (stateless models) or keeps parameters set elsewhere (e.g. a
factory-acceptance-test calibration), and simulated over whole segments so that
stateful models (lags, thermal inertia) see their history.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.datasets.samples import Samples
from enginebench.errors import MethodError
from enginebench.methods.base import Method, Params


def physical_model(data: Samples) -> Any:
    pm = data.physical_model
    if pm is None:
        raise MethodError("this dataset declares no physical model, so 'pm' and the hybrid methods cannot run on it")
    missing = [t for t in data.target_names if t not in pm.outputs]
    if missing:
        raise MethodError(f"physical model {pm.name!r} predicts {', '.join(pm.outputs)}, not {', '.join(missing)}")
    absent = [c for c in pm.inputs if c not in data.input_names]
    if absent:
        raise MethodError(f"physical model {pm.name!r} needs input column(s) {', '.join(absent)}, which are not "
                          "run-time inputs here; give them the 'input' role (experiment 'roles')")
    return pm


def calibration_signals(data: Samples) -> list[dict[str, np.ndarray]]:
    """Inputs and measured targets at the training rows of each segment."""
    out = []
    for s in data.segments:
        sig = {name: s.U[s.rows, j] for j, name in enumerate(data.input_names)}
        sig["time"] = s.t[s.rows]
        sig.update({name: s.y[:, k] for k, name in enumerate(data.target_names)})
        out.append(sig)
    return out


def simulate_rows(pm: Any, params: Mapping[str, Any], data: Samples) -> list[np.ndarray]:
    """The physical model's predictions of the targets at each segment's rows, (n_i, k)."""
    out = []
    for s in data.segments:
        sig = {name: s.U[:, j] for j, name in enumerate(data.input_names)}
        sig["time"] = s.t
        sim = pm.simulate(params, sig, data.dt)
        out.append(np.column_stack([np.asarray(sim[t], dtype=float)[s.rows] for t in data.target_names]))
    return out


class PhysicalModelMethod(Method):
    """The dataset's physical model (calibrated on training rows where it calibrates on data)."""

    name = "pm"
    family = "physical"
    modes = frozenset({"static", "window", "simulation"})
    summary = "the dataset's physical model"

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> dict[str, Any]:
        pm = physical_model(train)
        return {"model": pm.name, "params": pm.calibrate(calibration_signals(train))}

    def predict(self, fitted: dict[str, Any], data: Samples) -> list[np.ndarray]:
        return simulate_rows(physical_model(data), fitted["params"], data)

    def describe(self, fitted: dict[str, Any]) -> dict[str, Any]:
        return dict(fitted)
