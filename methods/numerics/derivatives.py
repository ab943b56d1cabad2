"""Regularised differentiation of sampled signals: the one differentiator of MoE and SINDy targets.

Models fitted on time derivatives (turboshaft-moe: MoE and SINDy) need dz/dt from noisy,
sampled trajectories; a plain finite difference amplifies the noise by 1/dt. This
module wraps the maintained ``derivative`` package's estimators: ``trend_filtered``
(``derivative.TrendFiltered``; ``order=0`` is Chartrand's total-variation derivative,
``order=1`` penalises the variation of the second derivative) and ``kalman`` (the RTS
smoother, quadratic regularisation), and makes them usable on long segments: a long
signal is cut into overlapping windows whose central parts are stitched back together.

The total-variation problem (``order=0``) is solved by default with ``solver="admm"``
(:mod:`tv_admm`): all windows of equal length in one batch, each to a verified optimum.
``solver="lasso"`` keeps the package's route (scikit-learn's coordinate descent per
window and column, settings ``tol``, ``max_iter``, ``precompute``), which at these sizes
usually stops at its iteration cap well short of the optimum; it stays for ``order=1``
and to reproduce results computed before the batched solver existed.
"""

from __future__ import annotations

import hashlib
import warnings
from collections import OrderedDict
from typing import Any, Sequence

import numpy as np

from enginebench.errors import DataError
from enginebench.methods.numerics.tv_admm import integral_matrix, tv_solve

DEFAULT_WINDOW = 128
"""Samples per LASSO problem; the package's cost per sample grows with the window."""
DEFAULT_MARGIN = 16
"""Samples discarded at each inner window edge, where the estimate is least accurate."""


KINDS = ("trend_filtered", "kalman")
"""Estimators of the ``derivative`` package offered here."""
SOLVERS = ("admm", "lasso")
"""Solvers of the total-variation problem: batched ADMM with a KKT test, or the package's Lasso."""


def window_bounds(
    n: int, window: int = DEFAULT_WINDOW, margin: int = DEFAULT_MARGIN, first_keep: int | None = None
) -> list[tuple[int, int, int, int]]:
    """Cut ``n`` samples into overlapping windows.

    Returns ``(lo, hi, a, b)`` tuples: solve on ``[lo, hi)``, keep ``[a, b)``. The kept
    ranges tile ``[0, n)`` exactly; every window is ``window`` long unless ``n`` is shorter.
    Every kept range after the first is ``window - 2 margin`` long and has ``margin``
    solved samples on each side; the first keeps ``[0, first_keep)`` (default ``window -
    2 margin``; ``window - margin`` also keeps the first window's leading rows, which
    have no inner edge).
    """
    if window < 4 or not 0 <= margin < window // 2:
        raise DataError(
            f"derivative windows: window={window} must be >= 4 and margin={margin} in [0, window/2); "
            "use e.g. window=128, margin=16"
        )
    core = window - 2 * margin
    first = core if first_keep is None else int(first_keep)
    if not core <= first <= window - margin:
        raise DataError(
            f"derivative windows: first_keep={first_keep} must be in [window - 2 margin, window - margin] = "
            f"[{core}, {window - margin}]"
        )
    if n <= window:
        return [(0, n, 0, n)]
    out = []
    for a in [0, *range(first, n, core)]:
        b = min(n, first if a == 0 else a + core)
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


def differentiate(
    y: np.ndarray,
    t: np.ndarray,
    alpha: float,
    *,
    kind: str = "trend_filtered",
    order: int = 0,
    window: int = DEFAULT_WINDOW,
    margin: int = DEFAULT_MARGIN,
    first_keep: int | None = None,
    tol: float = 1e-3,
    max_iter: int = 10_000,
    precompute: bool = True,
    blas_threads: int | None = 1,
    quiet: bool = True,
    solver: str = "admm",
    kkt_tol: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed signal and derivative of ``y`` ((N,) or (N, c)) sampled at uniform times ``t``.

    ``kind="trend_filtered"``: each column and window solves ``min 1/2 |A u - (y - y_0)|^2 +
    alpha |D^(order+1) u|_1`` (``A`` integrates, ``D`` differentiates). ``solver="admm"``
    (order 0): :func:`tv_admm.tv_solve` on every window at once, up to ``max_iter``
    iterations, each window accepted when optimal to ``kkt_tol``; ``solver="lasso"``
    (and order 1): ``derivative.TrendFiltered`` (sklearn's Lasso with ``tol``,
    ``max_iter``, ``precompute``). ``kind="kalman"``: ``derivative.Kalman(alpha)`` (``order`` and the
    Lasso settings unused). ``alpha`` is in the units of ``y``: scale it with the signal;
    pass time in samples to make it independent of the sample period. Windows follow
    :func:`window_bounds`. Returns ``(y_smooth, dy_dt)``, both shaped like ``y``.
    ``blas_threads`` caps BLAS threads meanwhile (None: leave as is): the windows are
    small, and on busy shared cores threaded BLAS only waits. ``quiet`` silences the
    ConvergenceWarning of a window stopped at ``max_iter`` (its estimate is still
    usable); ``quiet=False`` lets callers count them (one warning per window).
    """
    y = np.asarray(y, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if kind not in KINDS:
        raise DataError(f"derivative: unknown kind {kind!r}; use one of {', '.join(KINDS)}")
    if not alpha > 0:
        raise DataError(f"tv derivative: alpha must be > 0, got {alpha}")
    if order not in (0, 1):
        raise DataError(f"tv derivative: order must be 0 (total variation of dy/dt) or 1, got {order}")
    if solver not in SOLVERS:
        raise DataError(f"tv derivative: unknown solver {solver!r}; use one of {', '.join(SOLVERS)}")
    flat = y.ndim == 1
    Y = y[:, None] if flat else y
    if Y.ndim != 2 or Y.shape[0] != t.shape[0]:
        raise DataError(f"tv derivative: y has shape {y.shape} but t has {t.shape[0]} samples; they must match in rows")
    if not np.isfinite(Y).all():
        raise DataError(f"tv derivative: y holds NaN or inf (first at row {int(np.argwhere(~np.isfinite(Y))[0, 0])})")
    h = _check_time(t, "tv derivative")
    bounds = window_bounds(len(t), window, margin, first_keep)
    # imported here, not at the top: the method modules that import this one (moe's options) load without
    # derivative, scikit-learn and scipy.stats, so listing methods stays fast
    from threadpoolctl import threadpool_limits

    if kind == "trend_filtered" and order == 0 and solver == "admm":
        with threadpool_limits(blas_threads, user_api="blas"):
            return _tv_admm(Y, h, alpha, bounds, max_iter=max_iter, kkt_tol=kkt_tol, quiet=quiet, flat=flat)
    from derivative import Kalman, TrendFiltered
    from sklearn.exceptions import ConvergenceWarning

    smooth = np.empty_like(Y)
    deriv = np.empty_like(Y)
    if kind == "kalman":
        estimator = Kalman(alpha=alpha)
    else:
        estimator = TrendFiltered(order=order, alpha=alpha, tol=tol, max_iter=max_iter, precompute=precompute)
    # the package memoises its last solve keyed on the estimator's id, which a later
    # estimator with another alpha may reuse: start and end with an empty cache
    type(estimator)._global.cache_clear()
    with warnings.catch_warnings(), threadpool_limits(blas_threads, user_api="blas"):
        if quiet:
            warnings.simplefilter("ignore", ConvergenceWarning)
        for lo, hi, a, b in bounds:
            tw = t[lo:hi] - t[lo]
            for c in range(Y.shape[1]):
                xd = estimator.d(Y[lo:hi, c], tw)
                deriv[a:b, c] = xd[a - lo : b - lo]
                smooth[a:b, c] = estimator.x(Y[lo:hi, c], tw)[a - lo : b - lo]
    type(estimator)._global.cache_clear()
    return (smooth[:, 0], deriv[:, 0]) if flat else (smooth, deriv)


def _tv_admm(
    Y: np.ndarray, dt: float, alpha: float, bounds: list[tuple[int, int, int, int]], *, max_iter: int,
    kkt_tol: float, quiet: bool, flat: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`differentiate`'s TV route: every (window, column) solved in one batch per window length."""
    from sklearn.exceptions import ConvergenceWarning

    smooth = np.empty_like(Y)
    deriv = np.empty_like(Y)
    for length in sorted({hi - lo for lo, hi, _, _ in bounds}):
        group = [w for w in bounds if w[1] - w[0] == length]
        B = np.concatenate([Y[lo:hi] - Y[lo] for lo, hi, _, _ in group], axis=1)  # (length, windows x columns)
        U, converged = tv_solve(B, alpha, dt, max_iter=max_iter, tol=kkt_tol)
        X = integral_matrix(length, dt) @ U
        c = Y.shape[1]
        for k, (lo, hi, a, b) in enumerate(group):
            cols = slice(k * c, (k + 1) * c)
            deriv[a:b] = U[a - lo : b - lo, cols]
            smooth[a:b] = X[a - lo : b - lo, cols] + Y[lo]
        if not quiet:
            for _ in range(int((~converged).sum())):
                warnings.warn(
                    f"tv derivative: a window did not reach its optimum (KKT test {kkt_tol}) within "
                    f"max_iter={max_iter} iterations", ConvergenceWarning, stacklevel=3,
                )
    return (smooth[:, 0], deriv[:, 0]) if flat else (smooth, deriv)


def tv_differentiate(y: np.ndarray, t: np.ndarray, alpha: float, **kwargs: int | float) -> tuple[np.ndarray, np.ndarray]:
    """Total-variation (trend-filtered) smoothed ``y`` and dy/dt: :func:`differentiate` with its defaults."""
    return differentiate(y, t, alpha, kind="trend_filtered", **kwargs)


def tv_derivative(y: np.ndarray, t: np.ndarray, alpha: float, **kwargs: int | float) -> np.ndarray:
    """Total-variation regularised dy/dt of ``y`` ((N,) or (N, c)) at uniform times ``t``.

    Keywords (``order``, ``window``, ``margin``, ``first_keep``, ``tol``, ``max_iter``, ``precompute``,
    ``blas_threads``, ``quiet``) go to :func:`differentiate`.
    """
    return tv_differentiate(y, t, alpha, **kwargs)[1]


CACHE_SIZE = 4
"""Results :func:`segment_derivatives` keeps in memory (least recently used dropped first)."""
_cache: OrderedDict[bytes, list[np.ndarray]] = OrderedDict()


def digest(arrays: Sequence[np.ndarray], settings: Any) -> bytes:
    """A key for results computed from ``arrays`` (values and shapes, as float64) and ``settings``
    (anything whose repr names every setting that changes the result)."""
    h = hashlib.blake2b(digest_size=20)
    h.update(repr((settings, len(arrays))).encode())
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(repr(a.shape).encode())
        h.update(memoryview(a).cast("B"))
    return h.digest()


def _cache_key(ys: Sequence[np.ndarray], ts: Sequence[np.ndarray], alpha: float, kwargs: dict[str, Any]) -> bytes:
    """A digest of the signals, times (values and shapes) and every setting that changes the result."""
    return digest([*ys, *ts], (float(alpha), sorted(kwargs.items()), len(ys)))


def clear_cache() -> None:
    """Forget every result kept by :func:`segment_derivatives`."""
    _cache.clear()


def segment_derivatives(
    ys: Sequence[np.ndarray], ts: Sequence[np.ndarray], alpha: float, *, where: Sequence[str] | None = None,
    cache: bool = True, **kwargs: Any,
) -> list[np.ndarray]:
    """dy/dt (:func:`differentiate`) of each segment separately, never across segment boundaries.

    ``where`` names each segment in a failing segment's error (e.g. "method 'moe', training
    segment 'f1'"), so the one-line message says which segment to fix. With ``cache`` the
    result is kept in memory keyed on a digest of the signals, times, ``alpha`` and
    ``kwargs`` (the last ``CACHE_SIZE``): model selection fits every grid point on the same
    training trajectories, and the derivatives (minutes at full size) are solved once per
    process instead of once per fit. Callers get copies, so the kept arrays never change.
    """
    if len(ys) != len(ts):
        raise DataError(f"segment derivatives: {len(ys)} signals but {len(ts)} time vectors")
    key = _cache_key(ys, ts, alpha, kwargs) if cache else b""
    if cache and key in _cache:
        _cache.move_to_end(key)
        return [d.copy() for d in _cache[key]]
    out = []
    for j, (y, t) in enumerate(zip(ys, ts)):
        try:
            out.append(differentiate(y, t, alpha, **kwargs)[1])
        except DataError as exc:
            if where is None:
                raise
            raise DataError(f"{where[j]}: {exc}") from None
    if cache:
        _cache[key] = [d.copy() for d in out]
        while len(_cache) > CACHE_SIZE:
            _cache.popitem(last=False)
    return out
