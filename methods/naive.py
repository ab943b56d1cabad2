"""Naive baselines that every table carries, so "worse than a constant" stays visible."""

from __future__ import annotations

from typing import Any

import numpy as np

from enginebench.errors import MethodError
from enginebench.method import Method, Params, SegmentPredictions
from enginebench.samples import Samples


class NaiveMean(Method):
    """Predicts the training mean of each target."""

    name = "naive-mean"
    family = "baseline"
    reference_baseline = True  # tables' skill is measured against it (results.tables.BASELINE)
    uses_features = False
    modes = frozenset({"static", "window", "simulation"})
    summary = "training mean of the target"

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> np.ndarray:
        return train.y.mean(axis=0)

    def predict(self, fitted: np.ndarray, data: Samples) -> list[np.ndarray]:
        out = [np.broadcast_to(fitted, (len(s), fitted.size)).copy() for s in data.segments]
        return SegmentPredictions(out) if data.mode == "simulation" else out

    def describe(self, fitted: np.ndarray) -> dict[str, Any]:
        return {"mean": fitted.tolist()}

    def c_model(self, fitted: np.ndarray) -> Any:
        """The C step of ``fitted`` for an FMU and the real-time figures (``methods/export``)."""
        from enginebench.methods.export.models import naive_mean_c

        return naive_mean_c(fitted)

    def step_times(self, fitted, data):
        """Its C step timed over ``data`` for the real-time figures (``methods/export/harness.py``)."""
        from enginebench.methods.export.harness import c_step_times

        return c_step_times(self.c_model(fitted), data)


class NaiveLast(Method):
    """Last-value persistence: y(t) is predicted by the measured y(t - dt) (window mode)."""

    name = "naive-last"
    family = "baseline"
    modes = frozenset({"window"})
    summary = "persistence: the last measured output y(t-dt)"

    def _columns(self, data: Samples) -> list[int]:
        if data.lags < 1:
            raise MethodError("naive-last needs mode 'window' with a window of at least one sample period")
        return [data.feature_index(f"{name}[t-1]") for name in data.target_names]

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> None:
        self._columns(train)
        return None

    def predict(self, fitted: None, data: Samples) -> list[np.ndarray]:
        cols = self._columns(data)
        return [s.X[:, cols].copy() for s in data.segments]
