"""``pm``: the dataset's own physical model, calibrated by the model's own rule.

The physical model is declared by the dataset (enginebench/physical.py). It is calibrated
on the training rows only (stateless models) or keeps parameters set elsewhere (e.g. a
factory-acceptance-test calibration), and simulated over whole segments so that
stateful models (lags, thermal inertia) see their history.
"""

from __future__ import annotations

import hashlib
import pickle
import weakref
from collections import OrderedDict
from typing import Any, Mapping, Sequence

import numpy as np

from enginebench.errors import MethodError
from enginebench.method import Method, Params, SegmentPredictions
from enginebench.samples import Samples


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


class SimulationCache:
    """Whole-segment simulations of a physical model, reused while the segment's arrays live.

    A job asks for the PM at a subsample's rows, but a stateful PM must run over the
    whole segment; every resample, block and repetition of a worker asks again with the
    same arrays and, for a PM calibrated elsewhere (factory test), the same parameters.
    Entries are keyed by the identity of the segment's input and time arrays (checked
    through weak references, so a freed array never matches), the model, its
    parameters, dt and targets; the oldest go first beyond ``max_bytes``.
    """

    def __init__(self, max_bytes: int = 256 * 2**20) -> None:
        self.max_bytes = max_bytes
        self._entries: OrderedDict[tuple, tuple[weakref.ref, weakref.ref, np.ndarray]] = OrderedDict()
        self._bytes = 0
        self.hits = 0

    def simulate(self, pm: Any, params: Mapping[str, Any], U: np.ndarray, t: np.ndarray, input_names: Sequence[str],
                 target_names: Sequence[str], dt: float) -> np.ndarray:
        """The PM's targets over the whole segment, (n, k)."""
        key = (id(U), id(t), pm.name, _fingerprint(params), float(dt), tuple(input_names), tuple(target_names))
        hit = self._entries.get(key)
        if hit is not None and hit[0]() is U and hit[1]() is t:
            self._entries.move_to_end(key)
            self.hits += 1
            return hit[2]
        sig = {name: U[:, j] for j, name in enumerate(input_names)}
        sig["time"] = t
        sim = pm.simulate(params, sig, dt)
        values = np.column_stack([np.asarray(sim[name], dtype=float) for name in target_names])
        values.setflags(write=False)
        if hit is not None:
            self._drop(key)
        if values.nbytes <= self.max_bytes:
            self._entries[key] = (weakref.ref(U), weakref.ref(t), values)
            self._bytes += values.nbytes
            while self._bytes > self.max_bytes:
                self._drop(next(iter(self._entries)))
        return values

    def _drop(self, key: tuple) -> None:
        self._bytes -= self._entries.pop(key)[2].nbytes

    def clear(self) -> None:
        self._entries.clear()
        self._bytes = 0


def _fingerprint(params: Mapping[str, Any]) -> str:
    """A digest of the parameter values (exact: arrays and floats by their bytes)."""
    return hashlib.sha1(pickle.dumps(sorted(params.items()), protocol=4)).hexdigest()


SIMULATIONS = SimulationCache()
"""This process's cache of whole-segment PM simulations."""


def simulate_rows(pm: Any, params: Mapping[str, Any], data: Samples) -> list[np.ndarray]:
    """The physical model's predictions of the targets at each segment's rows, (n_i, k)."""
    return [SIMULATIONS.simulate(pm, params, s.U, s.t, data.input_names, data.target_names, data.dt)[s.rows]
            for s in data.segments]


class PhysicalModelMethod(Method):
    """The dataset's physical model (calibrated on training rows where it calibrates on data)."""

    name = "pm"
    family = "physical"
    uses_features = False  # simulated from the raw inputs U
    modes = frozenset({"static", "window", "simulation"})
    summary = "the dataset's physical model"
    export_note = ("FMU where the dataset's physical model has a C step (marine-diesel's and gas-turbine-tat's: "
                   "enginebench export RUN --method pm --fmu OUT.fmu, from a run with --keep-models); none for the "
                   "others (an import spec's FMU)")

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> dict[str, Any]:
        pm = physical_model(train)
        # targets and dt: what a C step of the model (export --fmu, real-time figures) is built for
        return {"model": pm.name, "params": pm.calibrate(calibration_signals(train)),
                "targets": list(train.target_names), "dt": float(train.dt)}

    def predict(self, fitted: dict[str, Any], data: Samples) -> list[np.ndarray]:
        out = simulate_rows(physical_model(data), fitted["params"], data)
        return SegmentPredictions(out) if data.mode == "simulation" else out

    def describe(self, fitted: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in fitted.items() if k not in ("targets", "dt")}

    def c_model(self, fitted: dict[str, Any]) -> Any:
        """The physical model's fixed step in C where it offers one (``c_model(params, dt, targets)``)."""
        from enginebench.physical import get_physical_model

        if "targets" not in fitted or "dt" not in fitted:
            return None
        pm = get_physical_model(fitted["model"])
        make = getattr(pm, "c_model", None)
        return None if make is None else make(fitted["params"], fitted["dt"], tuple(fitted["targets"]))

    def step_times(self, fitted: dict[str, Any], data: Samples) -> Any:
        """The real-time figures' step: the C step where the physical model has one (None otherwise)."""
        from enginebench.methods.export.harness import c_step_times

        return c_step_times(self.c_model(fitted), data)
