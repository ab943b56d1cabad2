"""The hybrid MTL-KRLS: the spectral closed form against a direct primal solve, and the method."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.samples import make_samples
from enginebench.errors import MethodError
from enginebench.methods.base import grid_points
from enginebench.methods.kernels import Spectral
from enginebench.methods.mtl_krls import MTLKRLS, mtl_coefficients


def primal_solution(Phi, y, p, lam, theta):
    """w, w_y, w_p from the normal equations of the seed's eq. 20, solved directly."""
    D = Phi.shape[1]
    G = Phi.T @ Phi
    I = np.eye(D)
    A = np.block([
        [2 * G + (lam + 2 * theta) * I, -theta * I, -theta * I],
        [-theta * I, G + theta * I, np.zeros((D, D))],
        [-theta * I, np.zeros((D, D)), G + theta * I],
    ])
    rhs = np.concatenate([Phi.T @ (y + p), Phi.T @ y, Phi.T @ p])
    sol = np.linalg.solve(A, rhs)
    return sol[:D], sol[D:2 * D], sol[2 * D:]


@pytest.mark.parametrize("n, D", [(40, 15), (30, 60)])  # fewer and more features than rows
@pytest.mark.parametrize("lam, theta", [(0.1, 1.0), (2.0, 0.05), (1e-2, 30.0)])
def test_spectral_closed_form_matches_the_primal_solve(n, D, lam, theta):
    rng = np.random.default_rng(n + D)
    Phi, Phi_test = rng.normal(size=(n, D)), rng.normal(size=(7, D))
    y, p = rng.normal(size=n), rng.normal(size=n) + 0.5
    w, w_y, _ = primal_solution(Phi, y, p, lam, theta)
    spectral = Spectral.from_kernel(Phi @ Phi.T)
    a, b, c = mtl_coefficients(spectral.s, spectral.project(y[:, None]), spectral.project(p[:, None]),
                               np.array([lam]), np.array([theta]))
    K_test = Phi_test @ Phi.T
    shared = spectral.predict_coeffs(K_test, a[:, :, 0, :])[0, :, 0]
    task_y = spectral.predict_coeffs(K_test, b[:, :, 0, :])[0, :, 0]
    np.testing.assert_allclose(shared, Phi_test @ w, rtol=1e-8, atol=1e-8 * np.abs(Phi_test @ w).max())
    np.testing.assert_allclose(task_y, Phi_test @ w_y, rtol=1e-8, atol=1e-8 * np.abs(Phi_test @ w_y).max())


def test_coefficients_solve_each_3x3_system():
    rng = np.random.default_rng(3)
    s = rng.uniform(0, 5, 6)
    y_t, p_t = rng.normal(size=(6, 1)), rng.normal(size=(6, 1))
    lams, thetas = np.array([0.1, 3.0]), np.array([0.01, 1.0, 100.0])
    a, b, c = mtl_coefficients(s, y_t, p_t, lams, thetas)
    for k in range(6):
        for i, lam in enumerate(lams):
            for j, th in enumerate(thetas):
                M = np.array([[2 * s[k] + lam + 2 * th, -th, -th], [-th, s[k] + th, 0], [-th, 0, s[k] + th]])
                rhs = np.array([y_t[k, 0] + p_t[k, 0], y_t[k, 0], p_t[k, 0]])
                np.testing.assert_allclose([a[k, i, j, 0], b[k, i, j, 0], c[k, i, j, 0]], np.linalg.solve(M, rhs), rtol=1e-10)


def test_limits_in_theta_reduce_to_krls_on_the_task_average():
    """theta -> infinity ties all three models: KRLS on (y + p)/2 with lambda/4."""
    rng = np.random.default_rng(5)
    s = rng.uniform(0.1, 5, 8)
    y_t, p_t = rng.normal(size=(8, 1)), rng.normal(size=(8, 1))
    a, _, _ = mtl_coefficients(s, y_t, p_t, np.array([0.4]), np.array([1e12]))
    np.testing.assert_allclose(a[:, 0, 0, 0], ((y_t + p_t) / 2)[:, 0] / (s + 0.1), rtol=1e-9)


class ToyPM:
    """An imperfect physics of the toy data: misses the y(t-1) feedback and the u2 gain."""

    name = "toy-pm"
    inputs = ("u1", "u2")
    outputs = ("y",)

    def calibrate(self, segments):
        return {"offset": float(np.mean(np.concatenate([s["y"] for s in segments])))}

    def simulate(self, params, segment, dt):
        return {"y": np.sin(segment["u1"]) + 0.4 * segment["u2"] + params["offset"] - 0.0}


@pytest.fixture
def toy_samples(toy):
    train = make_samples(toy.select_segments(["s0", "s1"]), ["y"], physical_model=ToyPM())
    test = make_samples(toy.select_segments(["s3"]), ["y"], physical_model=ToyPM())
    return train, test


def test_grid_predictions_equal_separate_fits(toy_samples):
    train, test = toy_samples
    method = MTLKRLS(gamma_grid=(-1, 0, 2), lambda_grid=(-2, 0, 2), theta_grid=(-1, 1, 3))
    grid = grid_points(method.search_space(train))
    assert len(grid) == 12
    rng = np.random.default_rng(0)
    block = method.predict_grid(train, test.without_targets(), grid, rng)
    for g, params in enumerate(grid):
        single = np.concatenate(method.predict(method.fit(train, params, rng), test.without_targets()))
        np.testing.assert_allclose(block[g], single, rtol=1e-9, atol=1e-9)


def test_switches_change_the_model(toy_samples):
    train, test = toy_samples
    params = {"gamma": 0.3, "lambda": 0.1, "theta": 1.0}
    rng = np.random.default_rng(0)
    preds = {}
    for opts in [{}, {"pm_feature": False}, {"pm_task": False}, {"predict_with": "task"}]:
        m = MTLKRLS(**opts)
        preds[str(opts)] = np.concatenate(m.predict(m.fit(train, params, rng), test.without_targets()))
    values = list(preds.values())
    for i in range(len(values)):
        for j in range(i + 1, len(values)):
            assert not np.allclose(values[i], values[j])
    described = MTLKRLS().describe(MTLKRLS().fit(train, params, rng))
    assert described["theta"] == 1.0 and described["rms_distance_to_pm_on_training_rows"] > 0


def test_needs_a_physical_model(toy):
    train = make_samples(toy, ["y"])
    with pytest.raises(MethodError, match="declares no physical model"):
        MTLKRLS().fit(train, {"gamma": 1.0, "lambda": 1.0, "theta": 1.0}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="predict_with must be 'shared' or 'task'"):
        MTLKRLS(predict_with="both")
