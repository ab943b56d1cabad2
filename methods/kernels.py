"""Gaussian kernels and the spectral solver shared by the kernel methods (KRLS, MTL-KRLS).

One eigendecomposition of the training kernel, Q = V diag(s) V^T, turns every
regularised solve (Q + lambda I)^-1 y into a per-component division in the
eigenbasis, so a whole vector of regularisation values costs one decomposition.
``Spectral`` keeps the decomposition and the per-component solve separable: the hybrid
MTL-KRLS projects its two targets with ``project``, solves its own 3x3 systems per
component and comes back with ``lift`` or ``predict_coeffs``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from sklearn.metrics.pairwise import euclidean_distances
from sklearn.preprocessing import StandardScaler

from enginebench.errors import MethodError

NEGATIVE_EIG_RTOL = 1e-8
"""Eigenvalues below -NEGATIVE_EIG_RTOL * max|s| mean the matrix is not a kernel matrix."""


def make_scaler(X: np.ndarray, standardize: bool = True) -> StandardScaler:
    """A scaler fitted on training features: zero mean, unit std (std 0 -> 1), or the identity.

    With ``standardize=False`` the returned scaler leaves features unchanged, so fitted
    models always carry a scaler and the prediction path is the same either way.
    """
    return StandardScaler(with_mean=standardize, with_std=standardize).fit(X)


def sq_distances(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Squared Euclidean distances |a_i - b_j|^2, shape (len(A), len(B)), clipped at 0.

    ``B=None`` means ``B = A`` (the diagonal is then exactly zero).
    """
    D = euclidean_distances(A, B, squared=True)
    return np.maximum(D, 0.0, out=D)


def gaussian(D: np.ndarray, gamma: float, out: np.ndarray | None = None) -> np.ndarray:
    """Gaussian kernel exp(-gamma * D) from squared distances D: K(x, x') = exp(-gamma |x - x'|^2)."""
    out = np.multiply(D, -float(gamma), out=out)
    return np.exp(out, out=out)


def check_positive(values: np.ndarray, name: str) -> np.ndarray:
    """``values`` as a 1-D float array, or a MethodError if any is not a positive finite number."""
    try:
        arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
    except (TypeError, ValueError):
        raise MethodError(f"hyperparameter {name!r} must be a positive number, got {values!r}") from None
    bad = ~(np.isfinite(arr) & (arr > 0))
    if bad.any():
        raise MethodError(
            f"hyperparameter {name!r} must be a positive finite number, got {float(arr[bad][0])!r}; "
            f"choose values > 0 (e.g. a log grid 1e-4 ... 1e4)"
        )
    return arr


@dataclass(frozen=True)
class Spectral:
    """Eigendecomposition Q = V diag(s) V^T of a symmetric positive semi-definite kernel matrix.

    ``s`` is ascending and clipped at 0 (rounding makes the smallest eigenvalues of a
    Gaussian kernel matrix slightly negative); ``V`` has orthonormal columns.
    """

    V: np.ndarray
    s: np.ndarray

    @classmethod
    def from_kernel(cls, Q: np.ndarray, overwrite: bool = False) -> "Spectral":
        """Decompose ``Q`` (n x n; only its lower triangle is read). ``overwrite`` lets eigh reuse Q's memory."""
        Q = np.asarray(Q, dtype=np.float64)
        if Q.ndim != 2 or Q.shape[0] != Q.shape[1]:
            raise MethodError(f"kernel matrix must be square, got shape {Q.shape}")
        if Q.shape[0] == 0:
            raise MethodError("kernel matrix is empty: no training rows; give at least one training sample")
        if not np.isfinite(Q).all():
            raise MethodError("kernel matrix has nan/inf entries; check the features and gamma for nan/inf")
        try:  # divide and conquer is fastest, but LAPACK's syevd can fail to converge on
            # nearly singular kernel matrices; the relatively robust driver then takes over
            s, V = scipy.linalg.eigh(Q, driver="evd", overwrite_a=False, check_finite=False)
        except np.linalg.LinAlgError:
            s, V = scipy.linalg.eigh(Q, driver="evr", overwrite_a=overwrite, check_finite=False)
        scale = float(np.max(np.abs(s)))
        if s[0] < -NEGATIVE_EIG_RTOL * scale:
            raise MethodError(
                f"kernel matrix is not positive semi-definite (smallest eigenvalue {s[0]:.3g}, "
                f"largest magnitude {scale:.3g}); pass a valid kernel matrix"
            )
        return cls(V=V, s=np.maximum(s, 0.0))

    def __len__(self) -> int:
        return self.s.size

    def project(self, y: np.ndarray) -> np.ndarray:
        """Components in the eigenbasis, V^T y: (n,) or (n, k) -> same shape."""
        return self.V.T @ y

    def lift(self, coeffs: np.ndarray) -> np.ndarray:
        """Back from the eigenbasis, V @ coeffs; ``coeffs`` is (n, ...) and keeps its trailing axes."""
        flat = np.asarray(coeffs).reshape(len(self), -1)
        return (self.V @ flat).reshape(np.shape(coeffs))

    def ridge_coeffs(self, Vty: np.ndarray, lambdas: np.ndarray) -> np.ndarray:
        """Eigenbasis coefficients of (Q + lambda I)^-1 y for every lambda: (n, k) -> (n, L, k)."""
        lambdas = check_positive(lambdas, "lambda")
        Vty = np.asarray(Vty, dtype=np.float64).reshape(len(self), -1)
        return Vty[:, None, :] / (self.s[:, None, None] + lambdas[None, :, None])

    def ridge_alpha(self, y: np.ndarray, lambdas: np.ndarray) -> np.ndarray:
        """Dual coefficients alpha(lambda) = V diag(1/(s + lambda)) V^T y, shape (n, L, k)."""
        y2 = np.asarray(y, dtype=np.float64).reshape(len(self), -1)
        return self.lift(self.ridge_coeffs(self.project(y2), lambdas))

    def predict_coeffs(self, K_eval: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
        """Predictions K_eval @ V @ coeffs for eigenbasis ``coeffs`` (n, L, k): shape (L, m, k).

        ``K_eval`` (m x n) is the kernel between evaluation rows and training rows;
        K_eval @ V is formed once and shared by every lambda. ``L`` may be any flattened
        grid (e.g. lambda x theta for MTL-KRLS), as long as the coefficients are per component.
        """
        coeffs = np.asarray(coeffs, dtype=np.float64)
        n, L, k = coeffs.shape
        KV = np.asarray(K_eval, dtype=np.float64) @ self.V
        return np.moveaxis((KV @ coeffs.reshape(n, L * k)).reshape(-1, L, k), 1, 0)

    def ridge_predict(self, K_eval: np.ndarray, y: np.ndarray, lambdas: np.ndarray) -> np.ndarray:
        """Kernel ridge predictions at ``K_eval`` (m x n) for every lambda: shape (L, m, k)."""
        y2 = np.asarray(y, dtype=np.float64).reshape(len(self), -1)
        return self.predict_coeffs(K_eval, self.ridge_coeffs(self.project(y2), lambdas))


# -- the ridge path without an eigendecomposition ----------------------------------------
#
# Model selection needs, per gamma, the solutions of (K + lambda I) x = b for a whole
# vector of lambdas, not the eigenvectors themselves. Two exact-to-rounding routes are
# cheaper than ``Spectral`` (eigh costs ~17 Cholesky factorisations; measured 0.92 s at
# n = 1600 on one core):
#
# * Householder tridiagonalisation K = Q T Q^T (LAPACK dsytrd, ~0.3 s at n = 1600) turns
#   every shifted system into an O(n) symmetric positive definite tridiagonal solve:
#   x = Q (T + lambda I)^-1 Q^T b. Backward stable like eigh, no tolerance involved.
# * Shifted Lanczos with full reorthogonalisation: one Krylov basis started at b serves
#   every lambda (Krylov spaces are shift invariant). For a Gaussian kernel it converges
#   in a few dozen matrix-vector products when gamma is small (numerically low rank) or
#   large (K close to I). Its solutions are accepted only with an a-posteriori
#   certificate on the true residual r = b - (K + lambda I) x, computed by one matrix
#   product: for a kernel with k(x, x) <= 1 the prediction error at any point is at most
#   |r| / sqrt(lambda) (Cauchy-Schwarz in the RKHS metric (K + lambda I)^-1), and that
#   bound must be below ``rtol`` times the RMS of b; or the residual must be as small as a
#   backward-stable direct solve leaves it (normwise backward error below
#   ``BACKWARD_ETA``), the floor that Cholesky or eigh share. Lambdas that miss both go
#   to Cholesky (a few) or to the Householder route (many).

BACKWARD_ETA = 4 * np.finfo(np.float64).eps
"""Normwise backward error |r| / (|K + lambda I| |x| + |b|) accepted from the Krylov solver."""
KRYLOV_RTOL = 1e-10
"""Bound on the Krylov solution's prediction error, relative to the RMS of the right-hand side."""
KRYLOV_CHECK_EVERY = 8
"""Lanczos iterations between two convergence checks (each check is an O(k) solve per lambda)."""
KRYLOV_SLACK = 2.0
"""Lanczos stops early when its extrapolated iteration count exceeds this many budgets."""
KRYLOV_MIN_STEPS = 32
"""No early stop before this many Lanczos iterations (the first rates are too pessimistic)."""
CHOLESKY_MAX_SHIFTS = 5
"""Up to this many lambdas are solved by one Cholesky factorisation each (dsytrd costs ~5.5)."""


def _tridiagonal_solve(d: np.ndarray, e: np.ndarray, B: np.ndarray) -> np.ndarray | None:
    """Solve the SPD tridiagonal system (diag d, off-diagonal e) for B; None if not positive definite."""
    if len(d) == 1:
        return B / d[0] if d[0] > 0 else None
    _, _, X, info = scipy.linalg.lapack.dptsv(d, e, B)
    return X if info == 0 else None


def householder_ridge(K: np.ndarray, B: np.ndarray, lambdas: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Exact (K + lambda I)^-1 B for every lambda by one Householder tridiagonalisation: (n, L, k).

    K = Q T Q^T (dsytrd); each lambda is an SPD tridiagonal solve with Q^T B, and Q is
    applied back to all solutions at once (dormqr on the reflectors). Falls back to the
    eigendecomposition of T (eigenvalues clipped at 0, as ``Spectral`` does) when a shifted
    T is not positive definite, which happens only when rounding makes K indefinite beyond
    lambda.
    """
    K = np.asarray(K, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64).reshape(len(K), -1)
    lambdas = check_positive(lambdas, "lambda")
    n, k = B.shape
    out = np.empty((n, len(lambdas), k))
    if n == 1:
        out[0] = B[0][None, :] / (K[0, 0] + lambdas[:, None])
        return out
    lapack = scipy.linalg.lapack
    lwork = int(lapack.dsytrd_lwork(n, lower=1)[0])
    # K is symmetric: its transpose is the Fortran-ordered view LAPACK can overwrite in place
    A, d, e, tau, info = lapack.dsytrd(K.T if overwrite else K, lower=1, lwork=max(lwork, 1), overwrite_a=overwrite)
    if info != 0:
        raise MethodError(f"tridiagonal reduction of the kernel matrix failed (LAPACK info {info})")
    reflectors = A[1:, :-1]
    Z = B.copy()
    Z[1:], _, info = lapack.dormqr("L", "T", reflectors, tau, B[1:], max(1, 64 * k))
    solutions = np.empty((n, len(lambdas) * k))
    for i, lam in enumerate(lambdas):
        X = _tridiagonal_solve(d + lam, e, Z)
        if X is None:  # rounding made K indefinite beyond this lambda: solve with T's spectrum clipped at 0
            s, W = scipy.linalg.eigh_tridiagonal(d, e, check_finite=False)
            X = W @ ((W.T @ Z) / (np.maximum(s, 0.0)[:, None] + lam))
        solutions[:, i * k:(i + 1) * k] = X
    solutions[1:], _, info = lapack.dormqr("L", "N", reflectors, tau, solutions[1:], max(1, 64 * solutions.shape[1]))
    return solutions.reshape(n, len(lambdas), k)


def cholesky_ridge(K: np.ndarray, B: np.ndarray, lambdas: np.ndarray) -> np.ndarray | None:
    """(K + lambda I)^-1 B by one Cholesky factorisation per lambda, (n, L, k); None if one is not PD."""
    B = np.asarray(B, dtype=np.float64).reshape(len(K), -1)
    out = np.empty((len(K), len(lambdas), B.shape[1]))
    for i, lam in enumerate(lambdas):
        A = K + lam * np.eye(len(K))
        try:
            factor = scipy.linalg.cho_factor(A, lower=True, overwrite_a=True, check_finite=False)
        except np.linalg.LinAlgError:
            return None
        out[:, i] = scipy.linalg.cho_solve(factor, B, check_finite=False)
    return out


def _hopeless(estimate: np.ndarray, previous: np.ndarray, target: np.ndarray, steps: int, kmax: int) -> bool:
    """True when the residual estimates, extrapolated at their rate since the last check, need
    more than ``KRYLOV_SLACK`` iteration budgets: stop early and hand those lambdas to a direct solver.

    Lanczos convergence speeds up as Ritz values settle, so the extrapolation is pessimistic;
    the slack keeps slowly starting but converging cases.
    """
    open_ = (estimate > target) & (previous > 0)
    if not open_.any():
        return False
    rate = np.clip(estimate[open_] / previous[open_], 1e-300, 1 - 1e-3)
    needed = KRYLOV_CHECK_EVERY * np.log(target[open_] / estimate[open_]) / np.log(rate)
    return bool(steps + needed.max() > KRYLOV_SLACK * kmax)


def lanczos_ridge(
    K: np.ndarray, b: np.ndarray, lambdas: np.ndarray, maxiter: int, rtol: float = KRYLOV_RTOL
) -> tuple[np.ndarray, np.ndarray, int]:
    """Shifted Lanczos (full reorthogonalisation) for (K + lambda I) x = b, every lambda from one basis.

    Returns the solutions (n, L), a mask of the lambdas whose true residual passed the
    certificate (see the comment above) and the number of iterations. The iteration stops
    when the Lanczos residual estimates beta_k |e_k^T (T_k + lambda I)^-1 e_1| |b| of
    every lambda are below their targets, on breakdown (an invariant subspace: exact), or
    after ``maxiter`` iterations.
    """
    n = len(b)
    lambdas = np.asarray(lambdas, dtype=np.float64)
    b_norm = float(np.linalg.norm(b))
    if b_norm == 0.0:
        return np.zeros((n, len(lambdas))), np.ones(len(lambdas), dtype=bool), 0
    K_norm = float(np.abs(K).sum(axis=1).max())  # |K|_inf >= |K|_2 for symmetric K
    forward = rtol * np.sqrt(lambdas) * b_norm / np.sqrt(n)  # |r| / sqrt(lambda) <= rtol * RMS(b)
    kmax = max(1, min(int(maxiter), n))
    Q = np.empty((kmax + 1, n))
    Q[0] = b / b_norm
    diag, off = np.empty(kmax), np.empty(kmax)
    e1 = np.zeros(kmax)
    e1[0] = b_norm
    U = np.zeros((0, len(lambdas)))
    steps = 0
    previous: np.ndarray | None = None
    for j in range(kmax):
        w = K @ Q[j]
        basis = Q[: j + 1]
        h = basis @ w
        w -= h @ basis
        h2 = basis @ w  # classical Gram-Schmidt twice keeps the basis orthonormal to rounding
        w -= h2 @ basis
        diag[j] = h[j] + h2[j]
        off[j] = float(np.linalg.norm(w))
        steps = j + 1
        breakdown = off[j] <= 8 * np.finfo(np.float64).eps * K_norm
        if breakdown or steps % KRYLOV_CHECK_EVERY == 0 or steps == kmax:
            U = np.empty((steps, len(lambdas)))
            for i, lam in enumerate(lambdas):
                u = _tridiagonal_solve(diag[:steps] + lam, off[: steps - 1].copy(), e1[:steps].copy())
                if u is None:
                    return np.zeros((n, len(lambdas))), np.zeros(len(lambdas), dtype=bool), steps
                U[:, i] = u
            estimate = np.zeros(len(lambdas)) if breakdown else off[j] * np.abs(U[-1])
            target = 0.5 * np.maximum(forward, BACKWARD_ETA * ((K_norm + lambdas) * np.linalg.norm(U, axis=0) + b_norm))
            if np.all(estimate <= target):
                break
            if previous is not None and steps >= KRYLOV_MIN_STEPS and _hopeless(estimate, previous, target, steps, kmax):
                break
            previous = estimate
        Q[j + 1] = w / off[j]
    X = Q[:steps].T @ U
    R = b[:, None] - K @ X - X * lambdas[None, :]
    r = np.linalg.norm(R, axis=0)
    floor = BACKWARD_ETA * ((K_norm + lambdas) * np.linalg.norm(X, axis=0) + b_norm)
    return X, (r <= forward) | (r <= floor), steps


def krylov_budget(n: int) -> int:
    """Default Lanczos budget for an n x n kernel: an iteration costs ~n^2, a tridiagonalisation ~n^3,
    so the budget grows with n (n / 12, at least 32; measured break-even at n = 1600 is ~150)."""
    return max(32, n // 12)


def ridge_solutions(
    K: np.ndarray, B: np.ndarray, lambdas: np.ndarray, krylov_maxiter: int | None = None, overwrite: bool = False
) -> tuple[np.ndarray, dict[str, int]]:
    """(K + lambda I)^-1 B for every lambda, (n, L, k), by the cheapest route that is exact to rounding.

    Shifted Lanczos first (``krylov_maxiter`` iterations at most, None = ``krylov_budget``,
    0 = never), accepted
    per lambda by its residual certificate; lambdas it leaves are solved by Cholesky when
    there are at most ``CHOLESKY_MAX_SHIFTS`` of them, else by the Householder route.
    Returns the solutions and counts of how many (lambda, target) pairs each route solved.
    """
    K = np.asarray(K, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64).reshape(len(K), -1)
    lambdas = check_positive(lambdas, "lambda")
    n, k = B.shape
    if krylov_maxiter is None:
        krylov_maxiter = krylov_budget(n)
    out = np.empty((n, len(lambdas), k))
    todo = np.zeros((len(lambdas), k), dtype=bool)
    counts = {"krylov": 0, "cholesky": 0, "householder": 0, "krylov_iterations": 0}
    for c in range(k):
        if krylov_maxiter > 0:
            X, ok, steps = lanczos_ridge(K, B[:, c], lambdas, krylov_maxiter)
            out[:, :, c] = X
            counts["krylov_iterations"] += steps
        else:
            ok = np.zeros(len(lambdas), dtype=bool)
        todo[:, c] = ~ok
    counts["krylov"] = int((~todo).sum())
    rest = np.flatnonzero(todo.any(axis=1))
    if rest.size == 0:
        return out, counts
    if rest.size <= CHOLESKY_MAX_SHIFTS:
        solved = cholesky_ridge(K, B, lambdas[rest])
        if solved is not None:
            out[:, rest] = np.where(todo[rest][None], solved, out[:, rest])
            counts["cholesky"] = int(todo.sum())
            return out, counts
    solved = householder_ridge(K, B, lambdas[rest], overwrite=overwrite)
    out[:, rest] = np.where(todo[rest][None], solved, out[:, rest])
    counts["householder"] = int(todo.sum())
    return out, counts
