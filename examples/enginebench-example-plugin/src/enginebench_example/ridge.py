"""Ridge regression on the features: y = b + s(x) w, with w = argmin |y - b - s(X) w|^2 + alpha |w|^2.

s standardises each feature with the training mean and standard deviation; b is the
training mean of the target. Model selection searches ``alpha``; ``predict_grid``
shares one singular value decomposition across every alpha of the grid.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from enginebench.api import (Method, MethodError, Params, Samples, SearchSpace, check_log_grid_option, log_grid,
                             split_rows)


@dataclass(frozen=True)
class RidgeFitted:
    """A fitted ridge model (plain arrays, so it pickles to worker processes)."""

    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    """(n_features, n_targets)"""
    intercept: np.ndarray
    """(n_targets,)"""
    alpha: float


class Ridge(Method):
    """Ridge regression on the (standardised) features; alpha chosen by enginebench's model selection."""

    name = "example-ridge"
    family = "data-driven"
    modes = frozenset({"static", "window"})
    summary = "ridge regression on the features (example plugin)"

    @classmethod
    def default_options(cls) -> dict[str, Any]:
        return {"alpha_grid": (-3, 3, 13), "standardize": True}

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)  # rejects unknown options with a MethodError naming them
        check_log_grid_option(self.name, "alpha_grid", self.options["alpha_grid"])

    def search_space(self, data: Samples) -> SearchSpace:
        low, high, num = self.options["alpha_grid"]
        return {"alpha": log_grid(low, high, int(num))}

    # -- helpers ----------------------------------------------------------------------------
    def _checked(self, X: np.ndarray, what: str, n_features: int | None = None) -> np.ndarray:
        if n_features is not None and X.shape[1] != n_features:
            raise MethodError(f"method {self.name!r}: {what} have {X.shape[1]} feature columns but the model was "
                              f"trained on {n_features}; build them for the same inputs, mode and window")
        bad = ~np.isfinite(X)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise MethodError(f"method {self.name!r}: {what} hold a non-finite value (row {row}, column {col}); "
                              f"clean or drop such rows before the run")
        return X

    def _standardize(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if not self.options["standardize"]:
            return np.zeros(X.shape[1]), np.ones(X.shape[1])
        scale = X.std(axis=0)
        return X.mean(axis=0), np.where(scale > 0, scale, 1.0)

    def _alpha(self, params: Params) -> float:
        try:
            alpha = float(params["alpha"])
        except (KeyError, TypeError, ValueError):
            raise MethodError(f"method {self.name!r}: hyperparameter 'alpha' missing or not a number in {dict(params)!r}") from None
        if not alpha > 0:
            raise MethodError(f"method {self.name!r}: alpha must be > 0, got {alpha}")
        return alpha

    # -- the Method interface -----------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> RidgeFitted:
        alpha = self._alpha(params)
        X = self._checked(train.X, "training features")
        if len(X) == 0:
            raise MethodError(f"method {self.name!r}: no training rows")
        y = train.y
        mean, scale = self._standardize(X)
        Z = (X - mean) / scale
        intercept = y.mean(axis=0)
        weights = np.linalg.solve(Z.T @ Z + alpha * np.eye(Z.shape[1]), Z.T @ (y - intercept))
        return RidgeFitted(mean, scale, weights, intercept, alpha)

    def predict(self, fitted: RidgeFitted, data: Samples) -> list[np.ndarray]:
        X = self._checked(data.X, "features to predict", len(fitted.mean))
        return split_rows((X - fitted.mean) / fitted.scale @ fitted.weights + fitted.intercept, data)

    def describe(self, fitted: RidgeFitted) -> dict[str, Any]:
        return {"alpha": fitted.alpha, "weights": fitted.weights.tolist(), "intercept": fitted.intercept.tolist()}

    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator) -> np.ndarray:
        """(n_grid, n_rows, n_targets) from one SVD of the training features: w(alpha) = V diag(s / (s^2 + alpha)) U^T y."""
        alphas = [self._alpha(p) for p in grid]
        X = self._checked(train.X, "training features")
        mean, scale = self._standardize(X)
        Z = (X - mean) / scale
        intercept = train.y.mean(axis=0)
        U, s, Vt = np.linalg.svd(Z, full_matrices=False)
        Uty = U.T @ (train.y - intercept)
        E = (self._checked(data.X, "features to predict", X.shape[1]) - mean) / scale @ Vt.T
        return np.stack([E @ ((s / (s**2 + a))[:, None] * Uty) + intercept for a in alphas])
