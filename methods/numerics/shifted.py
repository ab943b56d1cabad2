"""Shifted kernel systems for a whole regularisation grid, without an eigendecomposition.

Model selection needs, per gamma, sums of solutions of shifted systems

    X_j = sum_r w_jr (K + mu_jr I)^-1 B        (one j per grid point)

and usually only the predictions K_eval X_j, not the eigenvectors of K. KRLS is the case
of one term (mu = lambda, w = 1); the shared model of MTL-KRLS is a two-term sum (its
spectral filter has two real poles, see ``methods/mtl_krls.py``). Three routes are exact
to rounding and cheaper than an eigendecomposition (eigh costs ~17 Cholesky
factorisations; measured 0.92 s at n = 1600 on one core):

* Shifted Lanczos with full reorthogonalisation: one Krylov basis started at b serves
  every shift (Krylov spaces are shift invariant), and one eigendecomposition of the small
  Lanczos matrix T_k gives every shift's coefficients at once. For a Gaussian kernel it
  converges in a few dozen matrix-vector products when gamma is small (numerically low
  rank) or large (K close to I). Its solutions are accepted only with an a-posteriori
  certificate on the true residual r = b - (K + mu I) x, whose norm for every shift comes
  from one thin QR of the products K q_j the iteration already made: for a kernel with k(x, x) <= 1 the prediction error at any
  point is at most |r| / sqrt(mu) (Cauchy-Schwarz in the RKHS metric (K + mu I)^-1), and
  that bound must be below ``rtol`` times the RMS of b; or the residual must be as small
  as a backward-stable direct solve leaves it (normwise backward error below
  ``BACKWARD_ETA``), the floor that Cholesky or eigh share. A grid point is accepted when
  every one of its shifts is, so its prediction error is at most rtol RMS(b) sum_r |w_jr|.
* Cholesky, one factorisation per shift, when only a few shifts remain.
* Householder tridiagonalisation K = H T H^T (LAPACK dsytrd, ~0.3 s at n = 1600) turns
  every shifted system into an O(n) positive definite tridiagonal solve (LAPACK dptsv);
  H is applied once, to the combined solutions or to K_eval, whichever is smaller.
  With more than 4 n distinct shifts (MTL-KRLS on a bootstrap's ~630 distinct rows: ~2,600
  per gamma), T = V diag(s) V^T once (dstevd) instead: each grid point is then a filter
  sum_r w_jr / (s + mu_jr).
  Backward stable like eigh, no tolerance involved.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from enginebench.errors import MethodError
from enginebench.methods.numerics.kernels import check_positive

BACKWARD_ETA = 4 * np.finfo(np.float64).eps
"""Normwise backward error |r| / (|K + mu I| |x| + |b|) accepted from the Krylov solver."""
KRYLOV_RTOL = 1e-10
"""Bound on the Krylov solution's prediction error, relative to the RMS of the right-hand side."""
KRYLOV_CHECK_EVERY = 8
"""Lanczos iterations between two convergence checks (each check is one small eigendecomposition)."""
KRYLOV_SLACK = 2.0
"""Lanczos stops early when its extrapolated iteration count exceeds this many budgets."""
KRYLOV_MIN_STEPS = 32
"""No early stop before this many Lanczos iterations (the first rates are too pessimistic)."""
CHOLESKY_MAX_SHIFTS = 5
"""Up to this many shifts are solved by one Cholesky factorisation each (dsytrd costs ~5.5)."""
SPECTRAL_SHIFTS_PER_ROW = 4.0
"""The Householder route diagonalises T when it has more distinct shifts than this many per kernel row
(measured break-even on one core: 2 n shifts at n = 632 and 1000, 3 n at n = 1600)."""


def krylov_budget(n: int, transformed_columns: int = 0) -> int:
    """Default Lanczos budget for an n x n kernel: about what the direct route costs.

    An iteration costs ~n^2 (a matrix-vector product, memory bound), a tridiagonalisation
    ~n^3: n / 12 iterations (measured break-even at n = 1600 is ~150). The direct route
    then applies H to ``transformed_columns`` columns (2 n^2 each, blocked BLAS3, several
    times faster per flop than a matrix-vector product) and forms the predictions: one more
    iteration per 8 such columns. At least 32.
    """
    return max(32, n // 12 + transformed_columns // 8)


# -- Householder ----------------------------------------------------------------------------

def _tridiagonal_solve(d: np.ndarray, e: np.ndarray, B: np.ndarray) -> np.ndarray | None:
    """Solve the SPD tridiagonal system (diag d, off-diagonal e) for B; None if not positive definite."""
    if len(d) == 1:
        return B / d[0] if d[0] > 0 else None
    _, _, X, info = scipy.linalg.lapack.dptsv(d, e, B)
    return X if info == 0 else None


class _Householder:
    """K = H T H^T by dsytrd, with the shifted tridiagonal solves and the applications of H."""

    def __init__(self, K: np.ndarray, overwrite: bool) -> None:
        lapack = scipy.linalg.lapack
        n = len(K)
        self.n = n
        self._spectrum: tuple[np.ndarray, np.ndarray] | None = None
        if n == 1:
            self.d, self.e = np.array([K[0, 0]], dtype=float), np.zeros(0)
            return
        lwork = int(lapack.dsytrd_lwork(n, lower=1)[0])
        # K is symmetric: its transpose is the Fortran-ordered view LAPACK can overwrite in place
        A, self.d, self.e, self.tau, info = lapack.dsytrd(K.T if overwrite else K, lower=1, lwork=max(lwork, 1),
                                                          overwrite_a=overwrite)
        if info != 0:
            raise MethodError(f"tridiagonal reduction of the kernel matrix failed (LAPACK info {info})")
        self.reflectors = A[1:, :-1]

    def _apply(self, side: str, trans: str, C: np.ndarray) -> np.ndarray:
        """H^T C, H C (side 'L') or C H (side 'R'); H = diag(1, reflectors) leaves the first row/column."""
        C = np.array(C, dtype=np.float64, order="F")
        if self.n == 1 or C.size == 0:
            return C
        if side == "L":
            C[1:], _, info = scipy.linalg.lapack.dormqr("L", trans, self.reflectors, self.tau, C[1:],
                                                        max(1, 64 * C.shape[1]))
        else:
            C[:, 1:], _, info = scipy.linalg.lapack.dormqr("R", trans, self.reflectors, self.tau, C[:, 1:],
                                                           max(1, 64 * C.shape[0]))
        return C

    def spectrum(self) -> tuple[np.ndarray, np.ndarray]:
        """T = V diag(s) V^T with s clipped at 0 (as ``Spectral`` clips K's), computed once."""
        if self._spectrum is None:
            s, V = _tridiagonal_eigh(self.d, self.e)
            self._spectrum = (np.maximum(s, 0.0), V)
        return self._spectrum

    def solve(self, Z: np.ndarray, mu: float) -> np.ndarray:
        """(T + mu I)^-1 Z; with T's clipped spectrum when rounding made K indefinite beyond mu,
        so the tridiagonal system is not positive definite."""
        X = _tridiagonal_solve(self.d + mu, self.e, Z)
        if X is None:
            s, V = self.spectrum()
            X = V @ ((V.T @ Z) / (s[:, None] + mu))
        return X

    def combinations(self, B: np.ndarray, shifts: np.ndarray, weights: np.ndarray,
                     K_eval: np.ndarray | None) -> np.ndarray:
        """sum_r w_jr (K + mu_jr I)^-1 B, or K_eval times it: (n or m, J, k).

        With H^T B = Z, each solution is H sum_r w_jr (T + mu_jr I)^-1 Z. Up to
        ``SPECTRAL_SHIFTS_PER_ROW`` n distinct shifts: one O(n) tridiagonal solve each. Beyond,
        T's eigendecomposition V diag(s) V^T (O(n^2) to O(n^3), once) turns every grid point into
        a filter, H V [V^T Z * sum_r w_jr / (s + mu_jr)], cheaper than thousands of solves
        (MTL-KRLS has ~2,600 shifts per gamma).
        """
        n, k = B.shape
        J = len(shifts)
        Z = self._apply("L", "T", B)
        left = None if K_eval is None or len(K_eval) >= J * k else self._apply("R", "N", K_eval)  # smaller side
        if len(np.unique(shifts)) > SPECTRAL_SHIFTS_PER_ROW * n:
            s, V = self.spectrum()
            W = _filtered(V.T @ Z, s, shifts, weights)  # in T's eigenbasis
            if left is not None:
                return ((left @ V) @ W).reshape(-1, J, k)
            W = V @ W
        else:
            W = self._summed_solves(Z, shifts, weights)
            if left is not None:
                return (left @ W).reshape(-1, J, k)
        X = self._apply("L", "N", W)
        return X.reshape(n, J, k) if K_eval is None else (K_eval @ X).reshape(-1, J, k)

    def _summed_solves(self, Z: np.ndarray, shifts: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """sum_r w_jr (T + mu_jr I)^-1 Z by one tridiagonal solve per distinct shift: (n, J k)."""
        n, k = Z.shape
        uniq, inv = np.unique(shifts, return_inverse=True)
        inv = inv.reshape(shifts.shape)
        # shift-major (S, n, k) and (J, n, k): contiguous copies and row gathers; for k = 1 the
        # (n, J) view below is Fortran-ordered and BLAS takes it as is
        Y = np.stack([self.solve(Z, float(mu)) for mu in uniq])
        W = Y[inv[:, 0]] * weights[:, 0, None, None]
        for r in range(1, shifts.shape[1]):
            W += Y[inv[:, r]] * weights[:, r, None, None]
        return W.transpose(1, 0, 2).reshape(n, len(shifts) * k)


def _filtered(Zt: np.ndarray, s: np.ndarray, shifts: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Zt (n, k) times sum_r w_jr / (s + mu_jr) for every grid point j: (n, J k), built in place."""
    n, k = Zt.shape
    filt = s[:, None] + shifts[:, 0]
    np.divide(weights[:, 0], filt, out=filt)
    term = np.empty_like(filt)
    for r in range(1, shifts.shape[1]):
        np.add(s[:, None], shifts[:, r], out=term)
        filt += np.divide(weights[:, r], term, out=term)
    if k == 1:
        filt *= Zt
        return filt
    return (filt[:, :, None] * Zt[:, None, :]).reshape(n, -1)


def _tridiagonal_eigh(d: np.ndarray, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and eigenvectors of a symmetric tridiagonal matrix: LAPACK dstevd (divide and
    conquer, the fastest with vectors) where scipy wraps it, else scipy's default driver."""
    if len(d) == 1:
        return d.copy(), np.ones((1, 1))
    stevd = getattr(scipy.linalg.lapack, "dstevd", None)
    if stevd is not None:
        s, V, info = stevd(d, e)
        if info == 0:
            return s, V
    return scipy.linalg.eigh_tridiagonal(d, e, check_finite=False)


def householder_ridge(K: np.ndarray, B: np.ndarray, lambdas: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Exact (K + lambda I)^-1 B for every lambda by one Householder tridiagonalisation: (n, L, k)."""
    K = np.asarray(K, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64).reshape(len(K), -1)
    lambdas = check_positive(lambdas, "lambda")
    return _Householder(K, overwrite).combinations(B, lambdas[:, None], np.ones((len(lambdas), 1)), None)


# -- Cholesky -------------------------------------------------------------------------------

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


# -- Lanczos --------------------------------------------------------------------------------

def _hopeless(estimate: np.ndarray, previous: np.ndarray, target: np.ndarray, steps: int, kmax: int) -> bool:
    """True when the residual estimates, extrapolated at their rate since the last check, need
    more than ``KRYLOV_SLACK`` iteration budgets: stop early and hand those shifts to a direct solver.

    Lanczos convergence speeds up as Ritz values settle, so the extrapolation is pessimistic;
    the slack keeps slowly starting but converging cases.
    """
    open_ = (estimate > target) & (previous > 0)
    if not open_.any():
        return False
    rate = np.clip(estimate[open_] / previous[open_], 1e-300, 1 - 1e-3)
    needed = KRYLOV_CHECK_EVERY * np.log(target[open_] / estimate[open_]) / np.log(rate)
    return bool(steps + needed.max() > KRYLOV_SLACK * kmax)


def _krylov_coefficients(diag: np.ndarray, off: np.ndarray, b_norm: float, shifts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u(mu) = (T_k + mu I)^-1 e_1 |b| for every shift as W @ F, W (k, k) orthogonal and F (k, S),
    from one eigendecomposition of T_k (its eigenvalues clipped at 0: the true-residual
    certificate judges the result). |u(mu)| = |F[:, i]| and e_k^T u = W[-1] @ F need no k x S product."""
    if len(diag) == 1:
        tau, W = diag.copy(), np.ones((1, 1))
    else:
        tau, W = scipy.linalg.eigh_tridiagonal(diag, off, check_finite=False)
    return W, (W[0] * b_norm)[:, None] / (np.maximum(tau, 0.0)[:, None] + shifts[None, :])


def _lanczos(
    K: np.ndarray, b: np.ndarray, shifts: np.ndarray, maxiter: int, rtol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Shifted Lanczos for (K + mu I) x = b, every mu from one basis: x(mu) = basis.T @ U[:, i].

    Returns the basis (k, n), the coefficients U (k, S), a mask of the shifts whose true
    residual passed the certificate and the number of iterations k. The iteration stops
    when the Lanczos residual estimates beta_k |e_k^T u(mu)| of every shift are below their
    targets, on breakdown (an invariant subspace: exact), when the remaining ones look
    hopeless, or after ``maxiter`` iterations.
    """
    n, S = len(b), len(shifts)
    b_norm = float(np.linalg.norm(b))
    if b_norm == 0.0:
        return np.zeros((0, n)), np.zeros((0, S)), np.ones(S, dtype=bool), 0
    K_norm = float(np.abs(K).sum(axis=1).max())  # |K|_inf >= |K|_2 for symmetric K
    forward = rtol * np.sqrt(shifts) * b_norm / np.sqrt(n)  # |r| / sqrt(mu) <= rtol * RMS(b)
    kmax = max(1, min(int(maxiter), n))
    Q = np.empty((kmax + 1, n))
    KQ = np.empty((kmax, n))  # K q_j, kept for the residual certificate
    Q[0] = b / b_norm
    diag, off = np.empty(kmax), np.empty(kmax)
    steps = 0
    previous: np.ndarray | None = None
    for j in range(kmax):
        w = K @ Q[j]
        KQ[j] = w
        basis = Q[: j + 1]
        h = basis @ w
        w = w - h @ basis
        h2 = basis @ w  # classical Gram-Schmidt twice keeps the basis orthonormal to rounding
        w -= h2 @ basis
        diag[j] = h[j] + h2[j]
        off[j] = float(np.linalg.norm(w))
        steps = j + 1
        breakdown = off[j] <= 8 * np.finfo(np.float64).eps * K_norm
        if breakdown or steps % KRYLOV_CHECK_EVERY == 0 or steps == kmax:
            W, F = _krylov_coefficients(diag[:steps], off[: steps - 1], b_norm, shifts)
            estimate = np.zeros(S) if breakdown else off[j] * np.abs(W[-1] @ F)
            target = 0.5 * np.maximum(forward, BACKWARD_ETA * ((K_norm + shifts) * np.linalg.norm(F, axis=0) + b_norm))
            if np.all(estimate <= target):
                break
            if previous is not None and steps >= KRYLOV_MIN_STEPS and _hopeless(estimate, previous, target, steps, kmax):
                break
            previous = estimate
        Q[j + 1] = w / off[j]
    basis, KQ = Q[:steps], KQ[:steps]
    U = W @ F
    # True residuals r(mu) = b - K x - mu x = M c(mu) with M = [b, K basis^T, basis^T] and
    # c(mu) = [1, -u, -mu u]: one thin QR of M (n x (2k + 1)) gives |r(mu)| = |R c(mu)| for every
    # shift at O(k^2) each, with the rounding of a backward-stable QR (eps |M| |c|, the floor's scale)
    # instead of forming n x S residuals.
    R = np.linalg.qr(np.column_stack([b, KQ.T, basis.T]), mode="r")
    coeffs = np.vstack([np.ones((1, S)), -U, -U * shifts[None, :]])
    r = np.linalg.norm(R @ coeffs, axis=0)
    floor = BACKWARD_ETA * ((K_norm + shifts) * np.linalg.norm(U, axis=0) + b_norm)  # |x| = |u|: orthonormal basis
    ok = (r <= forward) | (r <= floor)
    return basis, U, ok, steps


def lanczos_ridge(
    K: np.ndarray, b: np.ndarray, lambdas: np.ndarray, maxiter: int, rtol: float = KRYLOV_RTOL
) -> tuple[np.ndarray, np.ndarray, int]:
    """Shifted Lanczos for (K + lambda I) x = b: solutions (n, L), certified mask (L,), iterations."""
    lambdas = np.asarray(lambdas, dtype=np.float64)
    basis, U, ok, steps = _lanczos(np.asarray(K, dtype=np.float64), np.asarray(b, dtype=np.float64), lambdas, maxiter, rtol)
    return basis.T @ U, ok, steps


# -- the cheapest route per grid point ------------------------------------------------------

def shifted_solutions(
    K: np.ndarray,
    B: np.ndarray,
    shifts: np.ndarray,
    weights: np.ndarray | None = None,
    K_eval: np.ndarray | None = None,
    krylov_maxiter: int | None = None,
    overwrite: bool = False,
    out: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, int]]:
    """sum_r weights[j, r] (K + shifts[j, r] I)^-1 B for every grid point j, by the cheapest exact route.

    ``shifts`` and ``weights`` are (J, R) (R terms per grid point; 1-D means R = 1 and
    weights 1). Returns the solutions (n, J, k), or with ``K_eval`` (m x n) the predictions
    K_eval @ solutions (m, J, k), formed without the n x J solutions where that is cheaper.
    Shifted Lanczos first (``krylov_maxiter`` iterations at most, None = ``krylov_budget``
    for the columns the direct route would transform, 0 = never), accepted per grid point by its residual certificate; the points it leaves
    are solved by Cholesky when they have at most ``CHOLESKY_MAX_SHIFTS`` distinct shifts,
    else by the Householder route. Also returns how many (grid point, column) pairs each
    route solved and the Lanczos iterations. ``out``: a (rows, J, k) array (a view into a larger one,
    say) the results are written into and returned as; None allocates one.
    """
    K = np.asarray(K, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64).reshape(len(K), -1)
    shifts = np.asarray(shifts, dtype=np.float64)
    shifts = shifts[:, None] if shifts.ndim == 1 else shifts
    weights = np.ones_like(shifts) if weights is None else np.asarray(weights, dtype=np.float64).reshape(shifts.shape)
    check_positive(shifts.ravel(), "lambda")
    if not np.isfinite(weights).all():
        raise MethodError("shifted solutions: the weights contain nan/inf")
    n, k = B.shape
    J = len(shifts)
    if krylov_maxiter is None:
        krylov_maxiter = krylov_budget(n, J * k if K_eval is None else min(len(K_eval), J * k))
    uniq, inv = np.unique(shifts, return_inverse=True)
    inv = inv.reshape(shifts.shape)
    rows = n if K_eval is None else len(K_eval)
    if out is None:
        out = np.empty((rows, J, k))
    elif out.shape != (rows, J, k):
        raise ValueError(f"shifted solutions: out has shape {out.shape}, expected {(rows, J, k)}")
    todo = np.ones((J, k), dtype=bool)
    counts = {"krylov": 0, "cholesky": 0, "householder": 0, "krylov_iterations": 0}
    if krylov_maxiter > 0:
        for c in range(k):
            basis, U, ok, steps = _lanczos(K, B[:, c], uniq, krylov_maxiter, KRYLOV_RTOL)
            counts["krylov_iterations"] += steps
            good = ok[inv].all(axis=1)
            if not good.any():
                continue
            C = np.einsum("sjr,jr->sj", U[:, inv[good]], weights[good])
            left = basis.T if K_eval is None else K_eval @ basis.T
            if good.all():  # a slice, not a masked scatter
                out[:, :, c] = left @ C
            else:
                out[:, good, c] = left @ C
            todo[good, c] = False
    counts["krylov"] = int((~todo).sum())
    rest = np.flatnonzero(todo.any(axis=1))
    if rest.size == 0:
        return out, counts
    solved = None
    rest_shifts = np.unique(shifts[rest])
    if rest_shifts.size <= CHOLESKY_MAX_SHIFTS:
        X = cholesky_ridge(K, B, rest_shifts)
        if X is not None:
            pos = np.searchsorted(rest_shifts, shifts[rest])
            solved = np.einsum("nprk,pr->npk", X[:, pos], weights[rest])
            if K_eval is not None:
                solved = (K_eval @ solved.reshape(n, -1)).reshape(rows, len(rest), k)
            counts["cholesky"] = int(todo.sum())
    if solved is None:
        solved = _Householder(K, overwrite).combinations(B, shifts[rest], weights[rest], K_eval)
        counts["householder"] = int(todo.sum())
    if todo[rest].all():  # every column of these points was left (always so for one target)
        out[:, rest] = solved
    else:
        out[:, rest] = np.where(todo[rest][None], solved, out[:, rest])
    return out, counts


def ridge_solutions(
    K: np.ndarray, B: np.ndarray, lambdas: np.ndarray, krylov_maxiter: int | None = None, overwrite: bool = False,
    K_eval: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, int]]:
    """(K + lambda I)^-1 B for every lambda, (n, L, k) (or K_eval times it), see ``shifted_solutions``."""
    return shifted_solutions(K, B, check_positive(lambdas, "lambda"), K_eval=K_eval, krylov_maxiter=krylov_maxiter,
                             overwrite=overwrite)
