"""The ``moe`` method: the Method contract wired to the package's options, training, simulation and explanation."""

from __future__ import annotations

from typing import Any

import numpy as np

from enginebench.datasets.samples import Samples
from enginebench.methods.base import EXPLAIN_WEIGHTS, Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.moe.explain import describe, gate_weights
from enginebench.methods.moe.fitted import MoEFitted
from enginebench.methods.moe.options import OPTIONS, search_space
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
        """The candidates of the ``*_grid`` options (defaults: 2-4 experts, beta2 0.1 or 1, lr 1e-3 or 1e-2;
        from the least-squares warm start a small rate refines, a large one may trade simulation accuracy for
        derivative fit: the validation score decides)."""
        return search_space(self.options)

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
