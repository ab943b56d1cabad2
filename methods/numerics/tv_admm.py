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
   active columns, penalty moved to the right side), then *refined*: while it fails the
   optimality conditions, jumps that lost their sign are dropped, the largest violator of
   each run of steps with ``|G| > alpha/dt`` is added, and the fit is solved again (up to
   ``REFINE`` fits, stopping on a cycle). ADMM's signs are slow to settle on these
   ill-conditioned problems (gengine2 NOx windows: a median of 13 signs of z differ from
   the minimiser's after 100 iterations, 4 after 1,000); the refinement fixes them in a
   few fits, so most windows are accepted on the first pass, not thousands of iterations on.
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
REFINE = 20
"""Most active-set refinements of one polished window per polishing pass (:func:`_refined_polish`)."""


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


def _signed_fit(AC: np.ndarray, b: np.ndarray, S: np.ndarray, s: np.ndarray, lam: float) -> np.ndarray:
    """Coefficients on the columns ``S`` of ``AC`` (``S[0] == 0``, the free constant) minimising
    ``1/2 |X t - b|^2 + lam s't`` with the signs ``s`` held fixed (``s[0] == 0``).

    QR of the active columns with ``b`` appended (R and Q'b without forming Q), which keeps
    the conditioning of ``X`` instead of squaring it; the penalty moves to the right side.
    """
    k = S.size
    R = qr(np.column_stack([AC[:, S], b]), mode="r", overwrite_a=True, check_finite=False)[0]
    return solve_triangular(R[:k, :k], R[:k, k] - solve_triangular(R[:k, :k], lam * s, trans="T"))


def _refined_polish(AC: np.ndarray, b: np.ndarray, z: np.ndarray, lam: float, steps: int | None = None) -> np.ndarray:
    """The polished ``u`` of one window from the signs of ``z``, then refined by active-set steps.

    Polish: the support and signs of ``z`` fix a piecewise-constant ``u``; its exact value is
    one least-squares solve (:func:`_signed_fit`). Refinement: while that ``u`` fails the
    optimality conditions, the gradient ``G`` along each step (what :func:`kkt_violation`
    tests) changes the signed support: a jump whose fitted value lost the sign it was fitted
    with is dropped, and each run of neighbouring off-support steps with ``|G| > lam`` (one
    sign) adds its largest as a jump of sign ``-sign(G)`` (the gradient is smooth along the
    window, so a run marks one missing jump, not many); then the signed fit is solved again.
    It stops when the signed support no longer changes (the conditions then hold to
    rounding: the window's minimiser), after ``steps`` more fits, or when a signed support
    comes back (a cycle), and returns the fit that violated the conditions least. The caller
    accepts a window only by the KKT test, so the steps need no convergence proof of their
    own; ``steps=0`` is the plain polish.
    """
    steps = REFINE if steps is None else steps
    n = b.size
    s_full = np.zeros(n)
    s_full[1:] = np.sign(z)
    seen = {s_full.astype(np.int8).tobytes()}
    best, best_viol = None, np.inf
    for step in range(steps + 1):
        S = np.r_[0, np.flatnonzero(s_full)]
        t = np.zeros(n)
        t[S] = _signed_fit(AC, b, S, s_full[S], lam)
        G = AC.T @ (AC @ t - b)
        sign = np.sign(t[1:])
        viol = max(abs(G[0]), np.where(sign != 0, np.abs(G[1:] + lam * sign), np.abs(G[1:]) - lam).max())
        if viol < best_viol:
            best, best_viol = t, viol
        if step == steps:
            break
        # drop the jumps that lost their sign; add the largest of each run of neighbouring violators of one sign
        on = s_full != 0
        new = np.where(on & (np.sign(t) == s_full), s_full, 0.0)
        excess = np.where(on, 0.0, np.abs(G) - lam)
        excess[0] = 0.0
        idx = np.flatnonzero(excess > 0)
        if idx.size:
            sg = np.sign(G[idx])
            starts = np.flatnonzero(np.r_[True, (np.diff(idx) != 1) | (np.diff(sg) != 0)])
            vals = excess[idx]
            peak = vals == np.repeat(np.maximum.reduceat(vals, starts), np.diff(np.r_[starts, idx.size]))
            new[idx[peak]] = -sg[peak]
        key = new.astype(np.int8).tobytes()
        if key in seen:  # no change (the signed support is optimal, to rounding) or a cycle
            break
        seen.add(key)
        s_full = new
    t = best
    return t[0] + np.r_[0.0, np.cumsum(t[1:])]


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
        P = np.column_stack([_refined_polish(AC, B[:, j], Z[:, j], lam) for j in new]) if new.size else np.empty((n, 0))
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
