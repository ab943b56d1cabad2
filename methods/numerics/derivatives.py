"""Total-variation regularised differentiation of sampled signals (for MoE and SINDy targets).

Models fitted on time derivatives (seed 003: MoE and SINDy) need dz/dt from noisy,
sampled trajectories; a plain finite difference amplifies the noise by 1/dt. This
module wraps the maintained ``derivative`` package's trend-filtered estimator
(``derivative.TrendFiltered``; ``order=0`` is Chartrand's total-variation derivative,
``order=1`` penalises the variation of the second derivative) and makes it usable on
long segments: the package solves a dense LASSO whose cost grows like the cube of the
length, so a long signal is cut into overlapping windows whose central parts are
stitched back together.
"""

from __future__ import annotations

import warnings
from typing import Sequence

import numpy as np
from derivative import TrendFiltered
from sklearn.exceptions import ConvergenceWarning
from threadpoolctl import threadpool_limits

from enginebench.errors import DataError

DEFAULT_WINDOW = 128
"""Samples per LASSO problem; the package's cost per sample grows with the window."""
DEFAULT_MARGIN = 16
"""Samples discarded at each inner window edge, where the estimate is least accurate."""


def window_bounds(n: int, window: int = DEFAULT_WINDOW, margin: int = DEFAULT_MARGIN) -> list[tuple[int, int, int, int]]:
    """Cut ``n`` samples into overlapping windows.

    Returns ``(lo, hi, a, b)`` tuples: solve on ``[lo, hi)``, keep ``[a, b)``. The kept
    ranges tile ``[0, n)`` exactly; every window is ``window`` long unless ``n`` is shorter.
    """
    if window < 4 or not 0 <= margin < window // 2:
        raise DataError(
            f"derivative windows: window={window} must be >= 4 and margin={margin} in [0, window/2); "
            "use e.g. window=128, margin=16"
        )
    if n <= window:
        return [(0, n, 0, n)]
    core = window - 2 * margin
    out = []
    for a in range(0, n, core):
        b = min(n, a + core)
        lo = max(0, a - margin)
        hi = min(n, lo + window)
        lo = max(0, hi - window)
        if out and out[-1][:2] == (lo, hi):  # the tail fits in the previous window
            out[-1] = (lo, hi, out[-1][2], b)
        else:
            out.append((lo, hi, a, b))
    return out


def _check_time(t: np.ndarray, where: str) -> float:
    """The constant sample period of ``t``; raises when ``t`` is not uniformly spaced."""
    if t.ndim != 1 or t.size < 3:
        raise DataError(f"{where}: need a 1-D time vector with at least 3 samples, got shape {t.shape}")
    steps = np.diff(t)
    h = float(np.median(steps))
    if not np.isfinite(t).all() or h <= 0:
        raise DataError(f"{where}: time must be finite and increasing")
    bad = np.flatnonzero(np.abs(steps - h) > 1e-6 * h)
    if bad.size:
        raise DataError(
            f"{where}: time is not uniformly sampled (step {steps[bad[0]]} s at row {bad[0] + 1}, "
            f"period {h} s); split the segment at gaps or resample it first"
        )
    return h


def tv_differentiate(
    y: np.ndarray,
    t: np.ndarray,
    alpha: float,
    *,
    order: int = 0,
    window: int = DEFAULT_WINDOW,
    margin: int = DEFAULT_MARGIN,
    tol: float = 1e-3,
    max_iter: int = 10_000,
    blas_threads: int | None = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed signal and derivative of ``y`` ((N,) or (N, c)) sampled at uniform times ``t``.

    Each column and window solves ``min 1/2 |A u - (y - y_0)|^2 + alpha |D^(order+1) u|_1``
    (``A`` integrates, ``D`` differentiates) with ``derivative.TrendFiltered``. ``alpha``
    is in the units of ``y``: scale it with the signal. Returns ``(y_smooth, dy_dt)``,
    both shaped like ``y``. ``blas_threads`` caps BLAS threads meanwhile (None: leave as
    is): the windows are small, and on busy shared cores threaded BLAS only waits.
    """
    y = np.asarray(y, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if not alpha > 0:
        raise DataError(f"tv derivative: alpha must be > 0, got {alpha}")
    if order not in (0, 1):
        raise DataError(f"tv derivative: order must be 0 (total variation of dy/dt) or 1, got {order}")
    flat = y.ndim == 1
    Y = y[:, None] if flat else y
    if Y.ndim != 2 or Y.shape[0] != t.shape[0]:
        raise DataError(f"tv derivative: y has shape {y.shape} but t has {t.shape[0]} samples; they must match in rows")
    if not np.isfinite(Y).all():
        raise DataError(f"tv derivative: y holds NaN or inf (first at row {int(np.argwhere(~np.isfinite(Y))[0, 0])})")
    _check_time(t, "tv derivative")
    smooth = np.empty_like(Y)
    deriv = np.empty_like(Y)
    estimator = TrendFiltered(order=order, alpha=alpha, tol=tol, max_iter=max_iter, precompute=True)
    # the package memoises its last solve keyed on the estimator's id, which a later
    # estimator with another alpha may reuse: start and end with an empty cache
    TrendFiltered._global.cache_clear()
    with warnings.catch_warnings(), threadpool_limits(blas_threads, user_api="blas"):
        # a LASSO stopped at max_iter still gives a usable estimate; do not flood the log
        warnings.simplefilter("ignore", ConvergenceWarning)
        for lo, hi, a, b in window_bounds(len(t), window, margin):
            tw = t[lo:hi] - t[lo]
            for c in range(Y.shape[1]):
                xs, xd = estimator.x(Y[lo:hi, c], tw), estimator.d(Y[lo:hi, c], tw)
                smooth[a:b, c] = xs[a - lo : b - lo]
                deriv[a:b, c] = xd[a - lo : b - lo]
    TrendFiltered._global.cache_clear()
    return (smooth[:, 0], deriv[:, 0]) if flat else (smooth, deriv)


def tv_derivative(y: np.ndarray, t: np.ndarray, alpha: float, **kwargs: int | float) -> np.ndarray:
    """Total-variation regularised dy/dt of ``y`` ((N,) or (N, c)) at uniform times ``t``.

    Keywords (``order``, ``window``, ``margin``, ``tol``, ``max_iter``, ``blas_threads``) go to
    :func:`tv_differentiate`.
    """
    return tv_differentiate(y, t, alpha, **kwargs)[1]


def segment_derivatives(
    ys: Sequence[np.ndarray], ts: Sequence[np.ndarray], alpha: float, **kwargs: int | float
) -> list[np.ndarray]:
    """:func:`tv_derivative` of each segment separately (never across segment boundaries)."""
    if len(ys) != len(ts):
        raise DataError(f"segment derivatives: {len(ys)} signals but {len(ts)} time vectors")
    return [tv_derivative(y, t, alpha, **kwargs) for y, t in zip(ys, ts)]
