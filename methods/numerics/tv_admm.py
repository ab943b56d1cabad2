"""Total-variation derivatives of many equal-length windows at once, solved to optimality.

Chartrand's TV derivative of a window ``b`` (``n`` samples, period ``dt``) is

    u* = argmin_u  1/2 |A u - b|^2 + alpha |D u|_1,

``A`` the trapezoid integral (first row zero, so ``b`` is the signal minus its first
sample), ``D`` the forward difference divided by ``dt``. The ``derivative`` package hands
this to scikit-learn's coordinate descent, whose columns (double integrals) are so
correlated that at full size every window stops at its iteration cap far from the
minimiser (one turboshaft fuel-flow window: objective 0.0569 stopped, 0.0036 optimal).

Here every window of a segment set is solved in one batch:

1. ADMM on ``z = D u``: the u-step is one matrix product with the inverse of
   ``A'A + rho D'D``, shared by all windows (they have the same length and period), so
   an iteration is one GEMM over the whole batch; the z-step is a soft threshold.
2. Every ``ROUND`` iterations each window not yet accepted whose signs of ``z`` changed
   since its last try is *polished*: the support and signs of ``z`` fix a
   piecewise-constant ``u``, whose exact value is a small least-squares solve (QR of the
   active columns, penalty moved to the right side).
3. A polished window is accepted when it satisfies the optimality (KKT) conditions of
   the problem to ``tol`` (relative to ``alpha``): then it *is* the minimiser, to
   rounding, whatever ADMM's own accuracy. Windows still open after ``max_iter``
   iterations keep the better of their ADMM and polished estimates (by objective) and
   are reported as not converged.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import qr, solve_triangular

ROUND = 100
"""ADMM iterations between polishing passes."""
RHO_PER_ALPHA = 10.0
"""ADMM penalty ``rho = RHO_PER_ALPHA * alpha / dt``: soft threshold ``alpha / (dt rho)`` = 0.1
(in units of the derivative's jumps); of 1, 10 and 100 x alpha the best for alpha 1e-4 .. 1e-2
on turboshaft windows (docs/methods.md). Acceptance rests on the KKT test, so rho only sets
the speed."""


def integral_matrix(n: int, dt: float) -> np.ndarray:
    """Trapezoid running integral (n x n): row i integrates samples 0..i; row 0 is zero."""
    A = np.tril(np.full((n, n), dt))
    A[:, 0] = A[np.diag_indices(n)] = dt / 2
    A[0] = 0.0
    return A


def objective(U: np.ndarray, B: np.ndarray, A: np.ndarray, alpha: float, dt: float) -> np.ndarray:
    """Each column's 1/2 |A u - b|^2 + alpha |D u|_1."""
    return 0.5 * ((A @ U - B) ** 2).sum(0) + alpha / dt * np.abs(np.diff(U, axis=0)).sum(0)


def kkt_violation(U: np.ndarray, B: np.ndarray, A: np.ndarray, alpha: float, dt: float) -> np.ndarray:
    """Each column's largest violation of the optimality conditions, relative to ``alpha``.

    With ``u = c + cumsum(v)`` (``v`` the jumps), optimality is: the gradient of the
    squared error is zero along ``c`` and equals ``-alpha/dt sign(v_i)`` where ``v_i != 0``,
    and is at most ``alpha/dt`` in size where ``v_i == 0``.
    """
    lam = alpha / dt
    g = A.T @ (A @ U - B)
    G = np.cumsum(g[::-1], axis=0)[::-1]  # G[0]: along c; G[i]: along the step starting at i
    V = np.diff(U, axis=0)
    on = V != 0
    viol = np.where(on, np.abs(G[1:] + lam * np.sign(V)), np.maximum(np.abs(G[1:]) - lam, 0.0))
    return np.maximum(np.abs(G[0]), viol.max(axis=0, initial=0.0)) / lam


def _polish(AC: np.ndarray, b: np.ndarray, z: np.ndarray, lam: float) -> np.ndarray:
    """The piecewise-constant u with jumps where ``z != 0`` (signs of ``z``) minimising the objective.

    ``AC``: column 0 is ``A 1`` (the free constant), column i the integral of a unit
    step at sample i. Solves ``min 1/2 |X t - b|^2 + lam s't`` by QR of the active
    columns with ``b`` appended (R and Q'b without forming Q), which keeps the
    conditioning of ``X`` instead of squaring it.
    """
    S = np.flatnonzero(z)
    k = S.size + 1
    R = qr(np.column_stack([AC[:, np.r_[0, S + 1]], b]), mode="r", overwrite_a=True, check_finite=False)[0]
    q = np.r_[0.0, lam * np.sign(z[S])]
    theta = solve_triangular(R[:k, :k], R[:k, k] - solve_triangular(R[:k, :k], q, trans="T"))
    v = np.zeros(z.size)
    v[S] = theta[1:]
    return theta[0] + np.r_[0.0, np.cumsum(v)]


def tv_solve(
    B: np.ndarray, alpha: float, dt: float = 1.0, *, max_iter: int = 20_000, tol: float = 1e-3
) -> tuple[np.ndarray, np.ndarray]:
    """TV derivatives ``U`` (n, W) of the windows ``B`` (n, W; each column minus its first sample).

    Returns ``(U, converged)``: ``converged[w]`` says window ``w`` passed the KKT test
    (:func:`kkt_violation` <= ``tol``) within ``max_iter`` ADMM iterations.
    """
    B = np.asarray(B, dtype=np.float64)
    n, W = B.shape
    lam = alpha / dt
    A = integral_matrix(n, dt)
    if n < 3:
        return np.linalg.lstsq(A, B, rcond=None)[0], np.ones(W, dtype=bool)
    AC = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]
    rho = RHO_PER_ALPHA * lam
    # the u-step's matrix is shared by every window
    D = np.diff(np.eye(n), axis=0)
    Minv = np.linalg.inv(A.T @ A + rho * (D.T @ D))
    AtB = A.T @ B
    out = np.empty_like(B)
    done = np.zeros(W, dtype=bool)
    open_ = np.arange(W)
    Z = np.zeros((n - 1, W))
    Y = np.zeros((n - 1, W))  # scaled dual
    tried = np.full((n - 1, W), 2, dtype=np.int8)  # signs of z at each window's last polish (2: none yet)
    for it in range(1, max_iter + 1):
        R = Z - Y
        DtR = np.zeros((n, R.shape[1]))  # D' (z - y) by differences
        DtR[:-1] -= R
        DtR[1:] += R
        U = Minv @ (AtB + rho * DtR)
        DU = np.diff(U, axis=0)
        V = DU + Y
        Z = np.sign(V) * np.maximum(np.abs(V) - lam / rho, 0.0)
        Y += DU - Z
        last = it == max_iter
        if it % ROUND and not last:
            continue
        signs = np.sign(Z).astype(np.int8)
        # a polish depends on the signs of z only: windows whose signs did not change are not polished again
        new = np.flatnonzero((signs != tried).any(axis=0) | last)
        tried[:, new] = signs[:, new]
        P = np.column_stack([_polish(AC, B[:, j], Z[:, j], lam) for j in new]) if new.size else np.empty((n, 0))
        ok = np.zeros(open_.size, dtype=bool)
        ok[new] = kkt_violation(P, B[:, new], A, alpha, dt) <= tol
        out[:, open_[ok]] = P[:, ok[new]]
        done[open_[ok]] = True
        if last:
            keep = ~ok  # every open window was polished on the last pass: keep the better estimate
            better = objective(P[:, keep], B[:, keep], A, alpha, dt) < objective(U[:, keep], B[:, keep], A, alpha, dt)
            out[:, open_[keep]] = np.where(better, P[:, keep], U[:, keep])
            break
        if ok.all():
            break
        keep = ~ok
        open_, B, AtB, Z, Y, tried = open_[keep], B[:, keep], AtB[:, keep], Z[:, keep], Y[:, keep], tried[:, keep]
    return out, done
