"""``numerics.lag_gram``: every grid point read from one Gram matrix equals least squares (LAPACK gelsd) on
that point's own regression matrix, and ill-posed points are handed back to the SVD solver."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from enginebench.methods.numerics.lag_gram import LagGram, Orders, lag_columns


def _segments(seed: int = 0, lengths=(300, 170, 90)):
    rng = np.random.default_rng(seed)
    out = []
    for n in lengths:
        U = rng.standard_normal((n, 2)).cumsum(axis=0) * 0.1 + rng.standard_normal((n, 2))
        y = np.zeros(n)
        for t in range(2, n):
            y[t] = 1.2 * y[t - 1] - 0.4 * y[t - 2] + 0.5 * U[t - 1, 0] - 0.2 * U[t, 1] + 0.05 * rng.standard_normal()
        out.append((U, y))
    return out


def _reference(segments, o: Orders) -> np.ndarray:
    Phi = np.vstack([lag_columns(y, U, np.arange(o.first_row, len(y)), o) for U, y in segments if len(y) > o.first_row])
    y = np.concatenate([y[o.first_row:] for U, y in segments if len(y) > o.first_row])
    return scipy.linalg.lstsq(Phi, y, lapack_driver="gelsd")[0]


def test_every_point_equals_least_squares_on_its_own_rows():
    segs = _segments()
    points = [Orders(na, nb, nk) for na in (0, 1, 3, 8) for nb in (1, 2, 5) for nk in (0, 1, 2)]
    gram = LagGram(segs, points)
    assert gram.L == 8 and gram.Pu == 7
    for o in points:
        got = gram.solve(o)
        assert got is not None, o
        np.testing.assert_allclose(got, _reference(segs, o), rtol=1e-9, atol=1e-10)
        assert gram.rows(o) == sum(len(y) - o.first_row for _, y in segs)


def test_dependent_columns_go_to_the_svd_solver():
    segs = [(np.c_[U[:, :1], np.ones(len(U))], y) for U, y in _segments(1)]  # a constant input = the offset column
    gram = LagGram(segs, [Orders(2, 2, 1)])
    assert gram.solve(Orders(2, 2, 1)) is None


def test_a_segment_shorter_than_the_longest_lag_still_gives_its_rows_to_short_points():
    segs = _segments(2, lengths=(400, 12))
    points = [Orders(1, 1, 0), Orders(16, 16, 1)]
    gram = LagGram(segs, points)
    np.testing.assert_allclose(gram.solve(points[0]), _reference(segs, points[0]), rtol=1e-9, atol=1e-10)
    assert gram.rows(points[0]) == 399 + 11


def test_targets_share_the_input_columns_and_each_equals_its_own_fit():
    segs = _segments(3)
    rng = np.random.default_rng(4)
    two = [(U, np.c_[y, np.convolve(U[:, 1], [0.3, 0.2])[:len(y)] + 0.01 * rng.standard_normal(len(y))])
           for U, y in segs]
    points = [Orders(2, 3, 1), Orders(4, 1, 0)]
    gram = LagGram(two, points)
    for target in (0, 1):
        one = [(U, Y[:, target]) for U, Y in two]
        for o in points:
            np.testing.assert_allclose(gram.solve(o, target), _reference(one, o), rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("n, P, Q, start, stop", [
    (500, 5, 7, 3, 500), (1000, 64, 64, 0, 1000), (1000, 8, 3, 40, 900), (3000, 64, 65, 64, 3000),
    (600, 1, 1, 0, 600), (2000, 1, 64, 0, 2000), (60, 8, 8, 2, 60),  # the last: a short window, summed directly
])
def test_lagged_products_equal_the_lag_columns_products(n, P, Q, start, stop):
    """The Gram block from lagged products equals the product of the materialised lag columns (zeros before
    sample 0), and a lag column's sum equals lagged_sums; at every size, start and lag count."""
    from numpy.lib.stride_tricks import sliding_window_view

    from enginebench.methods.numerics.lag_gram import lagged_products, lagged_sums

    rng = np.random.default_rng(n + P + Q)
    x, w = rng.normal(size=n) + 3.0, rng.normal(size=n)

    def columns(s: np.ndarray, lags: int) -> np.ndarray:
        padded = np.r_[np.zeros(lags), s]
        return sliding_window_view(padded[start + 1:stop + lags], lags)[:, ::-1]

    X, W = columns(x, P), columns(w, Q)
    assert X.shape == (stop - start, P) and np.array_equal(X[:, 0], x[start:stop])
    np.testing.assert_allclose(lagged_products(x, w, P, Q, start, stop), X.T @ W, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(lagged_sums(x, P, start, stop), X.sum(axis=0), rtol=1e-12)
