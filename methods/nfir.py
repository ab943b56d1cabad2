"""``nfir``: nonlinear finite impulse response, KRLS on lagged run-time inputs only (seed 003, eq. 11).

y(t) ~ f(u(t), u(t - s dt), u(t - 2 s dt), ..., u(t - h)) with the stride ``s`` (samples)
and the horizon ``h`` (seconds) as hyperparameters, f a Gaussian-kernel regularised
least-squares model (``methods/krls.py``). The features are built here from each
segment's raw inputs ``U`` and never from outputs, so the model is BIBO-stable by
construction: bounded inputs give bounded predictions, and there is nothing to diverge.
Rows near a segment's start, whose window reaches before the first sample, repeat that
first sample (edge padding), so every row of a trajectory gets a prediction.

Gamma is relative to the feature count d: the kernel is exp(-(gamma / d) |x - x'|^2) on
standardised features, so one gamma grid suits every (horizon, stride) pair. The kernel
is fitted on at most ``max_rows`` training rows drawn with the job's generator; predictions
are computed in chunks of rows so that a long evaluation set never forms a huge kernel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from enginebench.datasets.samples import Samples
from enginebench.errors import MethodError
from enginebench.methods.base import Params, SearchSpace, SegmentPredictions, split_rows
from enginebench.methods.kernels import Spectral, check_positive, gaussian, sq_distances
from enginebench.methods.krls import KRLS, KRLSFitted

PREDICT_CHUNK = 8192
"""Evaluation rows per kernel block (8192 x 1000 doubles = 66 MB)."""


def nfir_lags(horizon: float, stride: int, dt: float) -> np.ndarray:
    """Lags in samples: 0, stride, 2 stride, ... up to the horizon (seconds), as an int array."""
    if not (np.isfinite(horizon) and horizon >= 0):
        raise MethodError(f"method 'nfir': horizon must be a number of seconds >= 0, got {horizon!r}")
    if float(stride) != int(stride) or int(stride) < 1:
        raise MethodError(f"method 'nfir': stride must be a positive whole number of samples, got {stride!r}")
    span = int(math.floor(float(horizon) / dt + 1e-9))
    return np.arange(0, span + 1, int(stride), dtype=np.int64)


def lag_feature_names(inputs: Sequence[str], lags: np.ndarray) -> tuple[str, ...]:
    """``u[t]``, ``u[t-6]``, ... per input, inputs outermost (the order of ``lagged_inputs``)."""
    return tuple(f"{c}[t]" if k == 0 else f"{c}[t-{int(k)}]" for c in inputs for k in lags)


def lagged_inputs(U: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """(N, c) raw inputs -> (N, c * len(lags)): column j*len(lags)+i is input j at lag lags[i].

    A lag reaching before the first row takes the first row (edge padding).
    """
    U = np.asarray(U, dtype=np.float64)
    idx = np.maximum(np.arange(len(U))[:, None] - np.asarray(lags)[None, :], 0)  # (N, L)
    return np.ascontiguousarray(np.swapaxes(U[idx], 1, 2).reshape(len(U), -1))


@dataclass(frozen=True)
class NFIRFitted:
    """A fitted NFIR model: the KRLS model on lagged features plus how to build them."""

    krls: KRLSFitted
    inputs: tuple[str, ...]
    lags: np.ndarray
    horizon: float
    stride: int
    gamma: float
    """The relative gamma searched; the kernel uses ``krls.gamma = gamma / d``."""
    n_rows: int


class NFIR(KRLS):
    """Kernel regression of the output on a window of past run-time inputs (no past outputs)."""

    name = "nfir"
    family = "data-driven"
    modes = frozenset({"simulation", "static"})
    summary = "nonlinear FIR: KRLS on lagged inputs only (BIBO-stable); horizon and stride searched (seed 003)"

    @classmethod
    def default_options(cls) -> dict[str, Any]:
        return {
            **KRLS.default_options(),
            "gamma_grid": (-5, -1, 5),  # relative to the feature count: gamma / d
            "lambda_grid": (-8, 0, 9),
            "horizons": (2.0, 4.0, 8.0),  # seconds
            "strides": (6, 12),  # samples
            "max_rows": 1000,  # training rows for the kernel (0 = all; FALKON above exact_max_rows)
            "inputs": None,  # run-time input names to lag; None = all
        }

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        o = self.options
        for key in ("horizons", "strides"):
            if isinstance(o[key], (str, bytes)) or not isinstance(o[key], Sequence) or not len(o[key]):
                raise MethodError(f"method 'nfir': option {key} must be a non-empty list, got {o[key]!r}")
        for h in o["horizons"]:
            nfir_lags(h, 1, 1.0)
        for s in o["strides"]:
            nfir_lags(0.0, s, 1.0)
        if not (isinstance(o["max_rows"], (int, np.integer)) and o["max_rows"] >= 0):
            raise MethodError(f"method 'nfir': option max_rows must be an integer >= 0 (0 = all rows), got {o['max_rows']!r}")
        if o["inputs"] is not None and (isinstance(o["inputs"], str) or not all(isinstance(c, str) for c in o["inputs"])):
            raise MethodError(f"method 'nfir': option inputs must be a list of input column names or None, got {o['inputs']!r}")

    def search_space(self, data: Samples) -> SearchSpace:
        space = super().search_space(data)
        return {
            "horizon": np.array([float(h) for h in self.options["horizons"]]),
            "stride": np.array([int(s) for s in self.options["strides"]]),
            **space,
        }

    # -- features -------------------------------------------------------------------------
    def _columns(self, data: Samples) -> tuple[tuple[str, ...], list[int]]:
        names = tuple(data.input_names if self.options["inputs"] is None else self.options["inputs"])
        missing = [c for c in names if c not in data.input_names]
        if missing:
            raise MethodError(
                f"method 'nfir': option inputs names {', '.join(missing)}, which are not run-time inputs of the data "
                f"({', '.join(data.input_names)})"
            )
        if not names:
            raise MethodError("method 'nfir': no input to lag; the data have no run-time input columns")
        return names, [data.input_names.index(c) for c in names]

    def lagged(self, data: Samples, lags: np.ndarray, columns: list[int] | None = None) -> Samples:
        """``data`` with X replaced by the lagged inputs at each segment's evaluated rows."""
        names, cols = self._columns(data) if columns is None else (tuple(data.input_names[c] for c in columns), columns)
        for s in data.segments:
            if not np.isfinite(s.U[:, cols]).all():
                row, col = np.argwhere(~np.isfinite(s.U[:, cols]))[0]
                raise MethodError(
                    f"method 'nfir': segment {s.id!r} has nan/inf in input {names[col]!r} at row {row}; clean or drop it"
                )
        segs = tuple(replace(s, X=lagged_inputs(s.U[:, cols], lags)[s.rows]) for s in data.segments)
        return replace(data, segments=segs, feature_names=lag_feature_names(names, lags))

    def _kernel_rows(self, train: Samples, rng: np.random.Generator) -> np.ndarray:
        """Training rows used by the kernel: all, or ``max_rows`` drawn without replacement (sorted)."""
        n, m = len(train), int(self.options["max_rows"])
        if m == 0 or n <= m:
            return np.arange(n)
        return np.sort(rng.choice(n, size=m, replace=False))

    @staticmethod
    def _params(params: Params, dt: float) -> tuple[np.ndarray, float, int, float, float]:
        missing = [k for k in ("horizon", "stride", "gamma", "lambda") if k not in params]
        if missing:
            raise MethodError(
                f"method 'nfir': hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}; "
                "give horizon (s), stride (samples), gamma and lambda"
            )
        unknown = sorted(set(params) - {"horizon", "stride", "gamma", "lambda"})
        if unknown:
            raise MethodError(f"method 'nfir': unknown hyperparameter(s) {', '.join(unknown)}; it has horizon, stride, gamma, lambda")
        lags = nfir_lags(float(params["horizon"]), params["stride"], dt)
        gamma = float(check_positive(params["gamma"], "gamma")[0])
        lam = float(check_positive(params["lambda"], "lambda")[0])
        return lags, float(params["horizon"]), int(params["stride"]), gamma, lam

    # -- Method ---------------------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> NFIRFitted:
        self.check_mode(train.mode)
        lags, horizon, stride, gamma, lam = self._params(params, train.dt)
        names, cols = self._columns(train)
        lagged = self.lagged(train, lags, cols)
        sub = lagged.take(self._kernel_rows(lagged, rng))
        d = len(lagged.feature_names)
        krls = KRLS.fit(self, sub, {"gamma": gamma / d, "lambda": lam}, rng)
        return NFIRFitted(krls=krls, inputs=names, lags=lags, horizon=horizon, stride=stride, gamma=gamma, n_rows=len(sub))

    def predict(self, fitted: NFIRFitted, data: Samples) -> list[np.ndarray]:
        self.check_mode(data.mode)
        missing = [c for c in fitted.inputs if c not in data.input_names]
        if missing:
            raise MethodError(f"method 'nfir': the data lack input column(s) {', '.join(missing)} that the model was fitted on")
        lagged = self.lagged(data, fitted.lags, [data.input_names.index(c) for c in fitted.inputs])
        k = fitted.krls
        Xe = k.scaler.transform(lagged.X)
        out = np.empty((len(Xe), k.alpha.shape[1]))
        for a in range(0, len(Xe), PREDICT_CHUNK):
            out[a:a + PREDICT_CHUNK] = gaussian(sq_distances(Xe[a:a + PREDICT_CHUNK], k.X_train), k.gamma) @ k.alpha
        parts = split_rows(out + k.y_mean, data)
        return SegmentPredictions(parts) if data.mode == "simulation" else parts

    def describe(self, fitted: NFIRFitted) -> dict[str, Any]:
        return {
            "horizon_s": fitted.horizon,
            "stride_samples": fitted.stride,
            "lags_samples": [int(x) for x in fitted.lags],
            "inputs": list(fitted.inputs),
            "n_features": int(fitted.krls.X_train.shape[1]),
            "gamma_relative": fitted.gamma,
            "gamma": float(fitted.krls.gamma),
            "lambda": float(fitted.krls.lam),
            "solver": fitted.krls.solver,
            "kernel_rows": fitted.n_rows,
            "bibo_stable": True,
        }

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Every grid point, (n_grid, n_rows, k): per lag set one scaling, per gamma one eigendecomposition.

        The kernel rows are drawn once, so every grid point is fitted on the same rows.
        """
        parsed = [self._params(p, train.dt) for p in grid]
        names, cols = self._columns(train)
        rows = self._kernel_rows(train, rng)
        k_out = len(train.target_names)
        out = np.empty((len(parsed), len(data), k_out))
        by_lags: dict[tuple[int, ...], list[int]] = {}
        for i, (lags, *_rest) in enumerate(parsed):
            by_lags.setdefault(tuple(int(x) for x in lags), []).append(i)
        eval_cols = [data.input_names.index(c) for c in names]
        for lag_key, members in by_lags.items():
            lags = np.array(lag_key, dtype=np.int64)
            sub = self.lagged(train, lags, cols).take(rows)
            d = len(sub.feature_names)
            gammas = np.array([parsed[i][3] / d for i in members])
            lambdas = np.array([parsed[i][4] for i in members])
            if self.uses_falkon(len(sub)):
                out[members] = KRLS.predict_grid(self, sub, self.lagged(data, lags, eval_cols),
                                                 [{"gamma": g, "lambda": lam} for g, lam in zip(gammas, lambdas)], rng)
                continue
            scaler, Xs, yc, y_mean = self._train_arrays(sub)
            Xe = scaler.transform(self.lagged(data, lags, eval_cols).X)
            D_train = sq_distances(Xs)
            for gamma in dict.fromkeys(gammas.tolist()):
                idx = np.flatnonzero(gammas == gamma)
                spectral = Spectral.from_kernel(gaussian(D_train, gamma), overwrite=True)
                # dual coefficients of every lambda, (n, L * k): K_eval @ alpha is cheaper than K_eval @ V
                alpha = spectral.lift(spectral.ridge_coeffs(spectral.project(yc), lambdas[idx])).reshape(len(Xs), -1)
                target = np.asarray(members)[idx]
                for a in range(0, len(Xe), PREDICT_CHUNK):
                    K = gaussian(sq_distances(Xe[a:a + PREDICT_CHUNK], Xs), gamma)
                    block = (K @ alpha).reshape(len(K), len(idx), k_out)
                    out[target, a:a + PREDICT_CHUNK] = np.moveaxis(block, 1, 0) + y_mean
        return out
