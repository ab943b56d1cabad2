"""Ridge regression on the standardised features: the linear baseline of static and window tables.

A table whose only baseline is the training mean cannot show that a plain linear model wins;
``ridge`` is that model, selected like every method. The features are standardised on the
training rows (``make_scaler``, scale-safe), the targets centred, and

    w(alpha) = argmin |y - mean(y) - s(X) w|^2 + alpha n |w|^2,

with n the training rows. The penalty is relative to n, which for standardised features is each
column's own sum of squares (the diagonal of the Gram s(X)^T s(X)): alpha = 1 penalises a weight
as much as its column's fit. One thin SVD s(X) = U S V^T per training part serves every alpha
(w = V diag(S / (S^2 + alpha n)) U^T y) and every target at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from enginebench.declare import Declaration, log_grid as grid
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, log_grid, split_rows
from enginebench.methods.krls import _check_finite
from enginebench.methods.numerics.kernels import make_scaler, power_of_two_scale, standardize_rows
from enginebench.samples import Samples

if TYPE_CHECKING:  # sklearn is imported where a scaler is made: listing methods imports no sklearn
    from sklearn.preprocessing import StandardScaler

ALPHA_BOUND = (1e-14, 1e8)
"""Hard bounds of a searched penalty, relative to the training rows (the standardised Gram's diagonal): below
1e-14 the penalty is lost to rounding against the Gram's eigenvalues (at most the feature count); above 1e8 every
weight is shrunk below 1e-7 of its least-squares value, so the fit is the training mean."""


@dataclass(frozen=True)
class RidgeFitted:
    """A fitted ridge model: h(x) = (x - mean) / scale . weights + y_mean (plain arrays: it pickles)."""

    scaler: StandardScaler
    weights: np.ndarray
    """Weights on the standardised features, (d, k)."""
    y_mean: np.ndarray
    """The training mean of each target, (k,)."""
    alpha: float
    feature_names: tuple[str, ...] = ()


@dataclass(frozen=True)
class _Decomposition:
    """One training part's thin SVD and the rotated, centred targets: everything any alpha needs."""

    scaler: StandardScaler
    V: np.ndarray
    """Right singular vectors, (d, r)."""
    s: np.ndarray
    """Singular values of the standardised features, (r,)."""
    Uty: np.ndarray
    """U^T (y - y_mean) / y_scale, (r, k)."""
    y_mean: np.ndarray
    y_scale: np.ndarray
    """A power of two per target (exact): the solve sees targets of magnitude about 1 at any scale."""
    n: int

    def filters(self, alphas: np.ndarray) -> np.ndarray:
        """S / (S^2 + alpha n) per alpha, (len(alphas), r)."""
        return self.s / (self.s ** 2 + alphas[:, None] * self.n)


class Ridge(Method):
    """Ridge regression on the standardised features, its penalty selected on the training data.

    The linear baseline beside ``naive-mean`` in static and window tables: a nonlinear model that does
    not beat it has found no structure a straight line misses.
    """

    name = "ridge"
    family = "baseline"
    modes = frozenset({"static", "window"})
    joint_targets = True
    summary = "ridge regression on the standardised features (the linear baseline; one SVD serves every alpha)"
    declared_options = Declaration(
        grid("alpha_grid", (-6, 4, 21), "ridge penalties searched: log10 of alpha, relative to the training rows "
             "(the standardised Gram's diagonal) (low, high, count)", searches=("alpha",), bound=ALPHA_BOUND),
    )

    def search_space(self, data: Samples) -> SearchSpace:
        low, high, num = self.options["alpha_grid"]
        return {"alpha": log_grid(low, high, int(num))}

    def _decompose(self, train: Samples) -> _Decomposition:
        """Scaler, thin SVD of the standardised training features and the rotated centred targets."""
        X, y = train.X, train.y
        if len(X) == 0:
            raise MethodError(f"method {self.name!r}: the training samples are empty; give at least one training row")
        _check_finite(X, "training features", train.feature_names, self.name)
        _check_finite(y, "training targets", train.target_names, self.name)
        scaler = make_scaler(X, True)
        Xs = scaler.transform(X)
        y_mean = y.mean(axis=0)
        yc = y - y_mean
        y_scale = power_of_two_scale(yc)
        U, s, Vt = np.linalg.svd(Xs, full_matrices=False)
        return _Decomposition(scaler, Vt.T, s, U.T @ (yc / y_scale), y_mean, y_scale, len(X))

    def _features(self, scaler: StandardScaler, data: Samples) -> np.ndarray:
        """The standardised features to predict, checked for width and nan/inf."""
        blocks = [s.X for s in data.segments]
        width = blocks[0].shape[1] if blocks else len(data.feature_names)
        trained = int(scaler.n_features_in_)
        if width != trained:
            raise MethodError(
                f"method {self.name!r}: the data have {width} feature columns but the model was trained on "
                f"{trained}; predict with samples built for the same inputs, mode and window"
            )
        Xe = standardize_rows(scaler, blocks) if blocks else np.empty((0, trained))
        _check_finite(Xe, "features to predict", data.feature_names, self.name)
        return Xe

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> RidgeFitted:
        alpha = _alpha(params)
        dec = self._decompose(train)
        coef = dec.filters(np.array([alpha]))[0][:, None] * dec.Uty
        return RidgeFitted(dec.scaler, (dec.V @ coef) * dec.y_scale, dec.y_mean, alpha, tuple(train.feature_names))

    def predict(self, fitted: RidgeFitted, data: Samples) -> list[np.ndarray]:
        Xe = self._features(fitted.scaler, data)
        return split_rows(Xe @ fitted.weights + fitted.y_mean, data)

    def describe(self, fitted: RidgeFitted) -> dict[str, Any]:
        d = fitted.weights.shape[0]
        names = list(fitted.feature_names) if len(fitted.feature_names) == d else [f"x{j}" for j in range(d)]
        return {"alpha": float(fitted.alpha), "intercept": fitted.y_mean.tolist(),
                "weights (standardised features)": dict(zip(names, fitted.weights.tolist()))}

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Predictions for every alpha of ``grid``, (n_grid, n_rows, n_targets), from one SVD of the training part.

        The evaluation rows are rotated once (s(X_e) V); each alpha is then a diagonal filter of the rotated
        targets, and all alphas and targets are one matrix product.
        """
        alphas = np.array([_alpha(p) for p in grid], dtype=float)
        dec = self._decompose(train)
        Z = self._features(dec.scaler, data) @ dec.V
        r, k = dec.Uty.shape
        coef = dec.filters(alphas)[:, :, None] * dec.Uty  # (g, r, k)
        pred = Z @ coef.transpose(1, 0, 2).reshape(r, len(alphas) * k)
        out = pred.reshape(len(Z), len(alphas), k).transpose(1, 0, 2)
        return out * dec.y_scale + dec.y_mean


def _alpha(params: Params) -> float:
    """The penalty of a grid point, checked: one positive finite number."""
    unknown = sorted(set(params) - {"alpha"})
    if unknown:
        raise MethodError(f"method 'ridge': unknown hyperparameter(s) {', '.join(unknown)}; it has 'alpha'")
    if "alpha" not in params:
        raise MethodError(f"method 'ridge': hyperparameter 'alpha' missing from {dict(params)!r}; give 'alpha'")
    value = params["alpha"]
    try:
        alpha = float(value) if np.ndim(value) == 0 else np.nan
    except (TypeError, ValueError):
        alpha = np.nan
    if not (np.isfinite(alpha) and alpha > 0):
        raise MethodError(f"method 'ridge': hyperparameter 'alpha' must be one positive finite number, got {value!r}")
    return alpha
