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
from typing import TYPE_CHECKING, Sequence

import numpy as np
import scipy.linalg

from enginebench.errors import MethodError

if TYPE_CHECKING:  # sklearn is imported where a scaler is made: listing methods imports no sklearn
    from sklearn.preprocessing import StandardScaler

NEGATIVE_EIG_RTOL = 1e-8
"""Eigenvalues below -NEGATIVE_EIG_RTOL * max|s| mean the matrix is not a kernel matrix."""


def power_of_two_scale(y: np.ndarray) -> np.ndarray:
    """Per column, the power of two nearest above its largest |value| (1 for an all-zero or non-finite column)."""
    top = np.max(np.abs(y), axis=0) if len(y) else np.zeros(y.shape[1])
    exponent = np.frexp(np.where(np.isfinite(top) & (top > 0), top, 1.0))[1]
    return np.ldexp(1.0, exponent)


def make_scaler(X: np.ndarray, standardize: bool = True) -> StandardScaler:
    """A scaler fitted on training features: zero mean, unit std (std 0 -> 1), or the identity.

    The mean and std are computed on each column divided by a power of two near its largest
    |value| and multiplied back: exact steps, so features of any scale (1e-200, whose squares
    underflow, or 1e200, whose squares overflow) are standardised to the same numbers as at
    scale 1, and features of ordinary scale to the very numbers ``StandardScaler`` gives (a
    constant column, whose std StandardScaler replaces by 1, is divided by that power of two
    instead, so its rounding residue is as small at every scale).
    With ``standardize=False`` the returned scaler leaves features unchanged, so fitted
    models always carry a scaler and the prediction path is the same either way.
    """
    from sklearn.preprocessing import StandardScaler

    scaler = StandardScaler(with_mean=standardize, with_std=standardize)
    if not standardize:
        return scaler.fit(X)
    X = np.asarray(X, dtype=np.float64)
    p = power_of_two_scale(X) if X.ndim == 2 else np.ones(0)
    scaler.fit(X / p)
    with np.errstate(over="ignore", under="ignore"):  # var_ is informative only: transform reads mean_ and scale_
        scaler.var_ = scaler.var_ * p * p
    scaler.mean_ = scaler.mean_ * p
    scaler.scale_ = scaler.scale_ * p
    return scaler


def standardize_rows(scaler: StandardScaler, blocks: Sequence[np.ndarray], extra: np.ndarray | None = None
                     ) -> np.ndarray:
    """``scaler.transform`` of the row ``blocks`` stacked, with the columns ``extra`` (rows, c) beside them.

    The arithmetic of ``StandardScaler.transform`` ((x - mean_) / scale_, elementwise: the same
    numbers), written once into one array: no stacked copy of the blocks, no ``hstack`` with
    ``extra`` and no copy for the scaler (on a million-row test part those copies cost as
    much as a tenth of a kernel method's prediction). The caller checks finiteness.
    """
    d = int(scaler.n_features_in_)
    n = sum(len(b) for b in blocks)
    width = d - (0 if extra is None else extra.shape[1])
    mean, scale = scaler.mean_, scaler.scale_  # None for an identity scaler (standardize=False)
    out = np.empty((n, d))

    def put(src: np.ndarray, lo: int, hi: int, rows: slice) -> None:
        dst = out[rows, lo:hi]
        if mean is not None:
            np.subtract(src, mean[lo:hi], out=dst)
        else:
            dst[...] = src
        if scale is not None:
            np.divide(dst, scale[lo:hi], out=dst)

    start = 0
    for b in blocks:
        put(b, 0, width, slice(start, start + len(b)))
        start += len(b)
    if extra is not None:
        put(extra, width, d, slice(0, n))
    return out


KERNEL_BLOCK_ROWS = 256
"""Rows of a kernel block in ``gaussian_apply``: 256 x 1,000 training rows is 2 MB, so the
distance, exponential and product passes run in cache instead of memory."""


def sq_norms(A: np.ndarray) -> np.ndarray:
    """Squared Euclidean norm of every row, (len(A),) (as scikit-learn's ``row_norms(squared=True)``)."""
    return np.einsum("ij,ij->i", A, A)


def _sq_distances(A: np.ndarray, a_norms: np.ndarray, B: np.ndarray, b_norms: np.ndarray,
                  out: np.ndarray | None = None) -> np.ndarray:
    """|a|^2 - 2 a.b + |b|^2 clipped at 0, in scikit-learn's order of operations (bit for bit the same)."""
    D = np.matmul(A, B.T, out=out)
    D *= -2.0
    D += a_norms[:, None]
    D += b_norms[None, :]
    return np.maximum(D, 0.0, out=D)


def sq_distances(A: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Squared Euclidean distances |a_i - b_j|^2, shape (len(A), len(B)), clipped at 0.

    ``B=None`` means ``B = A`` (the diagonal is then exactly zero). The arithmetic of
    scikit-learn's ``euclidean_distances(A, B, squared=True)``, without its input checks.
    """
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2:
        raise MethodError(f"features must be a 2-D array (rows x features), got shape {A.shape}")
    if B is None:
        norms = sq_norms(A)
        D = _sq_distances(A, norms, A, norms)
        np.fill_diagonal(D, 0.0)
        return D
    B = np.asarray(B, dtype=np.float64)
    if B.ndim != 2 or B.shape[1] != A.shape[1]:
        raise MethodError(f"features to compare have shape {B.shape}, expected (rows, {A.shape[1]})")
    return _sq_distances(A, sq_norms(A), B, sq_norms(B))


def gaussian(D: np.ndarray, gamma: float, out: np.ndarray | None = None) -> np.ndarray:
    """Gaussian kernel exp(-gamma * D) from squared distances D: K(x, x') = exp(-gamma |x - x'|^2)."""
    out = np.multiply(D, -float(gamma), out=out)
    return np.exp(out, out=out)


def gaussian_apply(X: np.ndarray, X_train: np.ndarray, gamma: float, coef: np.ndarray,
                   block_rows: int = KERNEL_BLOCK_ROWS) -> np.ndarray:
    """K(X, X_train) @ coef, (len(X), k), without the whole kernel matrix: blocks of ``block_rows`` rows.

    Each block's distances, kernel and product are formed in one cache-sized buffer with the
    arithmetic of ``gaussian(sq_distances(X, X_train), gamma) @ coef`` (the same numbers:
    the product of a row does not depend on the block it is in).
    """
    X = np.asarray(X, dtype=np.float64)
    X_train = np.asarray(X_train, dtype=np.float64)
    coef = np.asarray(coef, dtype=np.float64)
    flat = coef.reshape(len(X_train), -1)
    out = np.empty((len(X), flat.shape[1]))
    train_norms, norms = sq_norms(X_train), sq_norms(X)
    buf = np.empty((min(block_rows, len(X)), len(X_train)))
    for start in range(0, len(X), block_rows):
        stop = min(start + block_rows, len(X))
        K = _sq_distances(X[start:stop], norms[start:stop], X_train, train_norms, out=buf[: stop - start])
        np.multiply(K, -float(gamma), out=K)  # ``gaussian`` in place, inlined (profiles count it once)
        np.matmul(np.exp(K, out=K), flat, out=out[start:stop])
    return out.reshape((len(X), *coef.shape[1:]))


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
