"""The hybrid MTL-KRLS: the spectral closed form against a direct primal solve, and the method."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.pools import make_samples
from enginebench.errors import MethodError
from enginebench.method import grid_points
from enginebench.methods.mtl_krls import MTLKRLS, mtl_coefficients, shared_poles
from enginebench.methods.numerics.kernels import Spectral
from enginebench.methods.numerics.shifted import shifted_solutions


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


def test_shared_filter_is_the_sum_of_its_two_partial_fractions():
    """(s + 2 theta) / (s (2 s + 4 theta + lambda) + lambda theta) = w1 / (s + mu1) + w2 / (s + mu2),
    with positive weights summing to 1/2, over the whole 41 x 41 grid and eigenvalues 0 ... 1e4."""
    g = np.logspace(-4, 4, 41)
    lam, th = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    shifts, weights = shared_poles(lam, th)
    assert (shifts > 0).all() and (weights > 0).all()
    np.testing.assert_allclose(weights.sum(axis=1), 0.5, rtol=1e-14)
    s = np.r_[0.0, np.logspace(-8, 4, 50)][:, None]
    exact = (s + 2 * th) / (s * (2 * s + 4 * th + lam) + lam * th)
    fractions = weights[:, 0] / (s + shifts[:, 0]) + weights[:, 1] / (s + shifts[:, 1])
    np.testing.assert_allclose(fractions, exact, rtol=1e-12)


@pytest.mark.parametrize("lam, theta", [(0.1, 1.0), (2.0, 0.05), (1e-2, 30.0)])
@pytest.mark.parametrize("krylov_maxiter", [0, None])
def test_partial_fraction_solves_match_the_primal_solve(lam, theta, krylov_maxiter):
    """The fast path of fit/predict_grid (two shifted ridge solves on y + p) against eq. 20's normal equations."""
    rng = np.random.default_rng(7)
    Phi, Phi_test = rng.normal(size=(40, 15)), rng.normal(size=(7, 15))
    y, p = rng.normal(size=40), rng.normal(size=40) + 0.5
    w, _, _ = primal_solution(Phi, y, p, lam, theta)
    shifts, weights = shared_poles(np.array([lam]), np.array([theta]))
    pred, _ = shifted_solutions(Phi @ Phi.T, (y + p)[:, None], shifts, weights, K_eval=Phi_test @ Phi.T,
                                krylov_maxiter=krylov_maxiter)
    np.testing.assert_allclose(pred[:, 0, 0], Phi_test @ w, rtol=1e-8, atol=1e-8 * np.abs(Phi_test @ w).max())


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


def test_fast_grid_equals_the_eigendecomposition_over_a_wide_grid(toy_samples):
    """predict_grid's partial-fraction path against the closed form in the eigenbasis (9^3 points)."""
    from enginebench.methods.numerics.kernels import gaussian, sq_distances

    train, test = toy_samples
    method = MTLKRLS(gamma_grid=(-4, 4, 9), lambda_grid=(-4, 4, 9), theta_grid=(-4, 4, 9))
    grid = grid_points(method.search_space(train))
    block = method.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    pm_params, scaler, Xs, yc, pc, offset = method._prepare(train)
    Xe = method._eval(test, pm_params, scaler)
    for g, params in enumerate(grid[::37]):
        spectral = Spectral.from_kernel(gaussian(sq_distances(Xs), params["gamma"]))
        a, _, _ = mtl_coefficients(spectral.s, spectral.project(yc), spectral.project(pc),
                                   np.array([params["lambda"]]), np.array([params["theta"]]))
        ref = spectral.predict_coeffs(gaussian(sq_distances(Xe, Xs), params["gamma"]), a[:, :, 0, :])[0] + offset
        np.testing.assert_allclose(block[g * 37], ref, rtol=0, atol=1e-8 * np.abs(ref).max())


@pytest.mark.parametrize("predict_with", ["shared", "task"])
def test_grid_predictions_equal_separate_fits(toy_samples, predict_with):
    train, test = toy_samples
    method = MTLKRLS(gamma_grid=(-1, 0, 2), lambda_grid=(-2, 0, 2), theta_grid=(-1, 1, 3), predict_with=predict_with)
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


@pytest.mark.parametrize("bad, message", [
    ({"gamma": 1.0, "lambda": 1.0}, "method 'mtl-krls': hyperparameter(s) theta missing from"),
    ({"gamma": 1.0, "lambda": 1.0, "theta": 1.0, "delta": 2}, "method 'mtl-krls': unknown hyperparameter(s) delta"),
    ({"gamma": 1.0, "lambda": -1.0, "theta": 1.0}, "hyperparameter 'lambda' must be a positive finite number, got -1.0"),
    ({"gamma": 1.0, "lambda": 1.0, "theta": "a"}, "hyperparameter 'theta' must be a positive number, got 'a'"),
])
def test_a_bad_grid_point_among_many_is_named(toy_samples, bad, message):
    train, test = toy_samples
    grid = [{"gamma": 1.0, "lambda": 0.1, "theta": 1.0}] * 50 + [bad]
    with pytest.raises(MethodError) as err:
        MTLKRLS().predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert str(err.value).startswith(message)


@pytest.mark.parametrize("predict_with", ["shared", "task"])
def test_a_bootstrap_resamples_repeated_rows_are_solved_once(toy_samples, monkeypatch, predict_with):
    """Repeated training rows merge into weighted ones (numerics/repeats.py): the same grid predictions
    as the full system, for the shared model (shifted solves) and the task model (eigenbasis)."""
    import enginebench.methods.mtl_krls as mtl_module

    train, test = toy_samples
    boot = train.take(np.sort(np.random.default_rng(3).integers(0, len(train), len(train))))
    method = MTLKRLS(gamma_grid=(-3, 1, 5), lambda_grid=(-4, 2, 4), theta_grid=(-3, 3, 4), predict_with=predict_with)
    grid = grid_points(method.search_space(boot))
    merged = method.predict_grid(boot, test.without_targets(), grid, np.random.default_rng(0))
    monkeypatch.setattr(mtl_module, "RowGroups", type("Off", (), {"of": staticmethod(lambda X: None)}))
    full = method.predict_grid(boot, test.without_targets(), grid, np.random.default_rng(0))
    assert np.abs(merged - full).max() > 0  # a different (smaller) system was solved
    # the task model diagonalises the full kernel, exactly singular with repeats: rounding ~1e-9 there
    tol = 1e-10 if predict_with == "shared" else 1e-8
    np.testing.assert_allclose(merged, full, rtol=0, atol=tol * np.abs(full).max())
