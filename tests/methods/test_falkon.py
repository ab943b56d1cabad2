"""FALKON (Nystroem + preconditioned CG): agreement with exact KRLS, the direct Nystroem
solve and scikit-learn; streaming, determinism, multi-target and lambda-path equivalences;
error messages."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import torch
from sklearn.kernel_ridge import KernelRidge
from sklearn.metrics.pairwise import rbf_kernel
from threadpoolctl import threadpool_limits

from enginebench.errors import MethodError
from enginebench.methods.numerics.falkon import FalkonSolver, conjugate_gradient, falkon_path


@pytest.fixture(autouse=True)
def one_thread():
    """The test machine's cores are shared: one BLAS/torch thread avoids oversubscription stalls."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    with threadpool_limits(1):
        yield
    torch.set_num_threads(before)


def smooth_problem(n: int, d: int, rng: np.random.Generator, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
    X = rng.uniform(-2, 2, size=(n, d))
    cols = [np.sin(X[:, 0]) + 0.5 * X[:, 1] * X[:, 2 % d] + np.cos(X[:, 3 % d] + X[:, 4 % d]),
            np.tanh(X @ np.linspace(-1, 1, d)), X[:, 0] ** 2 / 4]
    y = np.stack(cols[:k], axis=1) + 0.1 * rng.normal(size=(n, k))
    return X, y


def rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize("gamma, lam", [(0.5, 1e-2), (2.0, 1e-3), (0.1, 1.0)])
def test_all_rows_as_centres_is_exact_krls(gamma, lam):
    rng = np.random.default_rng(0)
    X, y = smooth_problem(300, 3, rng, k=2)
    X_eval = rng.uniform(-2, 2, size=(80, 3))
    exact = KernelRidge(kernel="rbf", gamma=gamma, alpha=lam).fit(X, y).predict(X_eval)
    solver = FalkonSolver(gamma, lam, centres=10_000, device="cpu").fit(X, y, np.random.default_rng(1))
    assert solver.info["centres"] == 300  # clipped to n
    assert rel_err(solver.predict(X_eval), exact) < 1e-6
    # with m = n the preconditioner is the system itself: CG needs very few iterations
    assert solver.info["iterations"] <= 3 and solver.info["converged"]


def test_matches_direct_solve_of_the_nystroem_system():
    rng = np.random.default_rng(2)
    X, y = smooth_problem(600, 4, rng, k=2)
    X_eval = rng.uniform(-2, 2, size=(50, 4))
    gamma, lam = 0.3, 10.0
    solver = FalkonSolver(gamma, lam, centres=60, maxiter=200, tol=1e-11, device="cpu")
    solver.fit(X, y, np.random.default_rng(3))
    C = X[solver.centre_rows_]
    assert np.array_equal(C, solver.centres_)
    Knm, Kmm = rbf_kernel(X, C, gamma=gamma), rbf_kernel(C, C, gamma=gamma)
    beta = scipy.linalg.solve(Knm.T @ Knm + lam * Kmm, Knm.T @ y, assume_a="pos")
    assert solver.info["converged"] and solver.info["iterations"] < 60
    assert rel_err(solver.predict(X_eval), rbf_kernel(X_eval, C, gamma=gamma) @ beta) < 1e-6


def test_mae_within_two_percent_of_exact_kernel_ridge():
    rng = np.random.default_rng(5)
    X, y = smooth_problem(3000, 5, rng)
    X_test, y_test = smooth_problem(1000, 5, rng)
    gamma, lam = 0.1, 1e-2
    mae_exact = np.abs(KernelRidge(kernel="rbf", gamma=gamma, alpha=lam).fit(X, y).predict(X_test) - y_test).mean()
    mae = {}
    for m in (500, 20):
        solver = FalkonSolver(gamma, lam, centres=m, device="cpu").fit(X, y, np.random.default_rng(1))
        mae[m] = np.abs(solver.predict(X_test) - y_test).mean()
    assert abs(mae[500] / mae_exact - 1) < 0.02
    assert mae[20] > 1.5 * mae_exact  # the check discriminates: too few centres fail it


def test_streamed_blocks_equal_one_block_and_the_cache():
    rng = np.random.default_rng(7)
    X, y = smooth_problem(500, 3, rng, k=2)
    X_eval = rng.uniform(-2, 2, size=(70, 3))
    # tight tolerance: finite-precision CG turns rounding-level differences of the summation
    # order into differences of the size of the current residual, so compare converged solves
    kw = dict(gamma=0.5, lam=0.1, centres=80, device="cpu", tol=1e-12, maxiter=300)
    one = FalkonSolver(**kw, cache_mib=0).fit(X, y, np.random.default_rng(4))
    tiny = FalkonSolver(**kw, cache_mib=0, block_rows=37).fit(X, y, np.random.default_rng(4))
    cached = FalkonSolver(**kw, block_rows=37).fit(X, y, np.random.default_rng(4))
    assert (one.info["blocks"], one.info["cached"]) == (1, False)
    assert (tiny.info["blocks"], tiny.info["block_rows"], tiny.info["cached"]) == (14, 37, False)
    assert cached.info["cached"]
    assert one.info["converged"] and one.info["residual"] <= 1e-12
    ref = one.predict(X_eval)
    for other in (tiny, cached):
        assert other.info["converged"]
        assert rel_err(other.predict(X_eval), ref) < 1e-10


def test_float32_blocks_stay_close_to_float64():
    rng = np.random.default_rng(8)
    X, y = smooth_problem(800, 4, rng)
    X_eval = rng.uniform(-2, 2, size=(60, 4))
    kw = dict(gamma=0.2, lam=1.0, centres=100, device="cpu", block_rows=128, cache_mib=0)
    p64 = FalkonSolver(**kw).fit(X, y, np.random.default_rng(0)).predict(X_eval)
    f32 = FalkonSolver(**kw, dtype=torch.float32).fit(X, y, np.random.default_rng(0))
    assert f32.info["dtype"] == "float32"
    assert 0 < rel_err(f32.predict(X_eval), p64) < 1e-3


def test_deterministic_given_the_rng():
    rng = np.random.default_rng(9)
    X, y = smooth_problem(400, 3, rng)
    kw = dict(gamma=0.5, lam=0.1, centres=50, device="cpu")
    a = FalkonSolver(**kw).fit(X, y, np.random.default_rng(11))
    b = FalkonSolver(**kw).fit(X, y, np.random.default_rng(11))
    c = FalkonSolver(**kw).fit(X, y, np.random.default_rng(12))
    assert np.array_equal(a.centre_rows_, b.centre_rows_) and np.array_equal(a.coef_, b.coef_)
    assert np.array_equal(a.predict(X[:20]), b.predict(X[:20]))
    assert not np.array_equal(a.centre_rows_, c.centre_rows_)
    assert len(np.unique(a.centre_rows_)) == 50  # drawn without replacement


def test_targets_are_solved_independently_and_1d_targets_stay_1d():
    rng = np.random.default_rng(10)
    X, y = smooth_problem(400, 3, rng, k=3)
    kw = dict(gamma=0.5, lam=0.1, centres=60, device="cpu", maxiter=300, tol=1e-12)
    joint = FalkonSolver(**kw).fit(X, y, np.random.default_rng(2))
    assert joint.predict(X[:30]).shape == (30, 3)
    for j in range(3):
        single = FalkonSolver(**kw).fit(X, y[:, j], np.random.default_rng(2))
        pred = single.predict(X[:30])
        assert pred.shape == (30,)
        assert rel_err(joint.predict(X[:30])[:, j], pred) < 1e-10
    assert len(joint.info["residuals"]) == 3


def test_path_equals_one_solver_per_lambda():
    rng = np.random.default_rng(12)
    X, y = smooth_problem(500, 3, rng, k=2)
    X_eval = rng.uniform(-2, 2, size=(40, 3))
    lambdas = [1e-2, 1.0, 100.0]
    kw = dict(device="cpu", tol=1e-12, maxiter=300)
    pred, info = falkon_path(X, y, X_eval, 0.5, lambdas, 70, np.random.default_rng(6), **kw)
    assert pred.shape == (3, 40, 2) and all(info["converged"])
    for i, lam in enumerate(lambdas):
        single = FalkonSolver(0.5, lam, centres=70, **kw).fit(X, y, np.random.default_rng(6))
        assert rel_err(pred[i], single.predict(X_eval)) < 1e-10


def test_conjugate_gradient_solves_each_column_of_an_spd_system():
    rng = np.random.default_rng(13)
    A = rng.normal(size=(40, 40))
    W = torch.as_tensor(A @ A.T + 40 * np.eye(40))
    b = torch.as_tensor(rng.normal(size=(40, 3)))
    b[:, 2] = 0.0  # a zero right-hand side converges at once to zero
    x, info = conjugate_gradient(lambda v: W @ v, b, maxiter=100, tol=1e-12)
    np.testing.assert_allclose(x.numpy(), np.linalg.solve(W.numpy(), b.numpy()), rtol=1e-9, atol=1e-12)
    assert info["residuals"].max() <= 1e-12 and info["iterations"] <= 40
    assert np.all(x.numpy()[:, 2] == 0.0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(gamma=0.0, lam=1.0), "parameter 'gamma' must be a positive finite number, got 0.0"),
    (dict(gamma=1.0, lam=-1.0), "parameter 'lam' must be a positive finite number, got -1.0"),
    (dict(gamma=1.0, lam=1.0, centres=0), "parameter 'centres' must be an integer >= 1, got 0"),
    (dict(gamma=1.0, lam=1.0, block_rows=2.5), "parameter 'block_rows' must be an integer >= 1, got 2.5"),
    (dict(gamma=1.0, lam=1.0, dtype=torch.float16), "dtype must be torch.float32 or torch.float64"),
    (dict(gamma=1.0, lam=1.0, device="tpu"), "device 'tpu'"),
    (dict(gamma=1.0, lam=1.0, tol=-1e-3), "parameter 'tol' must be a finite number >= 0"),
])
def test_bad_parameters_are_named(kwargs, message):
    with pytest.raises(MethodError, match=message.replace("(", r"\(").replace(".", r"\.")):
        FalkonSolver(**kwargs)


@pytest.mark.parametrize("settings, message", [
    (dict(maxiter=0), "parameter 'maxiter' must be an integer >= 1, got 0"),
    (dict(block_rows=2.5), "parameter 'block_rows' must be an integer >= 1, got 2.5"),
    (dict(dtype=torch.float16), "dtype must be torch.float32 or torch.float64"),
    (dict(tol=-1e-3), "parameter 'tol' must be a finite number >= 0"),
    (dict(cache_mib=-1.0), "parameter 'cache_mib' must be a finite number >= 0 (0 = always stream)"),
    (dict(block_mib=0.0), "parameter 'block_mib' must be a positive finite number, got 0.0"),
])
def test_solver_and_path_check_their_shared_settings_alike(settings, message):
    """FalkonSolver and falkon_path take the same SolverSettings keywords and refuse them with the same message."""
    X, y = smooth_problem(20, 2, np.random.default_rng(0))
    pattern = message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")
    with pytest.raises(MethodError, match=pattern):
        FalkonSolver(1.0, 1.0, device="cpu", **settings)
    with pytest.raises(MethodError, match=pattern):
        falkon_path(X, y, X, 1.0, [1.0], 5, np.random.default_rng(0), device="cpu", **settings)


def test_an_unknown_setting_is_refused():
    with pytest.raises(TypeError, match="unknown"):
        FalkonSolver(1.0, 1.0, unknown=1)
    with pytest.raises(TypeError, match="unknown"):
        falkon_path(np.ones((4, 1)), np.ones(4), np.ones((4, 1)), 1.0, [1.0], 2, np.random.default_rng(0), unknown=1)


def test_unavailable_cuda_is_a_readable_error():
    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    with pytest.raises(MethodError, match="CUDA is not available; use device='auto' or 'cpu'"):
        FalkonSolver(1.0, 1.0, device="cuda")


def test_bad_data_are_named():
    rng = np.random.default_rng(14)
    X, y = smooth_problem(50, 3, rng)
    solver = FalkonSolver(0.5, 0.1, centres=10, device="cpu")
    with pytest.raises(MethodError, match="predict called before fit"):
        solver.predict(X)
    with pytest.raises(MethodError, match=r"targets y have shape \(49, 1\) but the features have 50 rows"):
        solver.fit(X, y[:49], np.random.default_rng(0))
    Xbad = X.copy()
    Xbad[7, 2] = np.nan
    with pytest.raises(MethodError, match="training features X contain nan/inf at row 7, column 2"):
        solver.fit(Xbad, y, np.random.default_rng(0))
    with pytest.raises(MethodError, match="rng must be a numpy.random.Generator"):
        solver.fit(X, y, 0)
    solver.fit(X, y, np.random.default_rng(0))
    with pytest.raises(MethodError, match="have 2 feature columns but the model was fitted on 3"):
        solver.predict(X[:, :2])


def test_default_stopping_rule_saves_passes_without_changing_predictions():
    """CG stopped at the default relative residual (1e-5) predicts like a solve to 1e-12, in fewer passes."""
    rng = np.random.default_rng(21)
    X, y = smooth_problem(4000, 5, rng)
    X_eval = rng.uniform(-2, 2, size=(300, 5))
    kw = dict(gamma=0.3, lam=1e-4 * 4000, centres=200, device="cpu", maxiter=300)
    default = FalkonSolver(**kw).fit(X, y, np.random.default_rng(4))
    tight = FalkonSolver(**kw, tol=1e-12).fit(X, y, np.random.default_rng(4))
    assert default.info["converged"] and default.info["residual"] <= 1e-5
    assert default.info["passes"] < tight.info["passes"]
    assert rel_err(default.predict(X_eval), tight.predict(X_eval)) < 1e-3
    # float32 kernel blocks (the benchmark's setting) with the same rule stay as close
    f32 = FalkonSolver(**kw, dtype=torch.float32).fit(X, y, np.random.default_rng(4))
    assert rel_err(f32.predict(X_eval), tight.predict(X_eval)) < 1e-3
