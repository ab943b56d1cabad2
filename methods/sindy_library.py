"""SINDy's numerics: the polynomial library, its batched open-loop simulation, the regularised
derivatives it is fitted on, and its equations written back in raw units (used by ``sindy.py``).

The library and simulation act on standardised signals; simulation steps every segment
at once on the shared fixed-step integrator (``numerics.integrate``: RK4 or Euler,
inputs held between samples, envelope -> diverged); derivatives come from the shared
differentiator (``numerics.derivatives``) in sample-index time.
"""

from __future__ import annotations

import itertools
import math
from typing import Any, Sequence

import numpy as np

from enginebench.errors import MethodError
from enginebench.methods.numerics.derivatives import SOLVERS as DERIVATIVE_SOLVERS  # noqa: F401 (SINDy's option)
from enginebench.methods.numerics.derivatives import differentiate as regularised_derivative
from enginebench.methods.numerics.integrate import integrate

DERIVATIVE_KINDS = ("trend_filtered", "kalman")
"""Regularised differentiators of the ``derivative`` package that SINDy offers.

``trend_filtered`` with order 0 is total-variation regularised differentiation (the
turboshaft-moe paper's choice); ``kalman`` is the Kalman (RTS) smoother, quadratic regularisation."""
INTEGRATORS = ("rk4", "euler")


def library_features(z: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """Polynomial library terms of the rows of ``z`` (n, n_vars) -> (n, n_terms).

    Term j is ``prod_v z[:, v] ** powers[j, v]``; this matches pysindy's
    ``PolynomialLibrary`` for the same ``powers_`` and is vectorised over rows.
    """
    z = np.asarray(z, dtype=np.float64)
    degree = int(powers.max()) if powers.size else 0
    table = np.empty((degree + 1, *z.shape))
    table[0] = 1.0
    for p in range(1, degree + 1):
        table[p] = table[p - 1] * z
    picked = table[powers, :, np.arange(powers.shape[1])[None, :]]  # (n_terms, n_vars, n)
    return picked.prod(axis=1).T


def model_rhs(coef: np.ndarray, powers: np.ndarray, x: np.ndarray, u: np.ndarray | None) -> np.ndarray:
    """dx/dt of a polynomial model for a batch of states (n, k) and controls (n, m)."""
    z = x if u is None or u.shape[1] == 0 else np.hstack([x, u])
    return library_features(z, powers) @ coef.T


def simulate_batch(
    coef: np.ndarray,
    powers: np.ndarray,
    x0: np.ndarray,
    controls: Sequence[np.ndarray],
    times: Sequence[np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    integrator: str = "rk4",
    substeps: int = 1,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Simulate ``dx/dt = coef @ theta(x, u)`` open loop on many segments at once.

    ``x0`` (S, k) are the initial states; ``controls[s]`` (N_s, m) and ``times[s]``
    (N_s,) the inputs and sample times of segment s. Inputs are held constant over
    each sample interval (zero-order hold); each interval is integrated with
    ``substeps`` fixed steps of RK4 or explicit Euler. All segments still running are
    advanced together in one vectorised step (the shared ``numerics.integrate``).

    A segment whose state turns non-finite or leaves [lower, upper] is stopped: its
    state is held at the last in-envelope value for the rest of its rows and it is
    flagged. Returns one (N_s, k) trajectory per segment and the flags (S,).
    """
    if integrator not in INTEGRATORS:
        raise MethodError(f"sindy: unknown integrator {integrator!r}; use one of {', '.join(INTEGRATORS)}")
    x0 = np.atleast_2d(np.asarray(x0, dtype=np.float64))
    n_seg, k = x0.shape
    lengths = np.array([len(t) for t in times], dtype=np.int64)
    if len(controls) != n_seg or lengths.size != n_seg:
        raise MethodError("sindy: simulate_batch needs one control array and one time array per initial state")
    if n_seg == 0:
        return [], np.zeros(0, dtype=bool)
    m = controls[0].shape[1] if controls[0].ndim == 2 else 0
    L = int(lengths.max())
    U = np.zeros((n_seg, L, m))
    H = np.zeros((n_seg, max(L - 1, 0)))
    for j, (c, t) in enumerate(zip(controls, times)):
        U[j, : lengths[j]] = np.asarray(c, dtype=np.float64).reshape(lengths[j], m)
        H[j, : lengths[j] - 1] = np.diff(np.asarray(t, dtype=np.float64))

    def rhs(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return model_rhs(coef, powers, x, u if m else None)

    traj, diverged = integrate(rhs, x0, U, H, lengths, lower, upper, method=integrator, inputs="hold",
                               substeps=int(substeps))
    return [traj[j, :n] for j, n in enumerate(lengths)], diverged


def differentiate(
    x: np.ndarray,
    dt: float,
    *,
    kind: str = "trend_filtered",
    alpha: float = 1e-3,
    chunk: int = 256,
    margin: int = 32,
    max_iter: int = 20000,
    solver: str = "admm",
) -> np.ndarray:
    """Regularised time derivative of uniformly sampled signals ``x`` (n, k).

    The shared differentiator (``numerics.derivatives.differentiate``): ``trend_filtered``
    (order 0: total-variation regularisation, solved by ``solver``: batched ADMM to a
    verified optimum, or the package's Lasso with tol 1e-4) or ``kalman``. Both work with
    dense n x n matrices, so long signals are cut into overlapping chunks of ``chunk``
    rows; each chunk contributes its interior (``margin`` rows are dropped at each inner
    edge). The regularisation acts in sample-index time,
    which makes ``alpha`` independent of the sample period and keeps the LASSO well
    scaled. Lasso ConvergenceWarnings are let through (``_prepare`` counts them).
    """
    if kind not in DERIVATIVE_KINDS:
        raise MethodError(f"sindy: unknown derivative {kind!r}; use one of {', '.join(DERIVATIVE_KINDS)}")
    if chunk < 2 * margin + 8:
        raise MethodError(f"sindy: derivative_chunk ({chunk}) must exceed 2 x derivative_margin + 8 ({2 * margin + 8})")
    x = np.asarray(x, dtype=np.float64)
    index = np.arange(x.shape[0], dtype=np.float64)
    _, d = regularised_derivative(
        x, index, alpha, kind=kind, window=chunk, margin=margin, first_keep=chunk - margin, tol=1e-4,
        max_iter=max_iter, precompute=False, quiet=False, solver=solver,
    )
    return d / dt


def raw_coefficients(fit: Any) -> np.ndarray:
    """Coefficients (k, n_terms) of the same polynomial written in raw signal units.

    Each standardised term prod_v ((v - m_v) / s_v) ** p_v is expanded binomially;
    the result multiplies raw monomials of the same library and gives d(raw)/dt in
    units per second. Loops run over library terms, never over samples.
    """
    means = np.r_[fit.state_mean, fit.control_mean]
    stds = np.r_[fit.state_std, fit.control_std]
    index = {tuple(int(p) for p in row): j for j, row in enumerate(fit.powers)}
    raw = np.zeros_like(fit.coef)
    for j, row in enumerate(fit.powers):
        if not fit.coef[:, j].any():
            continue
        ranges = [range(int(p) + 1) for p in row]
        for kept in itertools.product(*ranges):
            factor = 1.0
            for v, (p, q) in enumerate(zip(row, kept)):
                factor *= math.comb(int(p), q) * (-means[v]) ** (int(p) - q) / stds[v] ** int(p)
            raw[:, index[kept]] += fit.coef[:, j] * factor
    return raw * (fit.state_std / fit.time_scale)[:, None]
