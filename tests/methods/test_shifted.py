"""Sums of shifted kernel solves (methods/numerics/shifted.py): every route against dense solves."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.errors import MethodError
from enginebench.methods.numerics.kernels import gaussian, sq_distances
from enginebench.methods.numerics.shifted import shifted_solutions


def _problem(n: int, m: int, gamma: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n + m, 4))
    K = gaussian(sq_distances(X[:n]), gamma)
    Ke = gaussian(sq_distances(X[n:], X[:n]), gamma)
    B = np.stack([np.sin(X[:n, 0]) + 0.1 * rng.normal(size=n), X[:n, 1] * X[:n, 2]], axis=1)
    return K, Ke, B


def _dense(K: np.ndarray, B: np.ndarray, shifts: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """sum_r w_jr (K + mu_jr I)^-1 B by one dense solve per shift: (n, J, k)."""
    n = len(K)
    return np.stack([sum(w * np.linalg.solve(K + mu * np.eye(n), B) for mu, w in zip(mus, ws))
                     for mus, ws in zip(shifts, weights)], axis=1)


@pytest.mark.parametrize("gamma", [1e-3, 0.3, 30.0])
@pytest.mark.parametrize("krylov_maxiter", [0, 8, None])
def test_two_term_sums_match_dense_solves_on_every_route(gamma: float, krylov_maxiter: int | None) -> None:
    K, Ke, B = _problem(150, 40, gamma)
    rng = np.random.default_rng(1)
    shifts = 10.0 ** rng.uniform(-3, 2, (25, 2))
    weights = rng.uniform(-1, 1, (25, 2))
    ref = _dense(K, B, shifts, weights)
    scale = np.abs(ref).max()
    X, counts = shifted_solutions(K, B, shifts, weights, krylov_maxiter=krylov_maxiter)
    assert counts["krylov"] + counts["cholesky"] + counts["householder"] == 25 * 2
    np.testing.assert_allclose(X, ref, rtol=0, atol=1e-8 * scale)
    P, _ = shifted_solutions(K, B, shifts, weights, K_eval=Ke, krylov_maxiter=krylov_maxiter)
    np.testing.assert_allclose(P, np.einsum("mn,njk->mjk", Ke, ref), rtol=0, atol=1e-8 * np.abs(Ke @ ref[:, 0]).max() * 10)
    if krylov_maxiter == 0:
        assert counts["householder"] == 50
    if krylov_maxiter is None and gamma != 0.3:  # low rank / near identity: Lanczos certifies every point
        assert counts["krylov"] == 50


def test_predictions_transform_the_smaller_side_with_the_same_result() -> None:
    """Few grid points and many evaluation rows: H is applied to the solutions, not to K_eval."""
    K, Ke, B = _problem(120, 300, 0.3)
    shifts = np.array([[1e-3, 2.0], [0.1, 5.0]])
    weights = np.array([[0.25, 0.25], [0.4, 0.1]])
    ref = np.einsum("mn,njk->mjk", Ke, _dense(K, B, shifts, weights))
    P, counts = shifted_solutions(K, B, shifts, weights, K_eval=Ke, krylov_maxiter=0)
    assert counts["cholesky"] == 4  # four distinct shifts: one Cholesky each
    np.testing.assert_allclose(P, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("krylov_maxiter", [0, None])
def test_results_written_into_a_view_of_a_larger_array(krylov_maxiter: int | None) -> None:
    """``out``: MTL-KRLS writes each gamma's predictions straight into its (rows, points, k) output."""
    K, Ke, B = _problem(120, 30, 0.3)
    rng = np.random.default_rng(2)
    shifts, weights = 10.0 ** rng.uniform(-3, 2, (9, 2)), rng.uniform(-1, 1, (9, 2))
    big = np.full((30, 20, 2), -7.0)
    block = big[:, 5:14]
    P, _ = shifted_solutions(K, B, shifts, weights, K_eval=Ke, krylov_maxiter=krylov_maxiter, out=block)
    assert P is block
    ref, _ = shifted_solutions(K, B, shifts, weights, K_eval=Ke, krylov_maxiter=krylov_maxiter)
    np.testing.assert_array_equal(big[:, 5:14], ref)
    assert (big[:, :5] == -7.0).all() and (big[:, 14:] == -7.0).all()
    with pytest.raises(ValueError, match=r"shifted solutions: out has shape \(30, 8, 2\), expected \(30, 9, 2\)"):
        shifted_solutions(K, B, shifts, weights, K_eval=Ke, out=big[:, :8])


def test_one_dimensional_shifts_are_plain_ridge_solutions() -> None:
    K, _, B = _problem(60, 1, 1.0)
    lambdas = np.array([1e-2, 1.0])
    X, _ = shifted_solutions(K, B, lambdas)
    for i, lam in enumerate(lambdas):
        np.testing.assert_allclose(X[:, i], np.linalg.solve(K + lam * np.eye(60), B), rtol=1e-9)


def test_bad_shifts_and_weights_are_refused() -> None:
    K, _, B = _problem(10, 1, 1.0)
    with pytest.raises(MethodError, match="hyperparameter 'lambda' must be a positive finite number, got -1.0"):
        shifted_solutions(K, B, np.array([[1.0, -1.0]]))
    with pytest.raises(MethodError, match="the weights contain nan/inf"):
        shifted_solutions(K, B, np.array([[1.0, 2.0]]), np.array([[1.0, np.nan]]))


@pytest.mark.parametrize("m", [10, 400])  # K_eval transformed (m < J k) or the solutions (m >= J k)
def test_many_shifts_take_the_tridiagonal_eigenbasis_with_the_same_result(monkeypatch, m: int) -> None:
    """More distinct shifts than kernel rows (MTL-KRLS's ~2,600 per gamma): the Householder route
    diagonalises T once instead of one tridiagonal solve per shift; both equal dense solves."""
    from enginebench.methods.numerics import shifted

    K, Ke, B = _problem(40, m, 0.3)
    rng = np.random.default_rng(3)
    shifts, weights = 10.0 ** rng.uniform(-4, 2, (30, 2)), rng.uniform(0, 1, (30, 2))  # 60 shifts > 40 rows
    ref = _dense(K, B, shifts, weights)
    results = {}
    for per_row, route in [(1.0, "eigenbasis"), (1e9, "solves")]:
        monkeypatch.setattr(shifted, "SPECTRAL_SHIFTS_PER_ROW", per_row)
        calls = []
        monkeypatch.setattr(shifted, "_tridiagonal_eigh", lambda d, e, f=shifted._tridiagonal_eigh: calls.append(1) or f(d, e))
        X, counts = shifted_solutions(K, B, shifts, weights, krylov_maxiter=0)
        P, _ = shifted_solutions(K, B, shifts, weights, K_eval=Ke, krylov_maxiter=0)
        assert counts["householder"] == 60 and len(calls) == (2 if route == "eigenbasis" else 0)
        np.testing.assert_allclose(X, ref, rtol=0, atol=1e-9 * np.abs(ref).max())
        np.testing.assert_allclose(P, np.einsum("mn,njk->mjk", Ke, ref), rtol=0, atol=1e-9 * np.abs(P).max())
        results[route] = P
    np.testing.assert_allclose(results["eigenbasis"], results["solves"], rtol=0, atol=1e-10 * np.abs(ref).max())
