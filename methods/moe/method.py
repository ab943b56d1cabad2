"""The ``moe`` method: the Method contract wired to the package's options, training, simulation and explanation."""

from __future__ import annotations

from typing import Any

import numpy as np

from enginebench.datasets.samples import Samples
from enginebench.methods.base import EXPLAIN_WEIGHTS, Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.moe.explain import describe, gate_weights
from enginebench.methods.moe.fitted import MoEFitted
from enginebench.methods.moe.options import HYPERPARAMETERS, OPTIONS
from enginebench.methods.moe.simulation import simulate
from enginebench.methods.moe.training import fit_mixture


class MoE(Method):
    """Mixture of LPV experts with frozen-stability sign constraints (seed 003)."""

    name = "moe"
    family = "hybrid"
    modes = frozenset({"simulation"})
    summary = "mixture of LPV experts with frozen stability, trained on TV derivatives (seed 003)"

    declared_options = OPTIONS

    def search_space(self, data: Samples) -> SearchSpace:
        return {
            "n_experts": np.array([2, 3, 4]),
            "beta1": np.array([1.0]),
            "beta2": np.array([0.1, 1.0]),
            "k": np.array([1.0]),
            "gate_hidden": np.array([16]),
            # from the least-squares warm start a small rate refines; a large one may trade
            # simulation accuracy for derivative fit: the validation RMAE decides
            "lr": np.array([1e-3, 1e-2]),
            "epochs": np.array([HYPERPARAMETERS["epochs"]]),
        }

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> MoEFitted:
        self.check_mode(train.mode)
        return fit_mixture(train, params, self.options, rng)

    def predict(self, fitted: MoEFitted, data: Samples) -> SegmentPredictions:
        self.check_mode(data.mode)
        traj, _, diverged = simulate(fitted, data)
        return SegmentPredictions([y[s.rows] for y, s in zip(traj, data.segments)], diverged)

    def describe(self, fitted: MoEFitted) -> dict[str, Any]:
        """Expert count, hyperparameters, local linear systems and the frozen-stability verdict."""
        return describe(fitted)

    def explain(self, fitted: MoEFitted, data: Samples) -> dict[str, list[np.ndarray]]:
        """The gate as ``weights`` (one (rows, experts) array per segment, along the simulated trajectory)."""
        return {EXPLAIN_WEIGHTS: gate_weights(fitted, data)}
