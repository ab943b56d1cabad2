"""The shared numerics (methods/numerics/): windowed differentiator, batched fixed-step integrator, device resolver."""

from __future__ import annotations

import itertools
import warnings

import numpy as np
import pytest
import torch
from derivative import Kalman, TrendFiltered
from derivative.utils import integ
from sklearn.linear_model import LassoLars

from enginebench.errors import DataError, MethodError
from enginebench.methods.numerics.derivatives import differentiate, segment_derivatives, window_bounds
from enginebench.methods.numerics.device import resolve_device
from enginebench.methods.numerics import tv_admm
from enginebench.methods.numerics.tv_admm import integral_matrix, kkt_violation, objective, tv_solve
from enginebench.methods.numerics.integrate import hold_after_exit, integrate


def test_window_bounds_with_a_longer_first_window_tile_the_signal():
    for n in (5, 256, 257, 300, 449, 1000, 1153):
        bounds = window_bounds(n, 256, 32, first_keep=224)
        kept = np.concatenate([np.arange(a, b) for _, _, a, b in bounds])
        np.testing.assert_array_equal(kept, np.arange(n))
        assert all(hi - lo == min(n, 256) and lo <= a and b <= hi for lo, hi, a, b in bounds)
        # every inner edge keeps the margin: a kept range starts >= 32 after its window unless at 0
        assert all(a - lo >= 32 or lo == 0 for lo, _, a, _ in bounds)
        assert all(hi - b >= 32 or hi == n for _, hi, _, b in bounds)
    assert window_bounds(1000, 256, 32, first_keep=224)[:2] == [(0, 256, 0, 224), (192, 448, 224, 416)]
    with pytest.raises(DataError, match="first_keep=250 must be in"):
        window_bounds(1000, 256, 32, first_keep=250)


def test_one_window_is_exactly_the_package_estimate_for_both_kinds():
    rng = np.random.default_rng(0)
    t = np.arange(90) * 1.0
    y = np.sin(0.1 * t) + 0.01 * rng.standard_normal(90)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tv_ref = TrendFiltered(order=0, alpha=1e-3, max_iter=20000).d(y, t)
        kal_ref = Kalman(alpha=1.0).d(y, t)
        _, tv = differentiate(y, t, 1e-3, tol=1e-4, max_iter=20000, precompute=False, solver="lasso")
    _, kal = differentiate(y, t, 1.0, kind="kalman")
    np.testing.assert_allclose(tv, tv_ref, rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(kal, kal_ref, rtol=1e-7, atol=1e-10)
    with pytest.raises(DataError, match="unknown kind 'spline'"):
        differentiate(y, t, 1.0, kind="spline")
    with pytest.raises(DataError, match="unknown solver 'cvx'; use one of admm, lasso"):
        differentiate(y, t, 1.0, solver="cvx")


def _tv_reference(y: np.ndarray, dt: float, alpha: float) -> np.ndarray:
    """The TV derivative by exact LARS on the problem written as a Lasso in the jumps of u.

    u = c + cumsum(v): the integral of a unit step at sample i is column i of A C; the free
    constant c is projected out, as in the ``derivative`` package.
    """
    n = y.size
    A = integ(n, dt)
    AC = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]
    x0, X1 = AC[:, :1], AC[:, 1:] * dt  # a jump of dt * (du/dt difference) per sample: |D u|_1 = |v|_1 / dt
    P = np.eye(n) - x0 @ np.linalg.pinv(x0)
    b = y - y[0]
    v = LassoLars(alpha=alpha / n, fit_intercept=False, max_iter=10_000).fit(P @ X1, P @ b).coef_ * dt
    c = np.linalg.lstsq(x0, b - AC[:, 1:] @ v, rcond=None)[0][0]
    return c + np.r_[0.0, np.cumsum(v)]


@pytest.mark.parametrize(
    ("n", "dt", "alpha", "lars_exact"), [(90, 1.0, 1e-3, False), (128, 0.25, 0.05, True), (60, 2.0, 1e-2, True)]
)
def test_tv_admm_reaches_the_exact_minimiser_that_coordinate_descent_stops_short_of(n, dt, alpha, lars_exact):
    rng = np.random.default_rng(n)
    t = np.arange(n) * dt
    y = np.sin(0.05 * t) + 0.3 * (t > t[n // 2]) + 0.01 * rng.standard_normal(n)
    A = integ(n, dt)
    ref = _tv_reference(y, dt, alpha)
    _, ours = differentiate(y, t, alpha)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, cd = differentiate(y, t, alpha, solver="lasso", tol=1e-4, max_iter=20000, precompute=False)
    B = (y - y[0])[:, None]
    f_ref, f_ours, f_cd = (float(objective(u[:, None], B, A, alpha, dt)[0]) for u in (ref, ours, cd))
    assert f_ours <= f_ref * (1 + 1e-9)
    assert float(kkt_violation(ours[:, None], B, A, alpha, dt)[0]) <= 1e-6
    # LARS itself is exact only where its path stays well conditioned (54 jumps of 89 at n = 90 is not)
    assert (float(kkt_violation(ref[:, None], B, A, alpha, dt)[0]) <= 1e-6) is lars_exact
    if lars_exact:
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-7 * np.abs(ref).max())
    assert f_cd > f_ours * (1 + 1e-6)  # the package's route stops short of the optimum here


def test_tv_admm_batches_windows_and_columns_like_separate_solves(monkeypatch):
    rng = np.random.default_rng(3)
    t = np.arange(700) * 0.5
    Y = np.c_[np.sin(0.02 * t), np.cos(0.05 * t)] + 0.01 * rng.standard_normal((700, 2))
    smooth, both = differentiate(Y, t, 1e-2, window=128, margin=16)
    for c in range(2):
        _, one = differentiate(Y[:, c], t, 1e-2, window=128, margin=16)
        np.testing.assert_allclose(both[:, c], one, rtol=0, atol=1e-9)
    # the smoothed signal integrates the derivative from each window's first sample
    assert np.abs(smooth - Y).max() < 0.05
    # the refinement solves these windows after one ADMM iteration: without it every window stays open
    monkeypatch.setattr(tv_admm, "REFINE", 0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, capped = differentiate(Y, t, 1e-2, window=128, margin=16, max_iter=1, quiet=False)
    assert np.isfinite(capped).all()
    assert len(caught) == 2 * len(window_bounds(700, 128, 16))
    assert "did not reach its optimum (KKT test 0.001) within max_iter=1 iterations" in str(caught[0].message)


def _brute_force_tv(b: np.ndarray, alpha: float, dt: float) -> np.ndarray:
    """The exact minimiser of a tiny window: every sign pattern of the jumps, each a signed least squares.

    The objective restricted to one orthant of the jumps is the quadratic the pattern's signed fit
    minimises; its minimiser counts only if it keeps the pattern's signs (else that orthant's minimum
    lies on a face, which a pattern with fewer jumps covers). The global minimum is the best of those.
    """
    n = b.size
    A = integral_matrix(n, dt)
    AC = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]
    lam = alpha / dt
    best, f_best = None, np.inf
    for pattern in itertools.product((-1.0, 0.0, 1.0), repeat=n - 1):
        s = np.array(pattern)
        S = np.r_[0, np.flatnonzero(s) + 1]
        X = AC[:, S]
        q = np.r_[0.0, lam * s[s != 0]]
        theta = np.linalg.lstsq(X.T @ X, X.T @ b - q, rcond=None)[0]
        if np.any(np.sign(theta[1:]) != s[s != 0]):
            continue
        t = np.zeros(n)
        t[S] = theta
        u = t[0] + np.r_[0.0, np.cumsum(t[1:])]
        f = float(objective(u[:, None], b[:, None], A, alpha, dt)[0])
        if f < f_best:
            best, f_best = u, f
    return best


def test_tv_solve_equals_the_brute_force_minimiser_of_tiny_windows():
    rng = np.random.default_rng(7)
    n, dt = 7, 0.5
    t = np.arange(n) * dt
    B = np.column_stack([np.sin(0.7 * t + ph) + 0.3 * (t > 1.2) + 0.05 * rng.standard_normal(n) for ph in range(6)])
    B -= B[0]
    for alpha in (1e-3, 1e-2, 5e-2):
        U, ok = tv_solve(B, alpha, dt)
        assert ok.all()
        for w in range(B.shape[1]):
            ref = _brute_force_tv(B[:, w], alpha, dt)
            np.testing.assert_allclose(U[:, w], ref, rtol=0, atol=1e-8 * np.abs(ref).max())


def _lasso_reference(b: np.ndarray, alpha: float, dt: float) -> tuple[float, np.ndarray]:
    """Minimum and minimiser by scipy's SLSQP on the lasso in the jumps, split into positive and negative parts."""
    from scipy.optimize import minimize

    n = b.size
    AC = np.cumsum(integral_matrix(n, dt)[:, ::-1], axis=1)[:, ::-1]
    lam = alpha / dt
    scale = np.linalg.norm(AC, axis=0)  # columns scaled to unit norm
    X = AC / scale

    def f(x):
        c, p, m = x[0], x[1:n], x[n:]
        theta = np.r_[c, p - m]
        r = X @ theta - b
        g = X.T @ r
        return 0.5 * r @ r + lam * ((p + m) / scale[1:]).sum(), np.r_[g[0], g[1:] + lam / scale[1:], -g[1:] + lam / scale[1:]]

    bounds = [(None, None)] + [(0.0, None)] * (2 * (n - 1))
    res = minimize(f, np.zeros(2 * n - 1), jac=True, method="SLSQP", bounds=bounds, options=dict(maxiter=10_000, ftol=1e-16))
    assert res.success, res.message
    theta = np.r_[res.x[0], res.x[1:n] - res.x[n:]] / scale
    return float(res.fun), theta[0] + np.r_[0.0, np.cumsum(theta[1:])]


def test_tv_solve_matches_a_scipy_lasso_reference_and_every_accepted_window_passes_the_kkt_test():
    rng = np.random.default_rng(11)
    n, dt, alpha = 40, 0.1, 1e-3
    t = np.arange(n) * dt
    B = np.column_stack([np.sin(2 * t + ph) + 0.5 * (t > 2.0) * ph + 0.02 * rng.standard_normal(n) for ph in range(2)])
    B -= B[0]
    A = integral_matrix(n, dt)
    U, ok = tv_solve(B, alpha, dt)
    assert ok.all()
    assert kkt_violation(U, B, A, alpha, dt).max() <= 1e-6  # accepted at 1e-3, reached to rounding
    f_ours = objective(U, B, A, alpha, dt)
    for w in range(B.shape[1]):
        f_ref, u_ref = _lasso_reference(B[:, w], alpha, dt)
        assert abs(f_ours[w] - f_ref) <= 1e-12 * f_ref
        np.testing.assert_allclose(U[:, w], u_ref, rtol=0, atol=1e-5 * np.abs(u_ref).max())
    # a real-sized batch: only windows that pass the test are reported converged, and those that do pass it
    y = np.cumsum(rng.standard_normal(4000)) * 0.05 + np.sin(np.arange(4000) * 0.01)
    W = np.stack([y[i : i + 256] - y[i] for i in range(0, 4000 - 256, 192)], axis=1)
    for max_iter in (100, 300):
        U, ok = tv_solve(W, alpha, dt, max_iter=max_iter)
        assert ok.any()
        kkt = kkt_violation(U, W, integral_matrix(256, dt), alpha, dt)
        np.testing.assert_array_equal(ok, kkt <= 1e-3)


def test_refinement_reaches_the_optimum_where_sign_polishing_alone_does_not(monkeypatch):
    # a derivative with three levels (two jumps) plus noise: the polish of an empty support (a constant
    # u) fails the test; the refinement adds the jumps the gradient points at and drops wrong ones
    rng = np.random.default_rng(5)
    n, dt, alpha = 120, 0.1, 1e-2
    tt = np.arange(n) * dt
    du = np.where(tt < 4.0, 1.0, np.where(tt < 8.0, -0.5, 0.8))
    y = np.r_[0.0, np.cumsum((du[1:] + du[:-1]) / 2) * dt] + 1e-3 * rng.standard_normal(n)
    b = y - y[0]
    A = integral_matrix(n, dt)
    AC = np.cumsum(A[:, ::-1], axis=1)[:, ::-1]
    lam = alpha / dt
    ref, ok = tv_solve(b[:, None], alpha, dt)
    assert ok[0]
    for z in (np.zeros(n - 1), -np.sign(np.diff(ref[:, 0]))):  # nothing known; every sign wrong
        plain = tv_admm._refined_polish(AC, b, z, lam, steps=0)
        refined = tv_admm._refined_polish(AC, b, z, lam, steps=50)
        assert kkt_violation(plain[:, None], b[:, None], A, alpha, dt)[0] > 1.0
        assert kkt_violation(refined[:, None], b[:, None], A, alpha, dt)[0] <= 1e-6
        np.testing.assert_allclose(refined, ref[:, 0], rtol=0, atol=1e-9 * np.abs(ref).max())
    # in the solver: after one polishing pass the refinement accepts windows plain polishing leaves open
    W = np.column_stack([b + 0.01 * np.sin(k * tt) for k in range(8)])
    _, ok_refined = tv_solve(W, alpha, dt, max_iter=tv_admm.ROUND)
    monkeypatch.setattr(tv_admm, "REFINE", 0)
    _, ok_plain = tv_solve(W, alpha, dt, max_iter=tv_admm.ROUND)
    assert ok_refined.all() and not ok_plain.all()


def test_segment_derivatives_name_the_failing_segment():
    t = np.arange(10) * 0.1
    ok = segment_derivatives([np.sin(t), np.cos(t)], [t, t], 1e-3, where=["seg 'a'", "seg 'b'"])
    assert [d.shape for d in ok] == [(10,), (10,)]
    bad_t = np.r_[t[:5], t[5:] + 0.05]
    with pytest.raises(DataError, match=r"^seg 'b': tv derivative: time is not uniformly sampled"):
        segment_derivatives([np.sin(t), np.cos(t)], [t, bad_t], 1e-3, where=["seg 'a'", "seg 'b'"])


def _decay(x, u):
    return -x + u


@pytest.mark.parametrize("method,inputs", [("rk4", "hold"), ("rk4", "linear"), ("euler", "hold")])
def test_integrator_matches_the_analytic_solution_in_numpy_and_torch(method, inputs):
    """dx/dt = -x + u with u = 1 from x0 = 3: x(t) = 1 + 2 e^{-t}; numpy and torch give the same numbers."""
    h, n = 0.05, 101
    U = np.ones((2, n, 1))
    H = np.full((2, n - 1), h)
    x0 = np.array([[3.0], [3.0]])
    lo, hi = np.array([-1e9]), np.array([1e9])
    traj, div = integrate(_decay, x0, U, H, [n, 40], lo, hi, method=method, inputs=inputs)
    exact = 1 + 2 * np.exp(-np.arange(n) * h)
    tol = 1e-6 if method == "rk4" else 3e-2
    np.testing.assert_allclose(traj[0, :, 0], exact, atol=tol)
    np.testing.assert_array_equal(traj[1, 40:, 0], traj[1, 39, 0])  # past its length a segment is not stepped
    assert not div.any()
    as_t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    t_traj, t_div = integrate(_decay, as_t(x0), as_t(U), as_t(H), [n, 40], as_t(lo), as_t(hi), method=method,
                              inputs=inputs)
    np.testing.assert_allclose(t_traj.numpy(), traj, rtol=1e-14, atol=1e-14)
    assert not t_div.any()


def test_integrator_flags_and_holds_a_segment_that_leaves_the_envelope():
    """dx/dt = x from 1 and 0.01: the first leaves [-5, 5] near t = ln 5 and is held at its last inside value;
    the second stays inside and follows RK4's growth factor."""
    h, n = 0.1, 40
    traj, div = integrate(lambda x, u: x, np.array([[1.0], [0.01]]), np.zeros((2, n, 0)), np.full((2, n - 1), h),
                          [n, n], np.array([-5.0]), np.array([5.0]))
    np.testing.assert_array_equal(div, [True, False])
    first_out = int(np.argmax(np.exp(np.arange(n) * h) > 5.0))
    assert np.all(traj[0, first_out - 1:, 0] == traj[0, first_out - 1, 0]) and traj[0, -1, 0] <= 5.0
    growth = 1 + h + h**2 / 2 + h**3 / 6 + h**4 / 24  # one RK4 step of dx/dt = x, exactly
    np.testing.assert_allclose(traj[1, :, 0], 0.01 * growth ** np.arange(n), rtol=1e-12)


def test_hold_after_exit_keeps_the_valid_prefix_in_numpy_and_torch():
    part = np.array([[[1.0], [2.0], [9.0], [3.0]], [[1.0], [1.5], [2.0], [2.5]], [[np.nan], [1.0], [1.0], [1.0]]])
    start, alive = np.array([[0.5], [0.5], [0.7]]), np.array([True, False, True])
    got, still = hold_after_exit(part, start, alive, np.array([-5.0]), np.array([5.0]))
    np.testing.assert_array_equal(got[:, :, 0], [[1, 2, 2, 2], [0.5, 0.5, 0.5, 0.5], [0.7, 0.7, 0.7, 0.7]])
    np.testing.assert_array_equal(still, [False, False, False])
    t_got, t_still = hold_after_exit(torch.as_tensor(part), torch.as_tensor(start), torch.as_tensor(alive),
                                     torch.tensor([-5.0], dtype=torch.float64), torch.tensor([5.0], dtype=torch.float64))
    np.testing.assert_array_equal(t_got.numpy(), got)
    np.testing.assert_array_equal(t_still.numpy(), still)


def test_device_resolver_names_the_caller():
    assert resolve_device("cpu", "method 'x'").type == "cpu"
    assert resolve_device("auto", "method 'x'").type in ("cpu", "cuda")
    with pytest.raises(MethodError, match=r"^method 'x': device 'tpu' is not supported|^method 'x': unknown device"):
        resolve_device("tpu", "method 'x'")
    with pytest.raises(MethodError, match=r"^method 'x': device must be a string"):
        resolve_device(0, "method 'x'")
    if not torch.cuda.is_available():
        with pytest.raises(MethodError, match=r"^method 'x': device 'cuda' requested but CUDA is not available"):
            resolve_device("cuda", "method 'x'")
