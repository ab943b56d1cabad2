"""MoE's training data: whole segments checked, corrected to standard day, augmented with input
derivatives, standardised, differentiated (TV) and laid out as schedulers V, regressors X and targets D."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.signal import savgol_filter

from enginebench.errors import MethodError
from enginebench.methods.moe.options import DERIVATIVE_WINDOW_SAMPLES, SIGN_WORDS, window_steps
from enginebench.methods.numerics.derivatives import segment_derivatives
from enginebench.samples import Samples


@dataclass
class Prepared:
    """Everything training needs, in network units (standardised signals, derivatives over ``d_scale``)."""

    scheduler_inputs: list[str]
    expert_inputs: list[str]
    derived: tuple[tuple[str, str, int], ...]
    sign: np.ndarray
    stats: dict[str, np.ndarray]
    """Training statistics, keyed as ``MoEFitted``'s fields: u_mean, u_scale, y_mean, y_scale, d_scale
    (the standardised derivative's scale, 1/s), y_min, y_max."""
    Us: list[np.ndarray]
    """Per segment: standardised augmented inputs."""
    Z: list[np.ndarray]
    """Per segment: standardised targets."""
    T: list[np.ndarray]
    si: list[int]
    ei: list[int]
    V: np.ndarray
    X: np.ndarray
    D: np.ndarray
    """dZ/dt / d_scale over all rows."""


def prepare(train: Samples, o: Mapping[str, Any]) -> Prepared:
    """The training samples as schedulers, regressors and derivative targets (see :class:`Prepared`)."""
    sched_in = _names(o["scheduler"], train.input_names, "scheduler")
    derived = _derived_columns(o["input_derivatives"], train.input_names)
    names = tuple(train.input_names) + tuple(d[0] for d in derived)
    expert_in = _names(o["expert_inputs"], names, "expert_inputs")
    expert_in += [d[0] for d in derived if d[0] not in expert_in]  # asked-for derivatives always join
    if not sched_in and not o["scheduler_state"]:
        raise MethodError("method 'moe': no scheduler: name at least one input in option scheduler or set scheduler_state=True")
    sign = _sign_matrix(o["signs"], train.target_names, expert_in, o["bias"])
    U, Y, T = _training_segments(train)
    corr = [correction_factors(o["correct"], train.input_names, train.target_names, u) for u in U]
    U = [u / fu for u, (fu, _) in zip(U, corr)]
    Y = [y / fy for y, (_, fy) in zip(Y, corr)]
    U = [augment(u, t, derived, train.input_names, o["derivative_window"]) for u, t in zip(U, T)]
    U_all, Y_all = np.concatenate(U), np.concatenate(Y)
    u_mean, u_scale = U_all.mean(0), _scale(U_all)
    y_mean, y_scale = Y_all.mean(0), _scale(Y_all)
    Z = [(y - y_mean) / y_scale for y in Y]
    # TV derivative with time counted in samples, so that tv_alpha does not depend on dt
    dZ = segment_derivatives(
        Z, [(t - t[0]) / train.dt for t in T], o["tv_alpha"], order=o["tv_order"], solver=o["tv_solver"],
        where=[f"method 'moe', training segment {s.id!r}" for s in train.segments],
    )
    dZ_all = np.concatenate(dZ) / train.dt
    d_scale = np.sqrt((dZ_all**2).mean(0))
    d_scale = np.where(d_scale > 0, d_scale, 1.0)
    Us = (U_all - u_mean) / u_scale
    Z_all = np.concatenate(Z)
    si = [train.input_names.index(c) for c in sched_in]
    ei = [names.index(c) for c in expert_in]
    V = np.hstack([Us[:, si]] + ([Z_all] if o["scheduler_state"] else []))
    X = np.hstack([Z_all, Us[:, ei]] + ([np.ones((len(Z_all), 1))] if o["bias"] else []))
    edges = np.cumsum([len(z) for z in Z])[:-1]
    stats = dict(u_mean=u_mean, u_scale=u_scale, y_mean=y_mean, y_scale=y_scale, d_scale=d_scale,
                 y_min=Y_all.min(0), y_max=Y_all.max(0))
    return Prepared(
        scheduler_inputs=sched_in, expert_inputs=expert_in, derived=derived, sign=sign, stats=stats,
        Us=np.split(Us, edges), Z=Z, T=T, si=si, ei=ei, V=V, X=X, D=dZ_all / d_scale,
    )


def _training_segments(train: Samples) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Per-segment raw inputs, targets and times; whole segments with finite values only."""
    if not train.has_targets:
        raise MethodError("method 'moe': the training samples carry no targets")
    U, Y, T = [], [], []
    for s in train.segments:
        if len(s.rows) != len(s.U) or not np.array_equal(s.rows, np.arange(len(s.U))):
            raise MethodError(
                f"method 'moe': training segment {s.id!r} is a row subsample ({len(s.rows)} of {len(s.U)} rows); "
                "derivative targets need whole segments: resample by segment, not by row"
            )
        if len(s.U) < 3:
            raise MethodError(f"method 'moe': training segment {s.id!r} has {len(s.U)} rows; at least 3 are needed for derivatives")
        for what, a, names in (("inputs", s.U, train.input_names), ("targets", s.y, train.target_names)):
            bad = np.argwhere(~np.isfinite(a))
            if bad.size:
                r, c = bad[0]
                raise MethodError(f"method 'moe': training segment {s.id!r}, {what} column {names[c]!r}, row {r}: NaN or inf")
        U.append(s.U)
        Y.append(s.y)
        T.append(s.t)
    if not U:
        raise MethodError("method 'moe': the training samples are empty; give at least one segment")
    return U, Y, T


def margin_matrix(max_time_constant: float | None, sign: np.ndarray, d_scale: np.ndarray, targets: Sequence[str]) -> np.ndarray:
    """(k, q) least magnitudes of the constrained coefficients, network units: 1/(tau_max d_scale) on own states."""
    margin = np.zeros_like(sign)
    if max_time_constant is None:
        return margin
    k = len(targets)
    wrong = [t for j, t in enumerate(targets) if sign[j, j] >= 0]
    if wrong:
        raise MethodError(
            f"method 'moe': option max_time_constant bounds own-state coefficients below 0, but target(s) "
            f"{', '.join(wrong)} have no '-' sign; use signs='stable' or {{'{wrong[0]}': '-'}}"
        )
    margin[np.arange(k), np.arange(k)] = 1.0 / (float(max_time_constant) * d_scale)
    return margin


def correction_factors(
    spec: Mapping[str, Mapping[str, Sequence[float]]] | None, inputs: Sequence[str], targets: Sequence[str], U: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Standard-day correction factors prod (U[:, c] / reference)^exponent from the raw inputs ``U`` (n, n_u).

    Returns (input factors (n, n_u), target factors (n, k)), 1 where a column is not corrected;
    the corrected value of a column is its raw value divided by its factor.
    """
    fu, fy = np.ones((len(U), len(inputs))), np.ones((len(U), len(targets)))
    if not spec:
        return fu, fy
    for col, by in spec.items():
        if col in inputs:
            out, j = fu, list(inputs).index(col)
        elif col in targets:
            out, j = fy, list(targets).index(col)
        else:
            raise MethodError(
                f"method 'moe': option correct names {col!r}, neither a target ({', '.join(targets)}) nor an input "
                f"({', '.join(inputs)})"
            )
        for c, (ref, exponent) in by.items():
            if c not in inputs:
                raise MethodError(f"method 'moe': option correct[{col!r}] uses {c!r}, not among the inputs ({', '.join(inputs)})")
            if c in spec:
                raise MethodError(f"method 'moe': option correct[{col!r}] uses {c!r}, which is itself corrected; correct by raw columns only")
            ratio = U[:, list(inputs).index(c)] / float(ref)
            if not (ratio > 0).all():
                raise MethodError(
                    f"method 'moe': option correct[{col!r}]: input {c!r} is <= 0 at row {int(np.argmax(~(ratio > 0)))}; "
                    "correction factors need positive values (absolute pressures and temperatures)"
                )
            out[:, j] *= ratio ** float(exponent)
    return fu, fy


def _derived_columns(spec: Mapping[str, int] | None, inputs: Sequence[str]) -> tuple[tuple[str, str, int], ...]:
    """(name, column, order) of every asked-for input derivative, orders 1..n per column."""
    if not spec:
        return ()
    unknown = [c for c in spec if c not in inputs]
    if unknown:
        raise MethodError(
            f"method 'moe': option input_derivatives names {', '.join(map(repr, unknown))}, not among the run-time "
            f"inputs ({', '.join(inputs)})"
        )
    return tuple((f"d{c}/dt" if n == 1 else f"d{n}{c}/dt{n}", c, n) for c, top in spec.items() for n in range(1, int(top) + 1))


def input_derivative(x: np.ndarray, t: np.ndarray, order: int, window_s: float | None = None) -> np.ndarray:
    """Smoothed ``order``-th time derivative of the columns of ``x`` (n, c) sampled at times ``t``.

    A cubic Savitzky-Golay fit over about ``window_s`` seconds, or ``DERIVATIVE_WINDOW_SAMPLES``
    samples when None (scipy; an odd window; the edges use the fit of the first / last window). Needs only the inputs, so it is the same at fit and run time;
    like the turboshaft-moe paper's TV-differentiated input derivatives it is not causal. Segments too short
    for a cubic window fall back to repeated central differences.
    """
    n = len(x)
    if n < 2:
        return np.zeros_like(x, dtype=np.float64)
    h = float(np.median(np.diff(t)))
    w = min(window_steps(window_s, h, DERIVATIVE_WINDOW_SAMPLES) | 1, n if n % 2 else n - 1)
    if w >= 5:
        return savgol_filter(x, w, 3, deriv=order, delta=h, axis=0, mode="interp")
    d = np.asarray(x, dtype=np.float64)
    for _ in range(order):
        d = np.gradient(d, t, axis=0) if len(d) > 1 else np.zeros_like(d)
    return d


def augment(
    u: np.ndarray, t: np.ndarray, derived: Sequence[tuple[str, str, int]], inputs: Sequence[str], window_s: float | None
) -> np.ndarray:
    """The raw inputs ``u`` (n, n_u) followed by the derived input derivatives (n, len(derived))."""
    if not derived:
        return u
    cols = [input_derivative(u[:, [list(inputs).index(c)]], t, n, window_s) for _, c, n in derived]
    return np.hstack([u] + cols)


def _names(chosen: Sequence[str] | None, available: Sequence[str], option: str) -> list[str]:
    if chosen is None:
        return list(available)
    unknown = [c for c in chosen if c not in available]
    if unknown:
        raise MethodError(
            f"method 'moe': option {option} names {', '.join(map(repr, unknown))}, not among the run-time inputs "
            f"({', '.join(available)})"
        )
    return list(chosen)


def _sign_matrix(signs: Any, targets: Sequence[str], inputs: Sequence[str], bias: bool) -> np.ndarray:
    """(k, q) signs over [z; u; 1]: a target name constrains its own-state coefficient, an input its column."""
    k, q = len(targets), len(targets) + len(inputs) + int(bias)
    sign = np.zeros((k, q))
    if signs == "stable":
        sign[np.arange(k), np.arange(k)] = -1
    elif isinstance(signs, Mapping):
        for name, word in signs.items():
            if name in targets:
                j = list(targets).index(name)
                sign[j, j] = SIGN_WORDS[word]
            elif name in inputs:
                sign[:, k + list(inputs).index(name)] = SIGN_WORDS[word]
            else:
                raise MethodError(
                    f"method 'moe': option signs names {name!r}, which is neither a target ({', '.join(targets)}) "
                    f"nor an expert input ({', '.join(inputs)})"
                )
    return sign


def _scale(values: np.ndarray) -> np.ndarray:
    """Column standard deviations usable as divisors (a constant column keeps scale 1)."""
    s = values.std(0)
    return np.where(s > 1e-9 * (1.0 + np.abs(values.mean(0))), s, 1.0)

