"""Repeated training rows merged into one weighted row: the same kernel least-squares solutions, smaller.

A bootstrap resample of n rows holds only about 63 % distinct ones (1 - 1/e); the rest are
repeats. For a model fitted by squared errors over rows, the c rows that share features x_g
(targets t_i) enter the loss as

    sum_i (f(x_g) - t_i)^2 = (sqrt(c) f(x_g) - sum_i t_i / sqrt(c))^2 + const,

one row whose feature map is scaled by sqrt(c) and whose target is the group sum over sqrt(c).
Every least-squares term of KRLS and of MTL-KRLS (shared and task models alike) transforms
the same way, so their dual problems shrink to the u distinct rows with

    K' = D K_u D,   t' = S t / sqrt(c),   K_eval' = K_eval_u D,   D = diag(sqrt(c)),

where S sums each group's rows. Predictions K_eval' x' equal the full problem's exactly (up
to rounding); every factorisation, Lanczos product and tridiagonal solve then works on u
rows instead of n: (u / n)^3, about a quarter, of the O(n^3) work of a bootstrap fit.
The residual certificate of ``shifted.py`` still bounds the prediction error: K' is the Gram
matrix of the scaled feature maps, and k(x, x) <= 1 still holds at the evaluation points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RowGroups:
    """The distinct rows of a feature matrix and how often each occurs."""

    first: np.ndarray
    """Index of each distinct row's first occurrence, ascending (u,)."""
    group: np.ndarray
    """Group of every row, (n,): 0..u-1 in order of first occurrence."""
    root_counts: np.ndarray
    """sqrt of each group's size, (u,)."""

    @classmethod
    def of(cls, X: np.ndarray) -> RowGroups | None:
        """The groups of identical rows of ``X`` (n, d); None when every row is distinct."""
        X = np.asarray(X, dtype=np.float64)
        if len(X) < 2:
            return None
        _, first, inverse, counts = np.unique(X, axis=0, return_index=True, return_inverse=True, return_counts=True)
        if len(first) == len(X):
            return None
        order = np.argsort(first)  # groups in order of first occurrence
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        return cls(first=first[order], group=rank[inverse.ravel()], root_counts=np.sqrt(counts[order].astype(np.float64)))

    def targets(self, T: np.ndarray) -> np.ndarray:
        """S T / sqrt(c): each group's summed targets over the root of its size, (u, k) for T (n, k)."""
        T = np.asarray(T, dtype=np.float64).reshape(len(self.group), -1)
        sums = np.zeros((len(self.first), T.shape[1]))
        np.add.at(sums, self.group, T)
        return sums / self.root_counts[:, None]

    def weigh(self, K: np.ndarray, K_eval: np.ndarray | None = None) -> None:
        """K <- D K D (distinct training rows, u x u) and K_eval <- K_eval D (m x u), in place."""
        K *= self.root_counts[:, None]
        K *= self.root_counts
        if K_eval is not None:
            K_eval *= self.root_counts
