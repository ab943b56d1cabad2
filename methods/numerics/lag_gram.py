"""Least squares for many lag orders at once: one Gram matrix of the longest lags, every order read from it.

An ARX grid fits the same training trajectories at many (na, nb, nk): each is a least-squares
problem whose columns are a subset of the columns of the grid's longest lags (output lags
1..Py, input lags 0..Pu-1 of every input, a constant). Forming each point's regression matrix
and factorising it (LAPACK gelsd, an SVD) costs O(rows x columns^2) per point; at campaign size
(170,000 rows, 641 columns) that is seconds a point and gigabytes of copies.

Here the data are read once per target into the Gram matrix ``G = Z^T Z`` of the longest
lags (Z = [lag columns | y], built one segment at a time from zero-copy lag views, so memory
is bounded by one segment). Every grid point's normal matrix is then a principal submatrix of
G plus the outer products of its few extra rows (the rows between its own first lag and the
grid's longest one, where its lags already lie inside the segment: each point keeps exactly its
own rows). It is solved by a Cholesky factor of the equilibrated normal matrix and one step of
iterative refinement on the true residual (the corrected semi-normal equations, forward-stable
like QR when the columns are not too close to dependent). Where the estimated condition number
of the equilibrated regression matrix exceeds :data:`MAX_CONDITION`, or the Cholesky factor does
not exist (dependent columns), the point is handed back to the caller's SVD solver: accuracy is
never traded for speed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import scipy.linalg
from numpy.lib.stride_tricks import sliding_window_view

MAX_CONDITION = 1e6
"""Largest condition number (2-norm estimate, equilibrated columns) solved by the semi-normal
equations; above it the point goes to the SVD solver (normal equations square it)."""


@dataclass(frozen=True)
class Orders:
    """One grid point's lags: output lags 1..na, input lags nk..nk+nb-1 of every input."""

    na: int
    nb: int
    nk: int

    @property
    def first_row(self) -> int:
        return max(self.na, self.nk + self.nb - 1)


def lag_columns(Y: np.ndarray, U: np.ndarray, rows: np.ndarray, o: Orders) -> np.ndarray:
    """[y(t-1..t-na), u_j(t-nk..t-nk-nb+1) per input, 1] at rows ``rows`` of one segment (``Y`` one target)."""
    t = rows[:, None]
    cols = [Y[t - np.arange(1, o.na + 1)[None, :]]]
    for j in range(U.shape[1]):
        cols.append(U[t - (o.nk + np.arange(o.nb))[None, :], j])
    cols.append(np.ones((len(rows), 1)))
    return np.hstack(cols)


class LagGram:
    """The Gram matrices of the longest lags of ``points`` over the segments (U_s, Y_s), every target at once.

    Z_u = [u_j lags 0..Pu-1 per input | 1] is shared by every target's problem: its Gram block
    is formed once. Each target k adds Z_k = [its y lags 1..Py | y_k]: the blocks Z_k^T Z_u and
    Z_k^T Z_k. A target's numbers never depend on the other targets (the same products, in the
    same order, as a fit of that target alone), so a joint fit equals the per-target fits exactly.
    """

    def __init__(self, segments: Sequence[tuple[np.ndarray, np.ndarray]], points: Sequence[Orders]) -> None:
        self.segments = [(np.asarray(U, dtype=np.float64), np.asarray(Y, dtype=np.float64).reshape(len(U), -1))
                         for U, Y in segments]
        self.m = self.segments[0][0].shape[1] if self.segments else 0
        self.k = self.segments[0][1].shape[1] if self.segments else 0
        self.Py = max(o.na for o in points)
        self.Pu = max(o.nk + o.nb for o in points)
        self.L = max(o.first_row for o in points)
        self.const = self.m * self.Pu
        nu, ny = self.const + 1, self.Py + 1
        self.G_u = np.zeros((nu, nu))
        self.G_yu = np.zeros((self.k, ny, nu))
        self.G_y = np.zeros((self.k, ny, ny))
        for U, Y in self.segments:
            if len(Y) <= self.L:
                continue
            Zu = self._inputs(U, self.L, len(Y))
            self.G_u += Zu.T @ Zu
            for t in range(self.k):
                Zy = self._outputs(np.ascontiguousarray(Y[:, t]), self.L, len(Y))
                self.G_yu[t] += Zy.T @ Zu
                self.G_y[t] += Zy.T @ Zy

    def _inputs(self, U: np.ndarray, start: int, stop: int) -> np.ndarray:
        """[u_j lags 0..Pu-1 per input, 1] at rows start..stop-1 (lags before the first row hold 0)."""
        Up = _padded(U, start - self.Pu + 1, stop)
        cols = [sliding_window_view(Up[:, j], self.Pu)[:, ::-1] for j in range(self.m)]
        cols.append(np.ones((stop - start, 1)))
        return np.hstack(cols)

    def _outputs(self, y: np.ndarray, start: int, stop: int) -> np.ndarray:
        """[y lags 1..Py, y] at rows start..stop-1 (lags before the first row hold 0)."""
        lags = sliding_window_view(_padded(y, start - self.Py, stop - 1), self.Py)[:, ::-1]
        return np.hstack([lags, y[start:stop, None]])

    def _columns(self, o: Orders) -> tuple[np.ndarray, np.ndarray]:
        """The point's output-lag columns (of Z_k) and input columns with the constant (of Z_u)."""
        u = [j * self.Pu + i for j in range(self.m) for i in range(o.nk, o.nk + o.nb)]
        return np.arange(o.na), np.asarray(u + [self.const], dtype=np.int64)

    def rows(self, o: Orders) -> int:
        return sum(max(0, len(Y) - o.first_row) for _, Y in self.segments)

    def solve(self, o: Orders, target: int = 0) -> np.ndarray | None:
        """The least-squares coefficients of ``o`` for ``target`` on its own rows (order of :func:`lag_columns`),
        or None when the SVD solver must take it (dependent columns, or a condition number above
        :data:`MAX_CONDITION`)."""
        iy, iu = self._columns(o)
        ycol = self.Py
        Gy, Gyu = self.G_y[target], self.G_yu[target]
        A = np.block([[Gy[np.ix_(iy, iy)], Gyu[np.ix_(iy, iu)]], [Gyu[np.ix_(iy, iu)].T, self.G_u[np.ix_(iu, iu)]]])
        b = np.r_[Gy[iy, ycol], Gyu[ycol, iu]]
        used = [(U, np.ascontiguousarray(Y[:, target])) for U, Y in self.segments if len(Y) > o.first_row]
        for U, y in used:
            stop = min(self.L, len(y))  # rows between this point's first lag and the grid's longest
            if stop > o.first_row:
                Zy, Zu = self._outputs(y, o.first_row, stop), self._inputs(U, o.first_row, stop)
                E = np.hstack([Zy[:, iy], Zu[:, iu]])
                A += E.T @ E
                b += E.T @ Zy[:, ycol]
        d = np.sqrt(np.diag(A))
        if not np.all(d > 0):
            return None
        try:
            R = scipy.linalg.cholesky(A / np.outer(d, d), lower=False, check_finite=False)
        except np.linalg.LinAlgError:
            return None
        rcond, info = scipy.linalg.lapack.dtrcon(R, norm="1", uplo="U", diag="N")
        if info != 0 or rcond <= 0 or 1.0 / rcond > MAX_CONDITION:
            return None
        theta = scipy.linalg.cho_solve((R, False), b / d, check_finite=False) / d
        # one step of refinement on the true residual: r = y - Phi theta, theta += (Phi^T Phi)^-1 Phi^T r
        g = np.zeros(len(b))
        for U, y in used:
            g += _correlate(y, U, y - _apply(y, U, o, theta), o)
        return theta + scipy.linalg.cho_solve((R, False), g / d, check_finite=False) / d


def _padded(a: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Rows lo..hi-1 of ``a``, rows before 0 as zeros (only the rows a lag window reads are copied)."""
    if lo >= 0:
        return a[lo:hi]
    return np.concatenate([np.zeros((-lo, *a.shape[1:])), a[:hi]])


def _apply(y: np.ndarray, U: np.ndarray, o: Orders, theta: np.ndarray) -> np.ndarray:
    """Phi theta at every row of a segment (rows before ``o.first_row`` are not used), by convolutions."""
    n, m = len(y), U.shape[1]
    out = np.full(n, theta[-1])
    if o.na:
        out += np.convolve(y, np.r_[0.0, theta[:o.na]])[:n]
    for j in range(m):
        b = theta[o.na + j * o.nb:o.na + (j + 1) * o.nb]
        out += np.convolve(U[:, j], np.r_[np.zeros(o.nk), b])[:n]
    return out


def _correlate(y: np.ndarray, U: np.ndarray, r: np.ndarray, o: Orders) -> np.ndarray:
    """Phi^T r over the segment's rows t >= o.first_row, each column a dot product of shifted views."""
    f, n = o.first_row, len(y)
    rr = r[f:]
    g = [y[f - i:n - i] @ rr for i in range(1, o.na + 1)]
    for j in range(U.shape[1]):
        g += [U[f - o.nk - l:n - o.nk - l, j] @ rr for l in range(o.nb)]
    g.append(rr.sum())
    return np.asarray(g)
