"""NFIR's shared-work grid path (``numerics/kernel_grid.py``) equals one solve per grid point."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.methods.numerics.kernel_grid import kernel_ridge_grid


def problem(n: int = 300, m: int = 250, d: int = 6, k: int = 2, seed: int = 0):
    """Smooth nonlinear targets of standardised-scale features, and evaluation rows beside them."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    Xe = rng.normal(size=(m, d)) * 1.2
    w = rng.normal(size=(d, k))
    y = np.sin(X @ w) + 0.05 * rng.normal(size=(n, k))
    return X, y - y.mean(axis=0), Xe


def one_point(X: np.ndarray, y: np.ndarray, Xe: np.ndarray, gamma: float, lam: float) -> np.ndarray:
    """The straightforward route: the kernels from explicit differences, one dense solve."""
    D = ((X[:, None, :] - X[None, :, :]) ** 2).sum(axis=2)
    De = ((Xe[:, None, :] - X[None, :, :]) ** 2).sum(axis=2)
    return np.exp(-gamma * De) @ np.linalg.solve(np.exp(-gamma * D) + lam * np.eye(len(X)), y)


def grid_of(gammas, lambdas):
    g, lam = np.meshgrid(gammas, lambdas, indexing="ij")
    return g.ravel(), lam.ravel()


def run(X, y, Xe, gammas, lambdas, chunk) -> tuple[np.ndarray, list[float]]:
    out = np.full((len(gammas), len(Xe), y.shape[1]), np.nan)
    order = []
    for idx, pred in kernel_ridge_grid(X, y, Xe, gammas, lambdas, chunk):
        assert np.all(gammas[idx] == gammas[idx[0]]) and np.isnan(out[idx]).all()  # each point once
        order.append(float(gammas[idx[0]]))
        out[idx] = pred
    return out, order


@pytest.mark.parametrize("chunk", [64, 10_000])  # several evaluation chunks, or one shared by every gamma
def test_every_grid_point_equals_its_own_solve(chunk):
    X, y, Xe = problem()
    # gammas from nearly flat to nearly diagonal kernels: Lanczos, Cholesky and Householder routes all serve
    gammas, lambdas = grid_of([3e-3, 0.05, 0.5, 5.0], [1e-3, 1e-2, 0.1, 1.0])
    shuffle = np.random.default_rng(1).permutation(len(gammas))  # grid order need not be gamma-major
    gammas, lambdas = gammas[shuffle], lambdas[shuffle]
    out, order = run(X, y, Xe, gammas, lambdas, chunk)
    assert order == list(dict.fromkeys(gammas.tolist()))
    for i, (g, lam) in enumerate(zip(gammas, lambdas)):
        np.testing.assert_allclose(out[i], one_point(X, y, Xe, g, lam), rtol=0, atol=1e-9 * np.abs(y).max())


def test_tiny_penalties_differ_from_one_solve_by_rounding_only():
    """Down to lambda = 1e-8 both routes are exact to rounding, amplified at most like the condition 1 / lambda."""
    X, y, Xe = problem(seed=2)
    gammas, lambdas = grid_of([1e-3, 0.1], 10.0 ** np.arange(-8, 1))
    out, _ = run(X, y, Xe, gammas, lambdas, 100)
    for i, (g, lam) in enumerate(zip(gammas, lambdas)):
        err = np.abs(out[i] - one_point(X, y, Xe, g, lam)).max() / np.abs(y).max()
        assert err <= 1e-11 / lam + 1e-9, (g, lam, err)  # measured: below a quarter of it


def test_no_evaluation_rows_give_empty_predictions():
    X, y, _ = problem(n=40)
    blocks = list(kernel_ridge_grid(X, y, np.empty((0, X.shape[1])), np.array([0.1, 0.1]), np.array([1e-2, 1.0]), 8))
    assert len(blocks) == 1 and blocks[0][1].shape == (2, 0, 2)
