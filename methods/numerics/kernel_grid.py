"""Gaussian kernel ridge predictions for a (gamma, lambda) grid on one feature set, in chunks of rows.

NFIR's model selection predicts every (gamma, lambda) of a lag set on a resample. The
straightforward route (kept in ``benchmarks/nfir_selection.py`` as the reference) computes one
eigendecomposition of the training kernel per gamma and the evaluation distances once per gamma
and chunk. Here the training distances and, when the evaluation rows fit one chunk, the
evaluation distances are computed once per feature set, and each gamma's lambdas are solved by
``ridge_solutions`` (``shifted.py``): a certified shifted Lanczos basis where it converges,
else one Householder tridiagonalisation (a third of an eigendecomposition) whose every lambda is
an O(n) tridiagonal solve. Both routes are exact to rounding, as the eigendecomposition is.
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from enginebench.methods.numerics.kernels import gaussian, sq_distances
from enginebench.methods.numerics.shifted import ridge_solutions


def kernel_ridge_grid(
    Xs: np.ndarray, yc: np.ndarray, Xe: np.ndarray, gammas: np.ndarray, lambdas: np.ndarray, chunk: int,
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Per distinct gamma (first appearance first): its grid indices and predictions (len(idx), len(Xe), k).

    ``Xs`` (n, d) training features, ``yc`` (n, k) targets as the solver sees them (centred and
    scaled by the caller, who maps predictions back), ``Xe`` (m, d) evaluation features, ``gammas``
    and ``lambdas`` one entry per grid point. Evaluation kernels are formed ``chunk`` rows at a
    time when ``m > chunk``, so a long evaluation set never forms a huge kernel.
    """
    gammas = np.asarray(gammas, dtype=np.float64)
    lambdas = np.asarray(lambdas, dtype=np.float64)
    yc = np.asarray(yc, dtype=np.float64).reshape(len(Xs), -1)
    n, k = yc.shape
    m = len(Xe)
    D_train = sq_distances(Xs)
    K = np.empty_like(D_train)
    D_eval = sq_distances(Xe, Xs) if 0 < m <= chunk else None  # one chunk: shared by every gamma
    K_eval = None if D_eval is None else np.empty_like(D_eval)
    for gamma in dict.fromkeys(gammas.tolist()):
        idx = np.flatnonzero(gammas == gamma)
        # the solver may factorise K in place: it is re-formed from D_train for the next gamma
        alpha, _ = ridge_solutions(gaussian(D_train, gamma, out=K), yc, lambdas[idx], overwrite=True)
        alpha = alpha.reshape(n, len(idx) * k)
        pred = np.empty((len(idx), m, k))
        for a in range(0, m, chunk):
            if D_eval is not None:
                Ke = gaussian(D_eval, gamma, out=K_eval)
            else:
                Ke = gaussian(sq_distances(Xe[a:a + chunk], Xs), gamma)
            pred[:, a:a + chunk] = np.moveaxis((Ke @ alpha).reshape(len(Ke), len(idx), k), 1, 0)
        yield idx, pred
