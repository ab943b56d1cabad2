"""Least squares for many lag orders at once: one Gram matrix of the longest lags, every order read from it.

An ARX grid fits the same training trajectories at many (na, nb, nk): each is a least-squares
problem whose columns are a subset of the columns of the grid's longest lags (output lags
1..Py, input lags 0..Pu-1 of every input, a constant). Forming each point's regression matrix
and factorising it (LAPACK gelsd, an SVD) costs O(rows x columns^2) per point; at campaign size
(170,000 rows, 641 columns) that is seconds a point and gigabytes of copies.

Here the data are read once per target into the Gram matrix ``G = Z^T Z`` of the longest
lags (Z = [lag columns | y]), formed from the signals' lagged products (:func:`lagged_products`:
one dot product per lag difference plus the few rows at the ends) instead of the lag columns:
O(rows x lags) per pair of signals, not O(rows x lags^2), and no lag matrix in memory. Every grid point's normal matrix is then a principal submatrix of
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
        ylag = np.r_[1:ny, 0]  # Z_k's columns: y lags 1..Py, then y itself (lag 0)
        for U, Y in self.segments:
            if len(Y) <= self.L:
                continue
            start, stop, Pu = self.L, len(Y), self.Pu
            # Gram blocks from lagged products of the signals (lagged_products), never the lag columns themselves
            us = [np.ascontiguousarray(U[:, j]) for j in range(self.m)]
            for j in range(self.m):
                for l in range(j, self.m):
                    block = lagged_products(us[j], us[l], Pu, Pu, start, stop)
                    self.G_u[j * Pu:(j + 1) * Pu, l * Pu:(l + 1) * Pu] += block
                    if l != j:
                        self.G_u[l * Pu:(l + 1) * Pu, j * Pu:(j + 1) * Pu] += block.T
                sums = lagged_sums(us[j], Pu, start, stop)
                self.G_u[j * Pu:(j + 1) * Pu, self.const] += sums
                self.G_u[self.const, j * Pu:(j + 1) * Pu] += sums
            self.G_u[self.const, self.const] += stop - start
            for t in range(self.k):
                y = np.ascontiguousarray(Y[:, t])
                for j in range(self.m):
                    self.G_yu[t][:, j * Pu:(j + 1) * Pu] += lagged_products(y, us[j], ny, Pu, start, stop)[ylag]
                self.G_yu[t][:, self.const] += lagged_sums(y, ny, start, stop)[ylag]
                self.G_y[t] += lagged_products(y, y, ny, ny, start, stop)[np.ix_(ylag, ylag)]

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


def lagged_products(x: np.ndarray, w: np.ndarray, P: int, Q: int, start: int, stop: int) -> np.ndarray:
    """``out[i, k] = sum_{t=start}^{stop-1} x(t - i) w(t - k)`` for lags i < P, k < Q (samples before 0 count as 0).

    The Gram block of two signals' lag columns without forming them: entry (i, i + d) is the
    product of x and w shifted by d summed over the window of rows seen at lag i; every such
    window holds the rows ``start .. stop - P`` (one dot product per shift d, P + Q - 1 of them),
    plus at most P - 1 rows at each end, added by cumulative sums of those few products. O(rows
    (P + Q)) instead of O(rows P Q), and no (rows x lags) matrix in memory. Short windows (fewer
    rows than 4 (P + Q)) are summed from their lag columns directly.
    """
    x, w = np.asarray(x, dtype=np.float64), np.asarray(w, dtype=np.float64)
    n = stop - start
    if n < 4 * (P + Q):
        X = sliding_window_view(_padded(x, start - P + 1, stop), P)[:, ::-1]
        W = sliding_window_view(_padded(w, start - Q + 1, stop), Q)[:, ::-1]
        return X.T @ W
    off = P + Q  # index of sample s in the padded signals is s - start + off
    xp = _padded(x, start - off, stop)
    wp = np.concatenate([_padded(w, start - off, stop), np.zeros(P)])  # tail products past a lag's rows: unused
    shifts = np.arange(-(P - 1), Q)  # d = k - i
    core_x = xp[off:off + n - P + 1]  # s = start .. stop - P
    core = np.array([core_x @ wp[off - d:off - d + n - P + 1] for d in shifts])
    # rows seen at lag i beyond the core: head s = start - i .. start - 1, tail s = stop - P + 1 .. stop - 1 - i
    head_s = np.arange(-(P - 1), 0)  # s - start, oldest first
    tail_s = np.arange(n - P + 1, n)  # s - start
    head = xp[off + head_s][None, :] * wp[off + head_s[None, :] - shifts[:, None]]  # (shifts, P - 1)
    tail = xp[off + tail_s][None, :] * wp[off + tail_s[None, :] - shifts[:, None]]
    # head part at lag i: the newest i head products; tail part at lag i: the oldest P - 1 - i tail products
    head_sum = np.concatenate([np.zeros((len(shifts), 1)), np.cumsum(head[:, ::-1], axis=1)], axis=1)  # [:, i]
    tail_sum = np.concatenate([np.zeros((len(shifts), 1)), np.cumsum(tail, axis=1)], axis=1)  # [:, j]: oldest j
    i = np.arange(P)[:, None]
    k = np.arange(Q)[None, :]
    d = k - i + (P - 1)  # row of shifts
    return core[d] + head_sum[d, i] + tail_sum[d, P - 1 - i]


def lagged_sums(x: np.ndarray, P: int, start: int, stop: int) -> np.ndarray:
    """``out[i] = sum_{t=start}^{stop-1} x(t - i)`` for i < P (samples before 0 count as 0): a lag column's sum."""
    xp = _padded(np.asarray(x, dtype=np.float64), start - P + 1, stop)
    n = stop - start
    return np.array([xp[P - 1 - i:P - 1 - i + n].sum() for i in range(P)])


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
