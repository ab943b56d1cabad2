"""``boost-fir``: gradient-boosted trees on the history of the run-time inputs (a virtual sensor).

y(t) ~ F(u(t), u(t - s dt), ..., u(t - h)), F a sum of regression trees grown by gradient
boosting (scikit-learn's ``HistGradientBoostingRegressor``, one model per target). It is
what engine teams use as a virtual sensor for emissions: the trees take the operating point's
strong, local nonlinearities (speed x load x lambda) that a smooth kernel or a polynomial
smears, and the input history gives the slower dynamics. Like ``nfir`` it never sees an
output, so it runs free by construction (bounded inputs, bounded predictions: a tree's
output lies within the training targets' range); the same features serve ``static`` mode.

Lags are those of ``nfir`` (``methods/input_history.py``): horizons derived from the
input -> output memory of the training data (M/2, M, 2M samples and the ladder's best), each
with the stride keeping at most ``max_lags`` lags per input; the horizon is the searched
hyperparameter, the boosting settings are options with scikit-learn's defaults. Trees are
fitted without early stopping (no internal random validation split: the toolkit's selection
validates), with ``random_state`` drawn from the job's generator.

``describe`` gives grouped permutation importances: how much the training RMSE grows when
one input's whole history (all its lags together) is shuffled across rows, and the ten
single lag features that matter most, on up to ``importance_rows`` training rows kept with
the model (a fixed shuffle, so the figures are reproducible). scikit-learn chose here:
its histogram trees are fast on 10^5-10^6 rows, have no compiled dependency of their own and
are deterministic given ``random_state``; LightGBM or XGBoost were not measured better here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from enginebench.declare import Declaration, number, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions, split_rows
from enginebench.methods.input_history import HISTORY_OPTIONS, InputHistory
from enginebench.methods.nfir_memory import MemoryEstimate, horizon_samples
from enginebench.samples import Samples

NAME = "boost-fir"
IMPORTANCE_SEED = 0
"""The importance shuffles' seed: fixed, so that ``describe`` of one model always reads the same."""


@dataclass(frozen=True)
class BoostFIRFitted:
    """One boosted-trees model per target, the lags that build its features and rows to explain it by."""

    models: tuple[Any, ...]
    inputs: tuple[str, ...]
    targets: tuple[str, ...]
    lags: np.ndarray
    horizon: float
    stride: int
    dt: float
    n_rows: int
    X_explain: np.ndarray
    y_explain: np.ndarray
    memory: MemoryEstimate | None = field(default=None)


class BoostFIR(InputHistory, Method):
    """Gradient-boosted regression trees of the outputs on a window of past run-time inputs."""

    name = NAME
    family = "data-driven"
    joint_targets = True
    modes = frozenset({"simulation", "static"})
    summary = ("gradient-boosted trees (scikit-learn) on lagged inputs only: a free-running virtual sensor; "
               "horizons derived from the data's memory")

    declared_options = Declaration(
        *HISTORY_OPTIONS,
        whole("max_iter", 100, "boosting iterations: trees per target", low=1),
        number("learning_rate", 0.1, "shrinkage of each tree", low=0, low_open=True),
        whole("max_leaf_nodes", 31, "leaves per tree", low=2),
        whole("min_samples_leaf", 20, "fewest training rows in a leaf", low=1, unit="rows"),
        number("l2_regularization", 0.0, "L2 penalty on leaf values", low=0),
        whole("max_rows", 0, "training rows the trees are fitted on (a draw of the job's generator; 0 = all)",
              low=0, unit="rows"),
        whole("importance_rows", 2000, "training rows kept with the model for describe's permutation importances",
              low=1, unit="rows"),
    )

    def search_space(self, data: Samples) -> SearchSpace:
        """The horizons (s) of the input history: given, or derived from the training data's memory."""
        return self.history_space(data)

    def _regressor(self, seed: int) -> Any:
        from sklearn.ensemble import HistGradientBoostingRegressor

        o = self.options
        return HistGradientBoostingRegressor(
            max_iter=int(o["max_iter"]), learning_rate=float(o["learning_rate"]),
            max_leaf_nodes=int(o["max_leaf_nodes"]), min_samples_leaf=int(o["min_samples_leaf"]),
            l2_regularization=float(o["l2_regularization"]), early_stopping=False, random_state=seed)

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> BoostFIRFitted:
        """One boosted-trees model per target on the lagged inputs of the training rows."""
        self.check_mode(train.mode)
        if not train.has_targets or len(train) == 0:
            raise MethodError(f"method {NAME!r}: fitting needs training samples with targets")
        lags, horizon, stride = self.history_params(params, train.dt, ())
        names, cols = self._columns(train)
        X = self.lagged(train, lags, cols).X
        y = np.asarray(train.y, dtype=np.float64)
        if not np.isfinite(y).all():
            row, col = np.argwhere(~np.isfinite(y))[0]
            raise MethodError(f"method {NAME!r}: training target {train.target_names[col]!r} has nan/inf at "
                              f"training row {int(row)}; clean or drop it")
        m = int(self.options["max_rows"])
        rows = np.sort(rng.choice(len(X), size=m, replace=False)) if 0 < m < len(X) else np.arange(len(X))
        seeds = rng.integers(0, 2**31 - 1, size=y.shape[1])
        models = tuple(self._regressor(int(seed)).fit(X[rows], y[rows, j]) for j, seed in enumerate(seeds))
        keep = np.random.default_rng(IMPORTANCE_SEED).permutation(len(X))[:int(self.options["importance_rows"])]
        memory = self.memory(train) if self.options["horizons"] is None else None
        return BoostFIRFitted(models=models, inputs=names, targets=tuple(train.target_names), lags=lags,
                              horizon=horizon, stride=stride, dt=float(train.dt), n_rows=len(rows),
                              X_explain=X[np.sort(keep)], y_explain=y[np.sort(keep)], memory=memory)

    def predict(self, fitted: BoostFIRFitted, data: Samples) -> list[np.ndarray]:
        """Each target's trees on the lagged inputs of the evaluated rows (no output is read)."""
        self.check_mode(data.mode)
        missing = [c for c in fitted.inputs if c not in data.input_names]
        if missing:
            raise MethodError(f"method {NAME!r}: the data lack input column(s) {', '.join(missing)} that the model "
                              "was fitted on")
        X = self.lagged(data, fitted.lags, [data.input_names.index(c) for c in fitted.inputs]).X
        out = np.column_stack([m.predict(X) for m in fitted.models]) if len(X) else np.empty((0, len(fitted.models)))
        parts = split_rows(out, data)
        return SegmentPredictions(parts) if data.mode == "simulation" else parts

    def describe(self, fitted: BoostFIRFitted) -> dict[str, Any]:
        """Lags, boosting settings and permutation importances per input and per lag feature."""
        features = [f"{c}[t]" if k == 0 else f"{c}[t-{int(k)}]" for c in fitted.inputs for k in fitted.lags]
        out: dict[str, Any] = {
            "horizon_s": fitted.horizon,
            "horizon_samples": horizon_samples(fitted.horizon, fitted.dt),
            "stride_samples": fitted.stride,
            "lags_samples": [int(x) for x in fitted.lags],
            "inputs": list(fitted.inputs),
            "n_features": len(features),
            "trees_per_target": [int(m.n_iter_) for m in fitted.models],
            "training_rows": fitted.n_rows,
            "bibo_stable": True,
            "importance": {
                "rule": f"increase of the RMSE on {len(fitted.y_explain)} training rows when one input's whole "
                        "history (or one lag feature) is shuffled across rows, in the target's unit",
                "targets": {t: _importances(m, fitted, j, features) for j, (t, m) in
                            enumerate(zip(fitted.targets, fitted.models))},
            },
        }
        return {**out, **self.history_description(fitted.memory, fitted.dt)}


def _importances(model: Any, fitted: BoostFIRFitted, target: int, features: list[str]) -> dict[str, Any]:
    """Grouped (per input) and single (per lag feature, the top ten) permutation importances of one target."""
    X, y = fitted.X_explain, fitted.y_explain[:, target]
    rng = np.random.default_rng(IMPORTANCE_SEED)
    base = _rmse(model.predict(X), y)
    perm = rng.permutation(len(X))
    n_lags = len(fitted.lags)

    def shuffled(cols: slice | list[int]) -> float:
        Xp = X.copy()
        Xp[:, cols] = X[perm][:, cols]
        return _rmse(model.predict(Xp), y) - base

    by_input = {c: round(shuffled(slice(i * n_lags, (i + 1) * n_lags)), 6) for i, c in enumerate(fitted.inputs)}
    single = sorted(((round(shuffled([j]), 6), f) for j, f in enumerate(features)), reverse=True)[:10]
    return {"training_rmse": round(base, 6), "by_input": dict(sorted(by_input.items(), key=lambda kv: -kv[1])),
            "top_features": {f: v for v, f in single}}


def _rmse(p: np.ndarray, y: np.ndarray) -> float:
    return float(np.sqrt(np.mean((p - y) ** 2)))
