"""``nfir``: nonlinear finite impulse response, KRLS on lagged run-time inputs only (turboshaft-moe, eq. 11).

y(t) ~ f(u(t), u(t - s dt), u(t - 2 s dt), ..., u(t - h)) with the stride ``s`` (samples)
and the horizon ``h`` as hyperparameters, f a Gaussian-kernel regularised least-squares
model (``methods/krls.py``). The features are built here from each segment's raw inputs
``U`` and never from outputs, so the model is BIBO-stable by construction: bounded inputs
give bounded predictions, and there is nothing to diverge. Rows near a segment's start,
whose window reaches before the first sample, repeat that first sample (edge padding), so
every row of a trajectory gets a prediction.

Horizons derived from the data (the default, ``horizons = None``). Records arrive sampled
anywhere from 1 ms to 10 s, so no horizon in seconds suits them all. Instead the memory of
the input -> output relation is measured in samples on the training data
(:func:`estimate_memory`): on a ladder of horizons 0, 1, 2, 4, ... samples, capped at a
quarter of the median training record, a ridge regression of the output(s) on the
features NFIR itself would see (each input at the ladder's lags, at most ``max_lags``
lags, plus their squares) is scored by blocked two-fold cross-validation. The memory M is
the shortest horizon that reaches 95 % of the error reduction the best horizon achieves
over lag 0 alone (0 when longer windows cut lag 0's error by less than 5 %); for a
first-order lag of time constant tau, M is about 1.5 tau. The horizon grid is then M/2,
M, 2M samples (M taken as at least 1) plus the ladder's best horizon when it lies beyond
2M, all capped as above, each searched with the stride that keeps at most ``max_lags``
lags per input:
``stride = ceil(h / (max_lags - 1))``. ``describe`` reports the ladder's errors, M, the
grid and a warning when M reached the cap (the record may be shorter than the system's
memory) or when no horizon explains the output (NFIR may not beat the mean).

Explicit grids keep their old meaning: ``horizons`` in seconds, ``strides`` in samples
(searched as a product); with ``horizons`` given and ``strides = None`` each horizon gets
the stride above. The hyperparameters are always ``horizon`` (seconds, a whole number of
samples when derived) and, optionally, ``stride`` (samples; derived from the horizon and
``max_lags`` when absent).

Gamma is relative to the feature count d: the kernel is exp(-(gamma / d) |x - x'|^2) on
standardised features, so one gamma grid suits every (horizon, stride) pair. The kernel
is fitted on at most ``max_rows`` training rows drawn with the job's generator; predictions
are computed in chunks of rows so that a long evaluation set never forms a huge kernel.

The lag helpers and the memory estimate (``estimate_memory``, ``MemoryEstimate``) are
``nfir_memory.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from enginebench.declare import log_grid as grid, whole
from enginebench.errors import MethodError
from enginebench.method import Params, SearchSpace, SegmentPredictions, split_rows
from enginebench.methods.input_history import HISTORY_OPTIONS, InputHistory
from enginebench.methods.krls import GAMMA_BOUND, LAMBDA_BOUND, KRLS, KRLSFitted
from enginebench.methods.nfir_memory import MemoryEstimate, horizon_samples
from enginebench.methods.numerics.kernel_grid import kernel_ridge_grid
from enginebench.methods.numerics.kernels import check_positive, gaussian, sq_distances
from enginebench.samples import Samples

__all__ = [
    "NFIR", "NFIRFitted", "PREDICT_CHUNK"
]

PREDICT_CHUNK = 8192
"""Evaluation rows per kernel block (8192 x 1000 doubles = 66 MB)."""


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
    dt: float = float("nan")
    memory: MemoryEstimate | None = field(default=None)
    """The memory estimate on the fitting data when the horizons were derived (``horizons = None``)."""


class NFIR(InputHistory, KRLS):
    """Kernel regression of the output on a window of past run-time inputs (no past outputs)."""

    name = "nfir"
    family = "data-driven"
    joint_targets = True
    modes = frozenset({"simulation", "static"})
    summary = "nonlinear FIR: KRLS on lagged inputs only (BIBO-stable); horizons derived from the data's memory (samples)"

    declared_options = KRLS.declared_options.extend(
        grid("gamma_grid", (-5, -1, 5), "kernel widths searched: log10 of gamma relative to the feature count d "
             "(the kernel is exp(-(gamma / d) |x - x'|^2)) (low, high, count)", searches=("gamma",),
             bound=GAMMA_BOUND),
        grid("lambda_grid", (-8, 0, 9), "ridge penalties searched: log10 of lambda (low, high, count)",
             searches=("lambda",), bound=LAMBDA_BOUND),
        *HISTORY_OPTIONS[:3],
        whole("max_rows", 1000, "training rows the kernel is fitted on (a draw of the job's generator; 0 = all)",
              low=0, unit="rows", message="{name} must be an integer >= 0 (0 = all rows), got {value}"),
        HISTORY_OPTIONS[3],
    )

    def search_space(self, data: Samples) -> SearchSpace:
        """Horizons (s) and strides as given, else derived (see the module docstring); then gamma, lambda."""
        return {**self.history_space(data), **super().search_space(data)}

    def _kernel_rows(self, train: Samples, rng: np.random.Generator) -> np.ndarray:
        """Training rows used by the kernel: all, or ``max_rows`` drawn without replacement (sorted)."""
        n, m = len(train), int(self.options["max_rows"])
        if m == 0 or n <= m:
            return np.arange(n)
        return np.sort(rng.choice(n, size=m, replace=False))

    def _params(self, params: Params, dt: float) -> tuple[np.ndarray, float, int, float, float]:
        lags, horizon, stride = self.history_params(params, dt, ("gamma", "lambda"))
        gamma = float(check_positive(params["gamma"], "gamma")[0])
        lam = float(check_positive(params["lambda"], "lambda")[0])
        return lags, horizon, int(stride), gamma, lam

    # -- Method ---------------------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> NFIRFitted:
        self.check_mode(train.mode)
        lags, horizon, stride, gamma, lam = self._params(params, train.dt)
        names, cols = self._columns(train)
        lagged = self.lagged(train, lags, cols)
        sub = lagged.take(self._kernel_rows(lagged, rng))
        d = len(lagged.feature_names)
        krls = KRLS.fit(self, sub, {"gamma": gamma / d, "lambda": lam}, rng)
        memory = self.memory(train) if self.options["horizons"] is None else None
        return NFIRFitted(krls=krls, inputs=names, lags=lags, horizon=horizon, stride=stride, gamma=gamma,
                          n_rows=len(sub), dt=float(train.dt), memory=memory)

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
        """Lags, kernel settings and, when the horizons were derived, the memory estimate behind them."""
        out: dict[str, Any] = {
            "horizon_s": fitted.horizon,
            "horizon_samples": horizon_samples(fitted.horizon, fitted.dt) if np.isfinite(fitted.dt) else None,
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
        return {**out, **self.history_description(getattr(fitted, "memory", None), fitted.dt)}

    def lag_groups(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
                   ) -> Iterator[tuple[list[int], Samples, Samples, np.ndarray, np.ndarray]]:
        """The grid points by lag set: (their indices, the lagged kernel rows of ``train``, ``data`` lagged alike,
        their gammas relative to the feature count, their lambdas). The kernel rows are drawn once for all."""
        parsed = [self._params(p, train.dt) for p in grid]
        names, cols = self._columns(train)
        rows = self._kernel_rows(train, rng)
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
            yield members, sub, self.lagged(data, lags, eval_cols), gammas, lambdas

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Every grid point, (n_grid, n_rows, k): per lag set one scaling and one set of distances, per gamma one
        ``ridge_solutions`` call for all its lambdas (``numerics/kernel_grid.py``; 2-3x faster than the
        eigendecomposition per gamma it replaced, ``benchmarks/nfir_selection.py``).

        The kernel rows are drawn once, so every grid point is fitted on the same rows.
        """
        out = np.empty((len(grid), len(data), len(train.target_names)))
        for members, sub, evaluated, gammas, lambdas in self.lag_groups(train, data, grid, rng):
            if self.uses_falkon(len(sub)):
                out[members] = KRLS.predict_grid(self, sub, evaluated,
                                                 [{"gamma": g, "lambda": lam} for g, lam in zip(gammas, lambdas)], rng)
                continue
            scaler, Xs, yc, y_mean, y_scale = self._train_arrays(sub)
            Xe = scaler.transform(evaluated.X)
            target = np.asarray(members)
            for idx, block in kernel_ridge_grid(Xs, yc, Xe, gammas, lambdas, PREDICT_CHUNK):
                out[target[idx]] = block * y_scale + y_mean
        return out

    def c_model(self, fitted):
        """The C step of ``fitted`` for an FMU and the real-time figures (``methods/export``)."""
        from enginebench.methods.export.models import nfir_c

        return nfir_c(fitted)

    def step_times(self, fitted, data):
        """Its C step timed over ``data`` for the real-time figures (``methods/export/harness.py``)."""
        from enginebench.methods.export.harness import c_step_times

        return c_step_times(self.c_model(fitted), data)
