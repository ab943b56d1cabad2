"""Exact KRLS: agreement with scikit-learn's KernelRidge, the whole grid from one
eigendecomposition per gamma, and numerical robustness."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from sklearn.kernel_ridge import KernelRidge
from sklearn.preprocessing import StandardScaler

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import grid_points
from enginebench.methods.krls import KRLS
from enginebench.methods.numerics.kernels import Spectral, gaussian, sq_distances

RNG = np.random.default_rng(0)


def _dataset(seed: int, sizes: tuple[int, ...] = (70, 50), offset: float = 0.0) -> Dataset:
    """Two segments of a smooth 3-input, 2-output engine-like map, on purposely unequal scales."""
    rng = np.random.default_rng(seed)
    n = sum(sizes)
    x1 = rng.uniform(400, 1000, n) + offset  # speed-like, large scale
    x2 = rng.uniform(0, 1, n)  # load-like
    x3 = rng.normal(15, 3, n)  # temperature-like
    y1 = 300 + 0.2 * x1 + 150 * x2**2 + 2 * np.sin(x3) + rng.normal(0, 0.5, n)
    y2 = 50 * np.tanh(x2 - 0.5) + 0.01 * x1 * x2
    frame = pd.DataFrame({
        "segment": np.repeat([f"s{i}" for i in range(len(sizes))], sizes),
        "time": np.concatenate([np.arange(k, dtype=float) for k in sizes]),
        "x1": x1, "x2": x2, "x3": x3, "y1": y1, "y2": y2,
    })
    schema = Schema.from_roles({"x1": "input", "x2": "input", "x3": "input", "y1": "output", "y2": "output"})
    return Dataset(name="synthetic", frame=frame, schema=schema, dt=1.0)


TRAIN = make_samples(_dataset(1), ["y1", "y2"])
TEST = make_samples(_dataset(2, sizes=(30, 25)), ["y1", "y2"]).without_targets()
TRAIN_1 = make_samples(_dataset(1), ["y1"])


def _kr(X: np.ndarray, y: np.ndarray, Xe: np.ndarray, gamma: float, lam: float) -> np.ndarray:
    return KernelRidge(kernel="rbf", gamma=gamma, alpha=lam).fit(X, y).predict(Xe)


def _fit_predict(method: KRLS, train, test, gamma: float, lam: float) -> np.ndarray:
    fitted = method.fit(train, {"gamma": gamma, "lambda": lam}, RNG)
    parts = method.predict(fitted, test)
    assert [p.shape for p in parts] == [(len(s), len(train.target_names)) for s in test.segments]
    return np.concatenate(parts)


# Standardised features: gamma acts on unit-variance inputs.
PAIRS = [(0.1, 1.0), (1.0, 0.1), (0.5, 1e-2), (3.0, 10.0), (0.05, 1e-4), (1.0, 1e-4)]


@pytest.mark.parametrize("gamma,lam", PAIRS)
def test_matches_kernel_ridge_raw(gamma: float, lam: float) -> None:
    """No standardising, no centring: exactly sklearn's KernelRidge on the raw arrays."""
    train = make_samples(_dataset(1), ["y1", "y2"])
    # raw features must be on a kernel-friendly scale for this comparison
    scaler = StandardScaler().fit(train.X)
    X, Xe = scaler.transform(train.X), scaler.transform(TEST.X)
    tr = replace(train, segments=tuple(replace(s, X=scaler.transform(s.X)) for s in train.segments))
    te = replace(TEST, segments=tuple(replace(s, X=scaler.transform(s.X)) for s in TEST.segments))
    ours = _fit_predict(KRLS(standardize=False, center_target=False), tr, te, gamma, lam)
    ref = _kr(X, train.y, Xe, gamma, lam)
    _assert_close(ours, ref, train.y, lam)


@pytest.mark.parametrize("gamma,lam", PAIRS)
def test_matches_kernel_ridge_standardised_centred(gamma: float, lam: float) -> None:
    """Defaults: sklearn StandardScaler + KernelRidge on y - mean(y), plus mean(y)."""
    scaler = StandardScaler().fit(TRAIN.X)
    y = TRAIN.y
    ref = _kr(scaler.transform(TRAIN.X), y - y.mean(0), scaler.transform(TEST.X), gamma, lam) + y.mean(0)
    ours = _fit_predict(KRLS(), TRAIN, TEST, gamma, lam)
    _assert_close(ours, ref, y, lam)


def _assert_close(ours: np.ndarray, ref: np.ndarray, y: np.ndarray, lam: float) -> None:
    assert ours.shape == ref.shape
    if lam >= 1e-2:  # well conditioned: agreement to rounding
        np.testing.assert_allclose(ours, ref, rtol=1e-8, atol=1e-9 * np.abs(y).max())
    else:  # cond(K + lam I) up to ~1e6: agree relative to the target scale
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9 * np.abs(y).max())


def test_single_target_and_describe() -> None:
    m = KRLS()
    fitted = m.fit(TRAIN_1, {"gamma": 0.3, "lambda": 0.1}, RNG)
    assert m.describe(fitted) == {"gamma": 0.3, "lambda": 0.1, "solver": "exact", "n_train": len(TRAIN_1)}
    pred = np.concatenate(m.predict(fitted, TEST))
    assert pred.shape == (len(TEST), 1)
    # the first column of a two-target fit is the same model
    both = _fit_predict(m, TRAIN, TEST, 0.3, 0.1)
    np.testing.assert_allclose(pred[:, 0], both[:, 0], rtol=1e-10)


def test_centring_reverts_to_training_mean_far_from_data() -> None:
    """Far from every training point K = 0: the centred model predicts mean(y), the raw one 0."""
    far = make_samples(_dataset(3, offset=1e5), ["y1", "y2"]).without_targets()
    centred = _fit_predict(KRLS(), TRAIN, far, 1.0, 0.1)
    raw = _fit_predict(KRLS(center_target=False), TRAIN, far, 1.0, 0.1)
    np.testing.assert_allclose(centred, np.broadcast_to(TRAIN.y.mean(0), centred.shape), rtol=1e-12)
    np.testing.assert_allclose(raw, 0.0, atol=1e-12)


def test_interpolates_training_data_at_tiny_lambda() -> None:
    """At lambda -> 0 the exact solution reproduces training targets (distinct points, moderate gamma)."""
    m = KRLS()
    fitted = m.fit(TRAIN, {"gamma": 2.0, "lambda": 1e-4}, RNG)
    pred = np.concatenate(m.predict(fitted, TRAIN.without_targets()))
    resid = np.abs(pred - TRAIN.y).max(axis=0) / np.abs(TRAIN.y - TRAIN.y.mean(0)).max(axis=0)
    assert (resid < 1e-2).all()


def test_predict_grid_equals_pointwise_fits_in_grid_order() -> None:
    m = KRLS()
    space = {"gamma": np.array([0.05, 0.5, 5.0]), "lambda": np.array([1e-4, 1e-2, 1.0, 100.0])}
    grid = grid_points(space)
    grid = [grid[i] for i in np.random.default_rng(5).permutation(len(grid))]  # order must be kept
    out = m.predict_grid(TRAIN, TEST, grid, RNG)
    assert out.shape == (12, len(TEST), 2)
    y_scale = np.abs(TRAIN.y).max()
    for k, p in enumerate(grid):
        single = _fit_predict(m, TRAIN, TEST, p["gamma"], p["lambda"])
        np.testing.assert_allclose(out[k], single, rtol=1e-9, atol=1e-9 * y_scale, err_msg=str(p))


def test_predict_grid_without_standardising_or_centring_and_empty_grid() -> None:
    m = KRLS(standardize=False, center_target=False)
    grid = [{"gamma": 1e-5, "lambda": 0.3}, {"gamma": 1e-4, "lambda": 3.0}, {"gamma": 1e-5, "lambda": 3.0}]
    out = m.predict_grid(TRAIN_1, TEST, grid, RNG)
    for k, p in enumerate(grid):
        ref = _kr(TRAIN_1.X, TRAIN_1.y, TEST.X, p["gamma"], p["lambda"])
        np.testing.assert_allclose(out[k], ref, rtol=1e-7, atol=1e-7 * np.abs(TRAIN_1.y).max())
    assert m.predict_grid(TRAIN_1, TEST, [], RNG).shape == (0, len(TEST), 1)


def test_duplicate_rows_and_tiny_lambda_stay_finite() -> None:
    """Repeated rows make the kernel matrix exactly singular; lambda = 1e-4 must still solve."""
    idx = np.r_[np.arange(len(TRAIN)), np.arange(len(TRAIN)), np.zeros(10, dtype=int)]
    dup = TRAIN.take(idx)
    m = KRLS()
    grid = [{"gamma": g, "lambda": 1e-4} for g in (1e-4, 1e-2, 1.0, 1e2, 1e4)]
    out = m.predict_grid(dup, TEST, grid, RNG)
    assert np.isfinite(out).all()
    fitted = m.fit(dup, grid[2], RNG)
    assert np.isfinite(fitted.alpha).all()
    scaler = StandardScaler().fit(dup.X)
    y = dup.y
    ref = _kr(scaler.transform(dup.X), y - y.mean(0), scaler.transform(TEST.X), 1.0, 1e-4) + y.mean(0)
    np.testing.assert_allclose(out[2], ref, rtol=0, atol=1e-9 * np.abs(y).max())


def test_search_space_is_the_design_grid() -> None:
    space = KRLS().search_space(TRAIN)
    assert list(space) == ["gamma", "lambda"]
    for values in space.values():
        assert values.size == 41
        np.testing.assert_allclose(np.log10(values), np.linspace(-4, 4, 41), atol=1e-12)
    small = KRLS(gamma_grid=(-1, 1, 3), lambda_grid=[0, 2, 2]).search_space(TRAIN)
    np.testing.assert_allclose(small["gamma"], [0.1, 1.0, 10.0])
    np.testing.assert_allclose(small["lambda"], [1.0, 100.0])


def test_spectral_solves_every_lambda_at_once() -> None:
    X = np.random.default_rng(7).normal(size=(40, 3))
    y = np.random.default_rng(8).normal(size=(40, 2))
    Q = gaussian(sq_distances(X), 0.7)
    sp = Spectral.from_kernel(Q)
    np.testing.assert_allclose(sp.V @ np.diag(sp.s) @ sp.V.T, Q, atol=1e-12)
    np.testing.assert_allclose(sp.lift(sp.project(y)), y, atol=1e-12)
    lambdas = np.array([1e-3, 0.1, 10.0])
    alpha = sp.ridge_alpha(y, lambdas)
    assert alpha.shape == (40, 3, 2)
    for j, lam in enumerate(lambdas):
        np.testing.assert_allclose(alpha[:, j], np.linalg.solve(Q + lam * np.eye(40), y), rtol=1e-8, atol=1e-10)
    Ke = gaussian(sq_distances(X[:5] + 0.1, X), 0.7)
    pred = sp.ridge_predict(Ke, y, lambdas)
    assert pred.shape == (3, 5, 2)
    np.testing.assert_allclose(pred, np.einsum("mn,nlk->lmk", Ke, alpha), rtol=1e-9, atol=1e-12)


def test_sq_distances_and_gaussian_kernel() -> None:
    A = np.array([[0.0, 0.0], [1.0, 2.0]])
    B = np.array([[1.0, 0.0], [1.0, 2.0], [3.0, 4.0]])
    D = sq_distances(A, B)
    np.testing.assert_allclose(D, [[1, 5, 25], [4, 0, 8]], atol=1e-12)
    np.testing.assert_allclose(gaussian(D, 0.5), np.exp(-0.5 * np.array([[1, 5, 25], [4, 0, 8]])), atol=1e-15)
    assert (np.diag(sq_distances(B)) == 0).all()


def test_sq_distances_match_scikit_learn_bit_for_bit() -> None:
    """Our distances keep scikit-learn's arithmetic (the previous implementation) exactly."""
    from sklearn.metrics.pairwise import euclidean_distances

    rng = np.random.default_rng(3)
    for d in (1, 5, 60):
        A, B = rng.normal(size=(90, d)) * 4, rng.normal(size=(35, d)) + 1
        assert np.array_equal(sq_distances(A, B), euclidean_distances(A, B, squared=True))
        assert np.array_equal(sq_distances(A), euclidean_distances(A, squared=True))
    with pytest.raises(MethodError, match="expected"):
        sq_distances(A, B[:, :2])


@pytest.mark.parametrize("rows, block", [(700, 256), (256, 256), (5, 256), (0, 256), (301, 7)])
def test_gaussian_apply_equals_the_whole_kernel_matrix(rows: int, block: int) -> None:
    """The blocked kernel product equals K(X, X_train) @ coef formed whole, 2-D and 1-D coefficients."""
    from enginebench.methods.numerics.kernels import gaussian_apply

    rng = np.random.default_rng(rows)
    X, Xt = rng.normal(size=(rows, 6)), rng.normal(size=(120, 6))
    coef = rng.normal(size=(120, 2))
    ref = gaussian(sq_distances(X, Xt), 0.4) @ coef
    got = gaussian_apply(X, Xt, 0.4, coef, block_rows=block)
    assert got.shape == (rows, 2)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-14)
    got1 = gaussian_apply(X, Xt, 0.4, coef[:, 0], block_rows=block)
    assert got1.shape == (rows,)
    np.testing.assert_allclose(got1, ref[:, 0], rtol=1e-12, atol=1e-14)


def test_spectral_rejects_non_psd_matrix() -> None:
    with pytest.raises(MethodError, match="not positive semi-definite"):
        Spectral.from_kernel(np.array([[1.0, 2.0], [2.0, 1.0]]))


@pytest.mark.parametrize(
    "params,message",
    [
        ({"gamma": 1.0}, "hyperparameter\\(s\\) lambda missing"),
        ({"gamma": 0.0, "lambda": 1.0}, "'gamma' must be a positive finite number, got 0.0"),
        ({"gamma": 1.0, "lambda": -1.0}, "'lambda' must be a positive finite number, got -1.0"),
        ({"gamma": 1.0, "lambda": float("nan")}, "'lambda' must be a positive finite number"),
        ({"gamma": 1.0, "lambda": 1.0, "theta": 2}, "unknown hyperparameter\\(s\\) theta"),
    ],
)
def test_bad_hyperparameters(params: dict, message: str) -> None:
    with pytest.raises(MethodError, match=message):
        KRLS().fit(TRAIN, params, RNG)
    with pytest.raises(MethodError, match=message):
        KRLS().predict_grid(TRAIN, TEST, [{"gamma": 1.0, "lambda": 1.0}, params], RNG)


def test_bad_options_and_inputs() -> None:
    with pytest.raises(MethodError, match="unknown option\\(s\\) bandwidth"):
        KRLS(bandwidth=2)
    with pytest.raises(MethodError, match="option gamma_grid=\\(-4, 4\\) must be"):
        KRLS(gamma_grid=(-4, 4))
    fitted = KRLS().fit(TRAIN, {"gamma": 1.0, "lambda": 1.0}, RNG)
    window = make_samples(_dataset(2), ["y1"], mode="window", window=2.0).without_targets()
    with pytest.raises(MethodError, match="data have 11 feature columns but the model was trained on 3"):
        KRLS().predict(fitted, window)
    ds = _dataset(1)
    frame = ds.frame.copy()
    frame.loc[5, "x2"] = np.nan
    bad = make_samples(ds.with_frame(frame), ["y1"])
    with pytest.raises(MethodError, match="column 'x2', stacked row 5"):
        KRLS().fit(bad, {"gamma": 1.0, "lambda": 1.0}, RNG)


def test_window_mode_fits_and_is_deterministic() -> None:
    train = make_samples(_dataset(1), ["y1"], mode="window", window=2.0)
    test = make_samples(_dataset(2), ["y1"], mode="window", window=2.0).without_targets()
    m = KRLS()
    a = np.concatenate(m.predict(m.fit(train, {"gamma": 0.1, "lambda": 0.1}, np.random.default_rng(1)), test))
    b = np.concatenate(m.predict(m.fit(train, {"gamma": 0.1, "lambda": 0.1}, np.random.default_rng(2)), test))
    assert a.shape == (len(test), 1) and np.isfinite(a).all()
    np.testing.assert_array_equal(a, b)


def test_constant_feature_is_harmless() -> None:
    """A constant input (std 0 -> scale 1) adds nothing to any distance: same predictions, no nan."""
    def with_constant(samples):
        segs = tuple(replace(s, X=np.hstack([s.X, np.full((len(s), 1), 7.0)])) for s in samples.segments)
        return replace(samples, segments=segs, feature_names=samples.feature_names + ("const",))

    m = KRLS()
    base = _fit_predict(m, TRAIN, TEST, 0.5, 1e-2)
    const = _fit_predict(m, with_constant(TRAIN), with_constant(TEST), 0.5, 1e-2)
    assert np.isfinite(const).all()
    np.testing.assert_allclose(const, base, rtol=1e-12, atol=1e-12 * np.abs(TRAIN.y).max())


def test_spectral_rejects_non_finite_matrix() -> None:
    with pytest.raises(MethodError, match="kernel matrix has nan/inf entries"):
        Spectral.from_kernel(np.array([[1.0, np.nan], [np.nan, 1.0]]))


def _smooth_problem(n: int, seed: int = 0):
    import pandas as pd

    from enginebench.datasets.dataset import Dataset
    from enginebench.datasets.pools import make_samples
    from enginebench.datasets.schema import Column, Schema

    rng = np.random.default_rng(seed)
    X = rng.uniform(-2, 2, (n, 4))
    y = np.sin(X[:, 0]) + 0.5 * X[:, 1] ** 2 - X[:, 2] + rng.normal(0, 0.1, n)
    frame = pd.DataFrame(X, columns=["a", "b", "c", "d"])
    frame.insert(0, "time", np.arange(n, dtype=float))
    frame.insert(0, "segment", "s")
    frame["y"] = y
    schema = Schema(tuple(Column(c, "input") for c in "abcd") + (Column("y", "output"),))
    return make_samples(Dataset("smooth", frame, schema, 1.0), ["y"])


def test_falkon_solver_is_within_two_percent_of_exact_where_exact_is_feasible():
    samples = _smooth_problem(4000)
    train, test = samples.take(np.arange(3000)), samples.take(np.arange(3000, 4000))
    params = {"gamma": 0.2, "lambda": 0.1}
    rng = np.random.default_rng(0)
    maes = {}
    for solver in ("exact", "falkon"):
        m = KRLS(solver=solver, centres=500)
        fitted = m.fit(train, params, rng)
        maes[solver] = np.mean(np.abs(np.concatenate(m.predict(fitted, test.without_targets())) - test.y))
        assert m.describe(fitted)["solver"] == solver
    assert abs(maes["falkon"] - maes["exact"]) <= 0.02 * maes["exact"]


def test_auto_solver_switches_above_the_row_threshold_and_grid_matches_fits():
    samples = _smooth_problem(700)
    train, test = samples.take(np.arange(500)), samples.take(np.arange(500, 700))
    m = KRLS(solver="auto", exact_max_rows=400, centres=500)
    assert m.uses_falkon(500) and not KRLS(exact_max_rows=600).uses_falkon(500)
    grid = [{"gamma": 0.2, "lambda": 0.1}, {"gamma": 0.2, "lambda": 1.0}]
    block = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(1))
    exact = KRLS(solver="exact").predict_grid(train, test.without_targets(), grid, np.random.default_rng(1))
    # with every row a centre FALKON solves the exact problem
    np.testing.assert_allclose(block, exact, rtol=1e-4, atol=1e-4)


def test_unknown_solver_is_refused():
    with pytest.raises(MethodError, match="solver must be one of auto, exact, falkon, got 'magic'"):
        KRLS(solver="magic")


def test_eigendecomposition_falls_back_when_divide_and_conquer_fails(monkeypatch):
    """syevd occasionally fails on nearly singular kernel matrices (seen on real data)."""
    import scipy.linalg

    from enginebench.methods.numerics.kernels import Spectral

    real = scipy.linalg.eigh
    calls = []

    def flaky(a, *args, driver=None, **kw):
        calls.append(driver)
        if driver == "evd":
            raise np.linalg.LinAlgError("The leading minor of order 5 of B is not positive definite.")
        return real(a, *args, driver=driver, **kw)

    monkeypatch.setattr(scipy.linalg, "eigh", flaky)
    rng = np.random.default_rng(0)
    A = rng.normal(size=(20, 3))
    Q = A @ A.T
    spectral = Spectral.from_kernel(Q.copy(), overwrite=True)
    assert calls == ["evd", "evr"]
    np.testing.assert_allclose(spectral.V @ np.diag(spectral.s) @ spectral.V.T, Q, atol=1e-10)


# -- the eigendecomposition-free ridge path (Lanczos / Cholesky / Householder) -------------

def _drift_problem(n: int, d: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Inputs with a slow drift and a smooth target, like the benchmark's (blocked folds extrapolate)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / n
    X = rng.normal(size=(n, d)) + 0.5 * np.sin(2 * np.pi * np.outer(t, np.arange(1, d + 1)))
    y = np.sin(X @ rng.normal(size=d) / np.sqrt(d)) + 0.3 * X[:, 0] * X[:, 1] + 0.1 * rng.normal(size=n)
    return X, y


@pytest.mark.parametrize("gamma", [1e-4, 1e-2, 0.1, 1.0, 30.0])
def test_ridge_routes_agree_with_the_eigendecomposition(gamma: float) -> None:
    from enginebench.methods.numerics.shifted import cholesky_ridge, householder_ridge, lanczos_ridge, ridge_solutions

    X, y = _drift_problem(300, 5, 3)
    K = gaussian(sq_distances(X[:240]), gamma)
    Ke = gaussian(sq_distances(X[240:], X[:240]), gamma)
    B = np.stack([y[:240] - y[:240].mean(), np.cos(X[:240, 2])], axis=1)
    lambdas = np.logspace(-4, 4, 41)
    ref = Spectral.from_kernel(K).ridge_predict(Ke, B, lambdas)
    scale = np.abs(B).max()

    def predictions(alpha: np.ndarray) -> np.ndarray:
        return np.einsum("mn,nlk->lmk", Ke, alpha)

    np.testing.assert_allclose(predictions(householder_ridge(K, B, lambdas)), ref, rtol=0, atol=1e-8 * scale)
    chol = cholesky_ridge(K, B, lambdas[:3])
    np.testing.assert_allclose(predictions(chol), ref[:3], rtol=0, atol=1e-8 * scale)
    X0, ok, steps = lanczos_ridge(K, B[:, 0], lambdas, maxiter=240)
    assert 1 <= steps <= 240
    # a certified lambda is as good as the direct solvers; an uncertified one is not returned by ridge_solutions
    np.testing.assert_allclose((Ke @ X0)[:, ok].T, ref[ok, :, 0], rtol=0, atol=1e-8 * scale)
    for budget in (0, 8, None):
        alpha, counts = ridge_solutions(K, B, lambdas, krylov_maxiter=budget)
        assert counts["krylov"] + counts["cholesky"] + counts["householder"] == B.shape[1] * len(lambdas)
        np.testing.assert_allclose(predictions(alpha), ref, rtol=0, atol=1e-8 * scale)
    alpha, _ = ridge_solutions(K.copy(), B, lambdas, overwrite=True)
    np.testing.assert_allclose(predictions(alpha), ref, rtol=0, atol=1e-8 * scale)


def test_ridge_solutions_uses_every_route_on_the_benchmark_grid() -> None:
    """Across the 41-gamma grid all three routes occur, and each lambda is solved exactly once."""
    from enginebench.methods.numerics.shifted import ridge_solutions

    X, y = _drift_problem(400, 8, 0)
    D = sq_distances(X)
    lambdas = np.logspace(-4, 4, 41)
    used = {"krylov": 0, "cholesky": 0, "householder": 0}
    for gamma in np.logspace(-4, 4, 21):
        _, counts = ridge_solutions(gaussian(D, gamma), (y - y.mean())[:, None], lambdas, krylov_maxiter=24)
        for key in used:
            used[key] += counts[key]
    assert all(v > 0 for v in used.values()), used


def test_householder_falls_back_to_the_clipped_spectrum_when_rounding_makes_k_indefinite() -> None:
    from enginebench.methods.numerics.shifted import householder_ridge

    rng = np.random.default_rng(5)
    V, _ = np.linalg.qr(rng.normal(size=(30, 30)))
    s = np.r_[-1e-10, np.logspace(-6, 1, 29)]  # one slightly negative eigenvalue, as rounding leaves
    K = (V * s) @ V.T
    K = 0.5 * (K + K.T)
    b = rng.normal(size=(30, 1))
    lambdas = np.array([1e-12, 1e-3])
    alpha = householder_ridge(K, b, lambdas)
    # lambda 1e-12: K + lambda I is indefinite; the clipped spectral solution (huge, ~1e11) is returned
    np.testing.assert_allclose(alpha[:, 0], Spectral.from_kernel(K).ridge_alpha(b, lambdas[:1])[:, 0], rtol=1e-6)
    # lambda 1e-3: positive definite, the tridiagonal solve equals a direct dense solve
    np.testing.assert_allclose(alpha[:, 1], np.linalg.solve(K + 1e-3 * np.eye(30), b), rtol=1e-10)


def test_grid_matches_kernel_ridge_per_blocked_fold() -> None:
    """predict_grid over a wide 9 x 9 grid equals sklearn's KernelRidge (centred target) on each blocked fold."""
    from enginebench.samples import Samples, SegmentSamples

    X, y = _drift_problem(250, 4, 11)
    names = tuple(f"x{j}" for j in range(X.shape[1]))

    def samples(rows: np.ndarray) -> Samples:
        seg = SegmentSamples(id="all", X=X[rows], rows=rows, U=X[rows], t=rows.astype(float), y=y[rows, None])
        return Samples(segments=(seg,), mode="static", window=0.0, dt=1.0, feature_names=names,
                       input_names=names, target_names=("y",))

    method = KRLS(standardize=False, center_target=True)
    grid = grid_points({"gamma": np.logspace(-4, 4, 9), "lambda": np.logspace(-4, 4, 9)})
    for fold in range(5):
        test = np.arange(fold * 50, fold * 50 + 50)
        train = np.setdiff1d(np.arange(250), test)
        out = method.predict_grid(samples(train), samples(test).without_targets(), grid, RNG)
        mean = y[train].mean()
        for k, p in enumerate(grid):
            ref = _kr(X[train], y[train] - mean, X[test], p["gamma"], p["lambda"]) + mean
            np.testing.assert_allclose(out[k, :, 0], ref, rtol=0, atol=1e-8 * np.abs(y).max(), err_msg=str(p))


@pytest.mark.parametrize("standardize", [True, False])
@pytest.mark.parametrize("extra_cols", [0, 2])
def test_standardize_rows_is_the_scalers_transform_bit_for_bit(standardize: bool, extra_cols: int) -> None:
    """The prediction path's standardisation: blocks stacked and [X, extra] scaled in one array, the same
    numbers as StandardScaler.transform(np.hstack([np.vstack(blocks), extra]))."""
    from enginebench.methods.numerics.kernels import make_scaler, standardize_rows

    rng = np.random.default_rng(3)
    blocks = [rng.normal(5.0, 3.0, (n, 7)) * rng.uniform(0.1, 100, 7) for n in (13, 1, 40)]
    extra = rng.normal(300.0, 20.0, (54, extra_cols)) if extra_cols else None
    stacked = np.vstack(blocks) if extra is None else np.hstack([np.vstack(blocks), extra])
    scaler = make_scaler(stacked[::2], standardize)
    got = standardize_rows(scaler, blocks, extra)
    np.testing.assert_array_equal(got, scaler.transform(stacked))
    assert got.flags.c_contiguous and got.shape == stacked.shape


def test_a_bootstrap_resamples_repeated_rows_are_solved_once(monkeypatch) -> None:
    """predict_grid on a bootstrap draw (about a third repeats) merges repeated rows into weighted ones
    (numerics/repeats.py): the same predictions as the full system over a wide grid."""
    import enginebench.methods.krls as krls_module
    from enginebench.methods.numerics.repeats import RowGroups

    boot = TRAIN.take(np.sort(np.random.default_rng(7).integers(0, len(TRAIN), len(TRAIN))))
    m = KRLS(gamma_grid=(-3, 2, 6), lambda_grid=(-4, 2, 7))
    grid = grid_points(m.search_space(boot))
    sizes = []
    monkeypatch.setattr(krls_module, "RowGroups", type("Spy", (), {"of": staticmethod(
        lambda X: sizes.append(len(X)) or RowGroups.of(X))}))
    merged = m.predict_grid(boot, TEST, grid, RNG)
    groups = RowGroups.of(StandardScaler().fit_transform(boot.X))
    assert sizes == [len(TRAIN)] and groups is not None and len(groups.first) < 0.75 * len(TRAIN)
    monkeypatch.setattr(krls_module, "RowGroups", type("Off", (), {"of": staticmethod(lambda X: None)}))
    full = m.predict_grid(boot, TEST, grid, RNG)
    np.testing.assert_allclose(merged, full, rtol=0, atol=1e-10 * np.abs(full).max())


def _inputs_times(ds: Dataset, factor: float) -> Dataset:
    frame = ds.frame.copy()
    for c in ("x1", "x2", "x3"):
        frame[c] = frame[c] * factor
    return replace(ds, frame=frame)


@pytest.mark.parametrize("factor", [1e-200, 1e-170, 3e-160, 1e150, 1e200])
def test_inputs_of_any_scale_give_the_predictions_of_scale_one(factor: float) -> None:
    """Standardisation of the inputs underflowed below ~1e-154 (their squares) and overflowed above ~1e154: the
    variance went to 0 or inf, the scaler kept 1 or nan, and the kernel saw all rows alike. Inputs times 1e-200
    now predict what the inputs do, to 1e-9, in fit/predict and in the grid path alike."""
    train = make_samples(_inputs_times(_dataset(1), factor), ["y1", "y2"])
    test = make_samples(_inputs_times(_dataset(2, sizes=(30, 25)), factor), ["y1", "y2"]).without_targets()
    m = KRLS(gamma_grid=(-2, 1, 4), lambda_grid=(-4, 0, 3))
    for gamma, lam in [(0.1, 1.0), (1.0, 1e-4)]:
        np.testing.assert_allclose(_fit_predict(m, train, test, gamma, lam), _fit_predict(m, TRAIN, TEST, gamma, lam),
                                   rtol=1e-9, atol=0)
    grid = grid_points(m.search_space(TRAIN))
    np.testing.assert_allclose(m.predict_grid(train, test, grid, RNG), m.predict_grid(TRAIN, TEST, grid, RNG),
                               rtol=1e-9, atol=0)


def test_the_scaler_of_ordinary_inputs_is_standard_scalers_bit_for_bit() -> None:
    from enginebench.methods.numerics.kernels import make_scaler

    X = np.random.default_rng(5).normal(3.0, 2.0, (40, 4)) * [1e-3, 1.0, 7.0, 1e4]
    ours, theirs = make_scaler(X), StandardScaler().fit(X)
    np.testing.assert_array_equal(ours.transform(X), theirs.transform(X))
    np.testing.assert_array_equal(ours.scale_, theirs.scale_)
