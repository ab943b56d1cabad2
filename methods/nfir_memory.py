"""NFIR's lagged inputs and the data-derived memory estimate behind its default horizons.

The lag helpers turn a horizon (seconds) and a stride (samples) into lags and build the
lagged-input features with edge padding (``nfir_lags``, ``lagged_inputs``...).
``estimate_memory`` measures how far back the inputs explain the output, in samples, on
the training data: a ridge FIR of the lagged inputs and their squares on a ladder of
horizons, scored by blocked two-fold cross-validation, and derives the horizon grid
around it (the rule is in ``nfir``'s module docstring). The NFIR method itself is
``nfir.py``; the estimate is numerics on arrays only, kept
apart from the method so each can be read on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from enginebench.errors import MethodError

MEMORY_ROWS = 20_000
"""Training rows (evenly spaced) used by the memory estimate: enough for a few hundred ridge features."""
MEMORY_BLOCKS = 10
"""Contiguous row blocks of the memory estimate's two-fold cross-validation (even vs odd blocks)."""
MEMORY_SHARE = 0.95
"""The memory is the shortest horizon reaching this share of the best horizon's error reduction over lag 0."""
MEMORY_MIN_GAIN = 0.05
"""Below this relative error reduction over lag 0, longer windows are not worth their features: the memory is 0."""
RECORD_FRACTION = 4
"""Horizons are capped at the median training record length divided by this."""


def nfir_lags(horizon: float, stride: int, dt: float) -> np.ndarray:
    """Lags in samples: 0, stride, 2 stride, ... up to the horizon (seconds), as an int array."""
    if not (np.isfinite(horizon) and horizon >= 0):
        raise MethodError(f"method 'nfir': horizon must be a number of seconds >= 0, got {horizon!r}")
    if float(stride) != int(stride) or int(stride) < 1:
        raise MethodError(f"method 'nfir': stride must be a positive whole number of samples, got {stride!r}")
    span = int(math.floor(float(horizon) / dt + 1e-9))
    return np.arange(0, span + 1, int(stride), dtype=np.int64)


def horizon_samples(horizon: float, dt: float) -> int:
    """A horizon in seconds as a whole number of samples (rounded down, as ``nfir_lags`` does)."""
    return int(math.floor(float(horizon) / dt + 1e-9))


def bounded_stride(span: int, max_lags: int) -> int:
    """The smallest stride that covers ``span`` samples with at most ``max_lags`` lags (lag 0 included)."""
    return max(1, math.ceil(int(span) / (int(max_lags) - 1)))


def lag_feature_names(inputs: Sequence[str], lags: np.ndarray) -> tuple[str, ...]:
    """``u[t]``, ``u[t-6]``, ... per input, inputs outermost (the order of ``lagged_inputs``)."""
    return tuple(f"{c}[t]" if k == 0 else f"{c}[t-{int(k)}]" for c in inputs for k in lags)


def lagged_inputs(U: np.ndarray, lags: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """(N, c) raw inputs -> (len(rows), c * len(lags)): column j*len(lags)+i is input j at lag lags[i].

    ``rows`` (default: every row) are the positions whose windows are built. A lag
    reaching before the first row takes the first row (edge padding).
    """
    U = np.asarray(U, dtype=np.float64)
    at = np.arange(len(U)) if rows is None else np.asarray(rows, dtype=np.int64)
    idx = np.maximum(at[:, None] - np.asarray(lags)[None, :], 0)  # (N, L)
    return np.ascontiguousarray(np.swapaxes(U[idx], 1, 2).reshape(len(at), -1))


# -- memory estimate ---------------------------------------------------------------------------
@dataclass(frozen=True)
class MemoryEstimate:
    """How far back the inputs explain the output, in samples, and the horizon grid derived from it."""

    samples: int
    """The estimated memory M (samples)."""
    best: int
    """The ladder horizon with the smallest cross-validated error (samples)."""
    cap: int
    """The longest horizon considered: the median training record over ``RECORD_FRACTION``."""
    ladder: tuple[int, ...]
    errors: tuple[float, ...]
    """Cross-validated error of the ridge FIR at each ladder horizon, relative to the output's variance."""
    grid: tuple[int, ...]
    """The horizons searched (samples)."""
    max_lags: int
    rows: int
    """Training rows the estimate used."""

    def warnings(self) -> list[str]:
        out = []
        if self.samples and self.best >= self.cap and len(self.ladder) > 1:
            out.append(f"the input->output memory estimate reached its cap of {self.cap} samples (a quarter of the "
                       "median training record): the records may be shorter than the system's memory, or the output "
                       "drifts; NFIR cannot look further back; give longer records or horizons explicitly")
        if min(self.errors) > 0.9:
            out.append(f"no horizon of lagged inputs explains the output well (best cross-validated error "
                       f"{min(self.errors):.2f} of its variance, linear and quadratic terms): NFIR may not beat "
                       "the training mean")
        return out

    def describe(self, dt: float) -> dict[str, Any]:
        return {
            "rule": f"memory M = shortest horizon reaching {MEMORY_SHARE:.0%} of the best error reduction over lag 0 "
                    "(ridge FIR of lagged inputs and their squares, blocked 2-fold CV); grid M/2, M, 2M samples and the "
                    f"ladder's best, capped at the median record / {RECORD_FRACTION}; stride = ceil(h / (max_lags - 1))",
            "memory_samples": self.samples,
            "memory_s": self.samples * dt,
            "best_samples": self.best,
            "cap_samples": self.cap,
            "ladder_samples": list(self.ladder),
            "ladder_errors": [round(e, 6) for e in self.errors],
            "grid_samples": list(self.grid),
            "max_lags": self.max_lags,
            "rows": self.rows,
        }


def memory_ladder(cap: int) -> np.ndarray:
    """Horizons 0, 1, 2, 4, ... samples up to ``cap`` (``cap`` itself included)."""
    steps = [0] + [2 ** k for k in range(int(cap).bit_length()) if 2 ** k <= cap]
    return np.unique(np.r_[steps, int(cap)]).astype(np.int64)


def _ridge_cv_error(X: np.ndarray, y: np.ndarray, folds: np.ndarray) -> float:
    """Two-fold CV error of a lightly regularised linear fit, summed over targets, over the total variance."""
    resid = 0.0
    for k in (0, 1):
        a, b = folds != k, folds == k
        xm, ym = X[a].mean(axis=0), y[a].mean(axis=0)
        Xa, Xb = X[a] - xm, X[b] - xm
        G = Xa.T @ Xa
        lam = 1e-6 * float(np.trace(G)) / max(1, G.shape[0]) + 1e-12
        w = np.linalg.solve(G + lam * np.eye(G.shape[0]), Xa.T @ (y[a] - ym))
        resid += float(np.sum((y[b] - ym - Xb @ w) ** 2))
    return resid / float(np.sum((y - y.mean(axis=0)) ** 2))


def estimate_memory(
    U: Sequence[np.ndarray], rows: Sequence[np.ndarray], y: Sequence[np.ndarray], max_lags: int,
    max_rows: int = MEMORY_ROWS,
) -> MemoryEstimate:
    """The input -> output memory in samples and the horizon grid around it (see ``nfir``'s module docstring).

    ``U[i]`` are segment i's raw inputs (n_i, c), ``rows[i]`` the rows where its outputs
    ``y[i]`` (len(rows[i]), k) are measured. Deterministic: rows are thinned evenly.
    """
    lengths = np.array([len(u) for u in U], dtype=np.int64)
    cap = max(1, int(np.median(lengths)) // RECORD_FRACTION)
    Y = np.vstack([np.asarray(v, dtype=np.float64).reshape(len(r), -1) for v, r in zip(y, rows)])
    seg_of = np.concatenate([np.full(len(r), i) for i, r in enumerate(rows)])
    at = np.concatenate([np.asarray(r, dtype=np.int64) for r in rows])
    keep = np.arange(0, len(at), max(1, math.ceil(len(at) / max_rows)))
    Y, seg_of, at = Y[keep], seg_of[keep], at[keep]
    allU = np.vstack(U)
    mean, std = allU.mean(axis=0), allU.std(axis=0)
    std = np.where(std > 0, std, 1.0)
    Us = [(np.asarray(u, dtype=np.float64) - mean) / std for u in U]
    folds = (np.arange(len(at)) * MEMORY_BLOCKS // max(1, len(at))) % 2
    ladder = memory_ladder(cap)
    if len(at) < 4 or np.ptp(folds) == 0 or not np.any(np.ptp(Y, axis=0) > 0):
        errors = np.ones(len(ladder))
    else:
        errors = np.empty(len(ladder))
        for j, h in enumerate(ladder):
            lags = np.arange(0, h + 1, bounded_stride(h, max_lags))
            X = np.empty((len(at), Us[0].shape[1] * len(lags)))
            for i in np.unique(seg_of):
                sel = seg_of == i
                X[sel] = lagged_inputs(Us[i], lags, at[sel])
            errors[j] = _ridge_cv_error(np.hstack([X, X ** 2]), Y, folds)
    e0, best = float(errors[0]), float(errors.min())
    if e0 - best <= MEMORY_MIN_GAIN * e0:
        memory = 0
    else:
        memory = int(ladder[np.flatnonzero(errors <= best + (1 - MEMORY_SHARE) * (e0 - best))[0]])
    centre = max(memory, 1)
    lowest = int(ladder[int(np.argmin(errors))])  # the FIR's own best horizon
    grid = tuple(int(h) for h in np.unique(np.clip([centre // 2, centre, 2 * centre, lowest if memory else centre],
                                                   0, cap)))
    return MemoryEstimate(samples=memory, best=lowest, cap=cap, ladder=tuple(int(h) for h in ladder),
                          errors=tuple(float(e) for e in errors), grid=grid, max_lags=int(max_lags), rows=len(at))
