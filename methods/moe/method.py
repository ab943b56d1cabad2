"""The ``moe`` method: the Method contract wired to the package's options, training, simulation and explanation."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Iterator, Sequence

import numpy as np

from enginebench.method import EXPLAIN_WEIGHTS, Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.moe.options import OPTIONS, resolve_params, search_space
from enginebench.samples import Samples

if TYPE_CHECKING:  # the torch modules are imported in the methods that use them: listing methods imports no torch
    from enginebench.methods.moe.fitted import MoEFitted


class MoE(Method):
    """Mixture of LPV experts with frozen-stability sign constraints (turboshaft-moe)."""

    name = "moe"
    family = "hybrid"
    modes = frozenset({"simulation"})
    summary = "mixture of LPV experts with frozen stability, trained on TV derivatives (turboshaft-moe)"

    declared_options = OPTIONS

    def search_space(self, data: Samples) -> SearchSpace:
        """The candidates of the ``*_grid`` options (defaults: 2-4 experts, beta2 0.1 or 1, lr 1e-3 or 1e-2;
        from the least-squares warm start a small rate refines, a large one may trade simulation accuracy for
        derivative fit: the validation score decides); epochs 100, more on a short record
        (``options.default_epochs``)."""
        return search_space(self.options, None if data is None else len(data))

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> MoEFitted:
        from enginebench.methods.moe.training import fit_mixture

        self.check_mode(train.mode)
        return fit_mixture(train, params, self.options, rng)

    def fit_grid(self, train: Samples, grid: Sequence[Params], rng: np.random.Generator
                 ) -> Iterator[tuple[int, MoEFitted]]:
        """Points that differ only in ``epochs`` share one training run, packed at each epoch count (in
        grid order of their first point): an ``epochs_grid`` of several values is early stopping chosen
        on the validation simulation error, for the price of the longest run. With ``batch_grid`` (the
        default) the runs train side by side in one batched loop (``grid.py``)."""
        from enginebench.methods.moe.grid import fit_mixture_grid

        runs: dict[tuple[Any, ...], dict[int, list[int]]] = {}  # run -> epochs -> grid indices
        for i, params in enumerate(grid):
            hp = resolve_params(params)
            key = tuple(sorted((k, v) for k, v in hp.items() if k != "epochs"))
            runs.setdefault(key, {}).setdefault(hp["epochs"], []).append(i)
        by_run = list(runs.values())
        plan = [(grid[next(iter(by_epochs.values()))[0]], sorted(by_epochs)) for by_epochs in by_run]
        for j, path in fit_mixture_grid(train, plan, self.options, rng):
            for fitted in path:
                for i in by_run[j][fitted.params["epochs"]]:
                    yield i, fitted

    def predict(self, fitted: MoEFitted, data: Samples) -> SegmentPredictions:
        from enginebench.methods.moe.simulation import simulate

        self.check_mode(data.mode)
        traj, _, diverged = simulate(fitted, data)
        return SegmentPredictions([y[s.rows] for y, s in zip(traj, data.segments)], diverged)

    def describe(self, fitted: MoEFitted) -> dict[str, Any]:
        """Expert count, hyperparameters, local linear systems and the frozen-stability verdict."""
        from enginebench.methods.moe.explain import describe

        return describe(fitted)

    def explain(self, fitted: MoEFitted, data: Samples) -> dict[str, list[np.ndarray]]:
        """The gate as ``weights`` (one (rows, experts) array per segment, along the simulated trajectory)."""
        from enginebench.methods.moe.explain import gate_weights

        return {EXPLAIN_WEIGHTS: gate_weights(fitted, data)}
