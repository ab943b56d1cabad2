"""The ``moe`` method and the TV derivative it trains on.

The recovery test uses a known two-regime linear system dz/dt = a_r z + b_r u, with the
regime chosen by a scheduler signal v: (a, b) = (-1, 2) for v < 0 and (-3, 0.5) for
v > 0. The trained mixture must recover both local systems and simulate a held-out
segment open loop.
"""

from __future__ import annotations

import copy
import json
import pickle
import warnings
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch
from derivative.utils import integ
from derivative import TrendFiltered
from scipy.integrate import solve_ivp

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import DataError, MethodError
from enginebench.methods.moe import MoE, frozen_stability, gate_weights, local_coefficients, simulate
from enginebench.methods.moe.model import moe_loss, signed_softplus
from enginebench.methods.numerics.derivatives import tv_derivative, tv_differentiate, window_bounds
from enginebench.methods.numerics.tv_admm import objective

DT = 0.05
REGIMES = {"low": (-1.0, 2.0), "high": (-3.0, 0.5)}  # v < 0, v > 0
REL_TOL = 0.15  # stated tolerance on the recovered coefficients


# -- data -------------------------------------------------------------------------------------
def two_regime_samples(seed: int, n_seg: int, n: int, noise: float = 0.005, v_const: float | None = None):
    """Simulation-mode samples of the two-regime system, integrated finely (RK4, 2 substeps)."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.05, 0.5, (n_seg, 3))
    ph = rng.uniform(0, 2 * np.pi, (n_seg, 3))
    amp = rng.uniform(0.5, 1.0, (n_seg, 3))
    period, phv = rng.uniform(8, 16, n_seg), rng.uniform(0, 2 * np.pi, n_seg)

    def u(t):
        return 1.0 + (amp * np.sin(2 * np.pi * f * np.asarray(t)[..., None, None] + ph)).sum(-1)

    def v(t):
        return np.full(n_seg, v_const) if v_const is not None else np.sin(2 * np.pi * t / period + phv)

    def rhs(t, z):
        low = v(t) < 0
        return np.where(low, REGIMES["low"][0], REGIMES["high"][0]) * z + np.where(low, REGIMES["low"][1], REGIMES["high"][1]) * u(t)

    sub, h = 2, DT / 2
    Z = np.empty((n, n_seg))
    z = rng.uniform(0.0, 2.0, n_seg)
    Z[0] = z
    for i in range(1, n):
        for j in range(sub):
            t = (i - 1) * DT + j * h
            k1 = rhs(t, z)
            k2 = rhs(t + h / 2, z + h / 2 * k1)
            k3 = rhs(t + h / 2, z + h / 2 * k2)
            k4 = rhs(t + h, z + h * k3)
            z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        Z[i] = z
    T = np.arange(n) * DT
    Z = Z + noise * Z.std() * rng.standard_normal(Z.shape)
    V = np.stack([v(t) for t in T])
    frames = [
        pd.DataFrame({"segment": f"r{seed}-{s}", "time": T, "u": u(T)[:, s], "v": V[:, s], "z": Z[:, s]})
        for s in range(n_seg)
    ]
    ds = Dataset("two-regime", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "v": "input", "z": "output"}), DT)
    return make_samples(ds, ["z"], "simulation")


@pytest.fixture(scope="module")
def train():
    return two_regime_samples(1, 4, 400)


@pytest.fixture(scope="module")
def test_data():
    return two_regime_samples(2, 2, 400)


@pytest.fixture(scope="module")
def short_data(test_data):
    """The first 120 rows of the held-out segments (for the slower step-by-step simulator)."""
    cut = lambda s: replace(s, X=s.X[:120], rows=s.rows[:120], U=s.U[:120], t=s.t[:120], y=None)  # noqa: E731
    return replace(test_data, segments=tuple(cut(s) for s in test_data.segments))


@pytest.fixture(scope="module")
def model(train):
    method = MoE(scheduler=["v"], batch_size=2048, device="cpu")  # full batch: 1600 rows
    return method, method.fit(train, {"n_experts": 3, "epochs": 300, "lr": 3e-2}, np.random.default_rng(0))


def rmae(pred, data, train):
    """Seed 003's RMAE_set: mean over segments of each segment's MAE, over mean |y| in training."""
    return np.mean([np.mean(np.abs(p - s.y)) for p, s in zip(pred, data.segments)]) / np.mean(np.abs(train.y))


# -- TV derivative ------------------------------------------------------------------------------
def test_tv_derivative_of_noisy_sine_is_close_to_analytic():
    rng = np.random.default_rng(3)
    t = np.arange(600) * 0.01
    y = np.sin(2 * t) + 0.01 * rng.standard_normal(t.size)
    exact = 2 * np.cos(2 * t)
    fd_rmse = np.sqrt(np.mean((np.gradient(y, t) - exact) ** 2))
    tv_rmse = np.sqrt(np.mean((tv_derivative(y, t, 1e-5) - exact) ** 2))
    tv1_rmse = np.sqrt(np.mean((tv_derivative(y, t, 1e-6, order=1) - exact) ** 2))
    assert tv_rmse < 0.15  # amplitude 2
    assert tv1_rmse < 0.08
    assert tv_rmse < fd_rmse / 5  # the noise a finite difference amplifies is removed


def test_tv_derivative_columns_windows_and_package_agree():
    rng = np.random.default_rng(4)
    t = np.arange(300) * 0.02
    Y = np.c_[np.sin(t), np.exp(-0.3 * t)] + 0.005 * rng.standard_normal((300, 2))
    D = tv_derivative(Y, t, 1e-5)
    assert D.shape == (300, 2)
    np.testing.assert_allclose(D[:, 1], tv_derivative(Y[:, 1], t, 1e-5))  # columns are independent
    # one window, the package's solver: exactly its estimate; several windows: close to its full-length one
    short = tv_derivative(Y[:100, 0], t[:100], 1e-5, solver="lasso")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref_short = TrendFiltered(order=0, alpha=1e-5, tol=1e-3, max_iter=10_000, precompute=True).d(Y[:100, 0], t[:100])
        ref_full = TrendFiltered(order=0, alpha=1e-5, tol=1e-3, max_iter=10_000, precompute=True).d(Y[:, 0], t)
    np.testing.assert_allclose(short, ref_short, rtol=1e-7, atol=1e-10)  # BLAS thread counts differ
    # the default (batched ADMM) solver: a lower objective than the package's stopped Lasso
    B, A = (Y[:100, :1] - Y[0, 0]), integ(100, 0.02)
    f_admm, f_lasso = (
        float(objective(u[:, None], B, A, 1e-5, 0.02)[0]) for u in (tv_derivative(Y[:100, 0], t[:100], 1e-5), short)
    )
    assert f_admm < f_lasso
    assert np.sqrt(np.mean((D[10:-10, 0] - ref_full[10:-10]) ** 2)) < 0.05
    smooth, _ = tv_differentiate(Y, t, 1e-5)
    assert np.sqrt(np.mean((smooth - Y) ** 2)) < 0.02


def test_window_bounds_tile_the_signal():
    for n in (5, 128, 129, 300, 1001):
        bounds = window_bounds(n, 128, 16)
        kept = np.concatenate([np.arange(a, b) for _, _, a, b in bounds])
        np.testing.assert_array_equal(kept, np.arange(n))
        assert all(hi - lo == min(n, 128) and lo <= a and b <= hi for lo, hi, a, b in bounds)


def test_tv_derivative_rejects_bad_time():
    t = np.r_[0.0, 0.1, 0.2, 0.5, 0.6]
    with pytest.raises(DataError, match=r"not uniformly sampled \(step 0.3.* at row 3"):
        tv_derivative(np.arange(5.0), t, 1e-3)
    with pytest.raises(DataError, match="must match in rows"):
        tv_derivative(np.arange(4.0), np.arange(5.0), 1e-3)
    with pytest.raises(MethodError, match="option tv_solver='cvx'; use 'admm' or 'lasso'"):
        MoE(tv_solver="cvx")


# -- building blocks ------------------------------------------------------------------------------
def test_signed_softplus_is_seed_eq6():
    x = torch.linspace(-30, 30, 61, dtype=torch.float64)
    for k in (0.5, 1.0, 10.0):
        neg = signed_softplus(x, torch.tensor(-1.0, dtype=torch.float64), k)
        np.testing.assert_allclose(neg.numpy(), -np.log1p(np.exp(k * x.numpy())) / k, rtol=1e-8)  # torch: linear beyond kx = 20
        assert (neg < 0).all()
    free = signed_softplus(x, torch.tensor(0.0, dtype=torch.float64), 1.0)
    np.testing.assert_array_equal(free.numpy(), x.numpy())


def test_loss_is_seed_eq4():
    rng = np.random.default_rng(5)
    f, y = rng.normal(size=(7, 3, 2)), rng.normal(size=(7, 2))
    a = rng.dirichlet(np.ones(3), size=7)
    coll = ((y - np.einsum("nm,nmk->nk", a, f)) ** 2).sum(1)
    err = ((y[:, None] - f) ** 2).sum(2)
    T = lambda x: torch.as_tensor(x)  # noqa: E731
    got2 = moe_loss(T(f), T(a), T(y), 0.7, 0.3, "alpha2").item()
    got1 = moe_loss(T(f), T(a), T(y), 0.7, 0.3, "alpha").item()
    assert got2 == pytest.approx(np.mean(0.7 * coll + 0.3 * (a**2 * err).sum(1)), rel=1e-12)
    assert got1 == pytest.approx(np.mean(0.7 * coll + 0.3 * (a * err).sum(1)), rel=1e-12)


# -- recovery and simulation -----------------------------------------------------------------------
def test_recovers_both_local_linear_systems(model):
    _, fitted = model
    points = np.array([[-0.8], [-0.4], [0.4], [0.8]])
    loc = local_coefficients(fitted, points)
    a, b = loc["A"][:, 0, 0], loc["B"][:, 0, 0]  # B's columns: u, v
    for j, regime in enumerate(["low", "low", "high", "high"]):
        a_true, b_true = REGIMES[regime]
        assert abs(a[j] - a_true) < REL_TOL * abs(a_true), (points[j], a[j])
        assert abs(b[j] - b_true) < REL_TOL * abs(b_true), (points[j], b[j])
    # the gate gives each regime its own expert
    assert np.argmax(loc["gate"][0]) == np.argmax(loc["gate"][1]) != np.argmax(loc["gate"][2]) == np.argmax(loc["gate"][3])


def test_open_loop_simulation_of_held_out_segments(model, train, test_data):
    method, fitted = model
    pred = method.predict(fitted, test_data.without_targets())
    assert len(pred) == 2 and not pred.diverged.any()
    assert all(p.shape == (400, 1) for p in pred)
    for p, s in zip(pred, test_data.segments):
        assert p[0, 0] == pytest.approx(s.y0[0], rel=1e-6)  # starts from the measured y0
    assert rmae(pred, test_data, train) < 0.05
    # the simulation never reads measured outputs after t0: replacing them changes nothing
    scrambled = replace(test_data, segments=tuple(replace(s, y=s.y[::-1] * 7.0) for s in test_data.segments))
    for p, q in zip(pred, method.predict(fitted, scrambled)):
        np.testing.assert_array_equal(p, q)


def test_affine_chunked_simulation_equals_stepwise(model, short_data):
    _, fitted = model
    data = short_data
    a, ga, _ = simulate(fitted, data, record_gate=True)
    b, gb, _ = simulate(fitted, data, record_gate=True, stepwise=True)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5)
    for x, y in zip(ga, gb):
        np.testing.assert_allclose(x, y, atol=1e-6)


def test_integrator_matches_scipy_for_a_frozen_scheduler(model):
    """With v held constant the model is an LTI system: RK4 at the data's dt vs solve_ivp."""
    _, fitted = model
    data = two_regime_samples(7, 1, 200, noise=0.0, v_const=0.5)
    seg = data.segments[0]
    (sim,), _, _ = simulate(fitted, data.without_targets())
    loc = local_coefficients(fitted, np.array([[0.5]]))
    A, B, c = loc["A"][0], loc["B"][0], loc["c"][0]

    def rhs(t, y):
        u = np.array([np.interp(t, seg.t, seg.U[:, k]) for k in range(seg.U.shape[1])])
        return A @ y + B @ u + c

    ref = solve_ivp(rhs, (seg.t[0], seg.t[-1]), seg.y0, t_eval=seg.t, rtol=1e-10, atol=1e-12, max_step=DT)
    np.testing.assert_allclose(sim[:, 0], ref.y[0], rtol=1e-4, atol=1e-4 * np.abs(ref.y).max())


def test_describe_and_frozen_stability(model):
    method, fitted = model
    d = method.describe(fitted)
    json.dumps(d)  # plain, storable artefacts
    assert d["n_experts"] == 3 and d["hyperparameters"]["epochs"] == 300
    assert d["schedulers"] == ["v"] and d["inputs"] == ["u", "v"]
    assert d["signs"] == {"dz/dt <- z": "-"}
    assert len(d["local_systems"]) == 1 + 3
    verdict = d["frozen_stability"]
    assert verdict["stable"] and verdict["state_coefficients_negative"]
    assert verdict["max_state_coefficient"] < 0 and verdict["max_real_eigenvalue"] < 0


def test_gate_weights_follow_the_scheduler(model, test_data):
    _, fitted = model
    gates = gate_weights(fitted, test_data.without_targets())
    low = None
    for g, s in zip(gates, test_data.segments):
        assert g.shape == (400, 3)
        np.testing.assert_allclose(g.sum(1), 1.0, atol=1e-5)
        v = s.U[:, 1]
        far = np.abs(v) > 0.2
        dom = g.argmax(1)
        low = low if low is not None else np.bincount(dom[far & (v < 0)], minlength=3).argmax()
        assert np.mean(dom[far & (v < 0)] == low) > 0.95
        assert np.mean(dom[far & (v > 0)] != low) > 0.95


def test_unstable_model_is_flagged_diverged(model, test_data, short_data):
    """A sign-free model given a large positive own-state coefficient must be stopped and flagged."""
    method, fitted = model
    bad = copy.deepcopy(fitted)
    bad.sign = np.zeros_like(bad.sign)  # sign-free experts
    bad.weights["sign"] = np.zeros_like(bad.weights["sign"])
    bad.weights["b2"][:, 0] += 20.0  # coefficient (z <- z) of every expert
    verdict = frozen_stability(bad)
    assert not verdict["stable"] and not verdict["state_coefficients_negative"]
    pred = method.predict(bad, test_data.without_targets())
    assert pred.diverged.all()
    span = fitted.y_max - fitted.y_min
    for p in pred:
        assert np.isfinite(p).all()
        assert (p >= fitted.y_min - 10 * span).all() and (p <= fitted.y_max + 10 * span).all()
        assert p[-1, 0] == p[-2, 0]  # held after it left the envelope
    # the step-by-step path agrees on the flags and the held values
    a, _, flags_a = simulate(bad, short_data)
    b, _, flags_b = simulate(bad, short_data, stepwise=True)
    assert flags_a.all() and flags_b.all()
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=1e-4)


def test_fitted_model_survives_pickle(model, test_data):
    method, fitted = model
    again = pickle.loads(pickle.dumps(fitted))
    for p, q in zip(method.predict(fitted, test_data.without_targets()), method.predict(again, test_data.without_targets())):
        np.testing.assert_array_equal(p, q)


# -- determinism, quasi-LPV, errors -------------------------------------------------------------------
def test_deterministic_under_a_seed_and_quasi_lpv_runs():
    small = two_regime_samples(3, 2, 100)
    method = MoE(scheduler=["v"], scheduler_state=True, batch_size=64, device="cpu")
    params = {"n_experts": 2, "epochs": 2}
    f1 = method.fit(small, params, np.random.default_rng(11))
    f2 = method.fit(small, params, np.random.default_rng(11))
    f3 = method.fit(small, params, np.random.default_rng(12))
    for name in f1.weights:
        np.testing.assert_array_equal(f1.weights[name], f2.weights[name])
    assert not np.array_equal(f1.weights["w1"], f3.weights["w1"])
    p1 = method.predict(f1, small.without_targets())
    p2 = method.predict(f2, small.without_targets())
    for a, b in zip(p1, p2):
        np.testing.assert_array_equal(a, b)
    gates = gate_weights(f1, small.without_targets())
    assert [g.shape for g in gates] == [(100, 2), (100, 2)]
    assert method.describe(f1)["schedulers"] == ["v", "z"]


def test_bad_input_errors(train):
    with pytest.raises(MethodError, match="unknown option"):
        MoE(schedular=["v"])
    with pytest.raises(MethodError, match="option integrator='midpoint'"):
        MoE(integrator="midpoint")
    with pytest.raises(MethodError, match=r"option scheduler names 'w', not among the run-time inputs \(u, v\)"):
        MoE(scheduler=["w"]).fit(train, {"epochs": 1}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="option signs names 'q'"):
        MoE(signs={"q": "-"}).fit(train, {"epochs": 1}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="hyperparameter n_experts=0 must be a positive integer"):
        MoE().fit(train, {"n_experts": 0}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="unknown hyperparameter"):
        MoE().fit(train, {"experts": 2}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="does not support mode 'static'"):
        MoE().fit(replace(train, mode="static"), {}, np.random.default_rng(0))
    subsample = train.take(np.arange(0, len(train), 2))
    with pytest.raises(MethodError, match=r"training segment 'r1-0' is a row subsample \(200 of 400 rows\)"):
        MoE().fit(subsample, {"epochs": 1}, np.random.default_rng(0))


# -- input derivatives, least-squares warm start, scheduler clamp --------------------------------------
def test_input_derivative_matches_analytic_and_feeds_the_regressors():
    from enginebench.methods.moe import input_derivative

    t = np.arange(400) * 0.05
    x = np.c_[np.sin(0.7 * t), 0.1 * t**2]
    d1 = input_derivative(x, t, 1, 1.0)
    d2 = input_derivative(x, t, 2, 1.0)
    np.testing.assert_allclose(d1[:, 0], 0.7 * np.cos(0.7 * t), atol=5e-3)
    np.testing.assert_allclose(d1[:, 1], 0.2 * t, atol=1e-8)
    np.testing.assert_allclose(d2[:, 1], 0.2, atol=1e-8)
    np.testing.assert_allclose(input_derivative(x[:3], t[:3], 1, 1.0)[:, 1], np.gradient(x[:3, 1], t[:3]))  # short segment


def lead_samples(seed: int, n_seg: int, n: int):
    """dz/dt = -z + u + 2 du/dt (a lead: z jumps with u), u a sum of slow sines."""
    rng = np.random.default_rng(seed)
    T = np.arange(n) * DT
    frames = []
    for s in range(n_seg):
        f, ph = rng.uniform(0.05, 0.4, 3), rng.uniform(0, 2 * np.pi, 3)
        u = np.sin(2 * np.pi * f * T[:, None] + ph).sum(1)
        du = (2 * np.pi * f * np.cos(2 * np.pi * f * T[:, None] + ph)).sum(1)
        sol = solve_ivp(lambda t, z: -z + np.interp(t, T, u) + 2 * np.interp(t, T, du), (0, T[-1]), [0.0],
                        t_eval=T, max_step=DT / 2, rtol=1e-8, atol=1e-10)
        frames.append(pd.DataFrame({"segment": f"l{seed}-{s}", "time": T, "u": u, "v": np.zeros(n), "z": sol.y[0]}))
    ds = Dataset("lead", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "v": "input", "z": "output"}), DT)
    return make_samples(ds, ["z"], "simulation")


def test_input_derivatives_let_the_mixture_model_a_lead():
    """Without du/dt among the regressors a lead cannot be represented (turboshaft-moe's COL' term)."""
    train, test = lead_samples(1, 3, 400), lead_samples(2, 2, 400)
    scores = {}
    for derivs in (None, {"u": 1}):
        method = MoE(scheduler=["v"], expert_inputs=["u"], input_derivatives=derivs, batch_size=2048, device="cpu")
        fitted = method.fit(train, {"n_experts": 1, "epochs": 150, "lr": 1e-2}, np.random.default_rng(0))
        scores[derivs is not None] = rmae(method.predict(fitted, test.without_targets()), test, train)
    with_d = MoE(scheduler=["v"], expert_inputs=["u"], input_derivatives={"u": 1}, batch_size=2048, device="cpu")
    fitted = with_d.fit(train, {"n_experts": 1, "epochs": 150, "lr": 1e-2}, np.random.default_rng(0))
    assert fitted.expert_inputs == ("u", "du/dt") and fitted.augmented_names == ("u", "v", "du/dt")
    loc = local_coefficients(fitted, np.array([[0.0]]))
    np.testing.assert_allclose(loc["A"][0, 0, 0], -1.0, rtol=REL_TOL)
    np.testing.assert_allclose(loc["B"][0, 0], [1.0, 2.0], rtol=REL_TOL)
    assert scores[True] < 0.05 < scores[False]
    with pytest.raises(MethodError, match="option input_derivatives names 'w'"):
        MoE(input_derivatives={"w": 1}).fit(train, {"epochs": 1}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="must map input columns to an order 1 or 2"):
        MoE(input_derivatives={"u": 3})


def test_warm_start_puts_every_expert_at_the_sign_bounded_least_squares_model():
    from enginebench.methods.moe import lstsq_coefficients, warm_start
    from enginebench.methods.moe.model import MixtureOfExperts

    rng = np.random.default_rng(0)
    X = np.c_[rng.normal(size=(500, 2)), np.ones(500)]
    theta = np.array([[-0.3, 0.8, 0.1]])
    D = X @ theta.T + 0.01 * rng.normal(size=(500, 1))
    sign = np.array([[-1.0, 0.0, 0.0]])
    net = MixtureOfExperts(1, 1, 3, 3, 8, 8, torch.as_tensor(sign), 1.0, torch.Generator().manual_seed(0), torch.float64)
    got = lstsq_coefficients(X, D, sign)
    np.testing.assert_allclose(got, theta, atol=0.01)
    warm_start(net, got, sign, 1.0, shrink=0.0)
    with torch.no_grad():
        G = net.coefficients(torch.linspace(-2, 2, 5, dtype=torch.float64)[:, None]).numpy()  # (5, M, 1, 3)
    np.testing.assert_allclose(G, np.broadcast_to(got, G.shape), rtol=1e-9, atol=1e-12)
    # the data prefer the wrong sign: the coefficient sits at its bound 0 and the others are the
    # least-squares fit without it (bounded least squares, not a fit-then-clip)
    got = lstsq_coefficients(X, -D, sign)
    assert got[0, 0] == 0.0
    np.testing.assert_allclose(got[0, 1:], np.linalg.lstsq(X[:, 1:], -D[:, 0], rcond=None)[0], rtol=1e-5)
    warm_start(net, got, sign, 1.0, shrink=0.0)
    with torch.no_grad():
        a = net.coefficients(torch.zeros((1, 1), dtype=torch.float64))[0, :, 0, 0].numpy()
    np.testing.assert_allclose(a, -1e-2, rtol=1e-9)  # starts 1e-2 beyond the bound, right sign
    # a margin of 0.5 binds (-0.3 is too slow): the coefficient sits at -0.5, the network at -(0.5 + 1e-2)
    margin = np.array([[0.5, 0.0, 0.0]])
    got = lstsq_coefficients(X, D, sign, margin)
    assert got[0, 0] == pytest.approx(-0.5, abs=1e-12)
    net = MixtureOfExperts(1, 1, 3, 2, 8, 8, torch.as_tensor(sign), 1.0, torch.Generator().manual_seed(0), torch.float64,
                           torch.as_tensor(margin))
    warm_start(net, got, sign, 1.0, margin, shrink=0.0)
    with torch.no_grad():
        a = net.coefficients(torch.zeros((1, 1), dtype=torch.float64))[0, :, 0, 0].numpy()
    np.testing.assert_allclose(a, -0.51, rtol=1e-9)


def test_signed_softplus_margin_bounds_the_magnitude():
    x = torch.linspace(-40, 40, 81, dtype=torch.float64)
    neg = signed_softplus(x, torch.tensor(-1.0, dtype=torch.float64), 1.0, 0.25)
    np.testing.assert_allclose(neg.numpy(), -(0.25 + np.log1p(np.exp(x.numpy()))), rtol=1e-8)  # torch: linear beyond x = 20
    assert (neg <= -0.25).all()
    free = signed_softplus(x, torch.tensor(0.0, dtype=torch.float64), 1.0, 0.25)
    np.testing.assert_array_equal(free.numpy(), x.numpy())  # a free coefficient ignores the margin


def test_affine_prefix_scan_equals_the_sequential_recurrence():
    from enginebench.methods.moe import affine_prefix_scan

    g = torch.Generator().manual_seed(3)
    Phi = torch.eye(2, dtype=torch.float64) + 0.1 * torch.randn((3, 37, 2, 2), generator=g, dtype=torch.float64)
    gamma = torch.randn((3, 37, 2), generator=g, dtype=torch.float64)
    z0 = torch.randn((3, 2), generator=g, dtype=torch.float64)
    M, c = affine_prefix_scan(Phi, gamma)
    z, ref = z0, []
    for n in range(37):
        z = (Phi[:, n] @ z[..., None])[..., 0] + gamma[:, n]
        ref.append(z)
    got = (M @ z0[:, None, :, None])[..., 0] + c
    np.testing.assert_allclose(got.numpy(), torch.stack(ref, 1).numpy(), rtol=1e-12, atol=1e-12)


def test_margin_and_simulation_loss(train, test_data):
    """max_time_constant = 0.5 s binds (the true regimes have a = -1 and -3): every expert's own-state
    coefficient stays <= -2 everywhere; the simulation term trains and its windows are simulated
    exactly like ``simulate``."""
    method = MoE(scheduler=["v"], batch_size=2048, device="cpu", dtype="float64",
                 max_time_constant=0.5, sim_weight=1.0, shooting_window=5.0)
    fitted = method.fit(train, {"n_experts": 2, "epochs": 20, "lr": 1e-2}, np.random.default_rng(0))
    verdict = frozen_stability(fitted)
    assert verdict["max_state_coefficient"] <= -2.0 + 1e-9 and verdict["stable"]
    d = method.describe(fitted)
    assert d["warm_start"] == {"init": "lstsq"}
    assert d["max_time_constant_s"] == 0.5 and d["sim_weight"] == 1.0 and d["corrected"] == {}
    json.dumps(d)
    pred = method.predict(fitted, test_data.without_targets())
    assert not pred.diverged.any() and np.isfinite(np.concatenate(list(pred))).all()
    with pytest.raises(MethodError, match="max_time_constant bounds own-state coefficients"):
        MoE(scheduler=["v"], signs="none", max_time_constant=1.0).fit(train, {"epochs": 1}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="quasi-LPV"):
        MoE(scheduler=["v"], scheduler_state=True, sim_weight=1.0).fit(train, {"epochs": 1}, np.random.default_rng(0))
    for bad in ({"max_time_constant": -1}, {"sim_weight": -1.0}, {"init": "oe"}, {"correct": {"z": {"v": [0, 1]}}},
                {"derivative_window": 0}, {"shooting_window": "20 s"}):
        with pytest.raises(MethodError):
            MoE(**bad)
    with pytest.raises(MethodError, match=r"option init='output_error'; only 'lstsq'.* removed"):
        MoE(init="output_error")


def test_time_windows_default_to_samples_and_explicit_seconds_still_work():
    """derivative_window / shooting_window None = 24 / 240 samples whatever dt (at 12 Hz: the former
    2 s / 20 s); a number is seconds."""
    from enginebench.methods.moe import input_derivative
    from enginebench.methods.moe.training import _Shooting

    rng = np.random.default_rng(2)
    for dt in (1.0 / 12.0, 0.05, 3.0):
        t = np.arange(600) * dt
        x = np.cumsum(rng.standard_normal((600, 1)), axis=0)
        by_samples = input_derivative(x, t, 1)
        np.testing.assert_array_equal(by_samples, input_derivative(x, t, 1, 24 * dt))
        shoot = _Shooting([x], [x], [t], None, [0], [0], np.ones(1))
        assert shoot.width == 241 and _Shooting([x], [x], [t], 10 * dt, [0], [0], np.ones(1)).width == 11
    t12 = np.arange(600) / 12.0
    np.testing.assert_array_equal(input_derivative(x, t12, 2), input_derivative(x, t12, 2, 2.0))
    assert MoE().options["derivative_window"] is None and MoE().options["shooting_window"] is None


def test_rollout_of_training_windows_equals_simulate(model, short_data):
    from enginebench.methods.moe import build_network
    from enginebench.methods.moe.simulation import _Sim

    _, fitted = model
    seg = short_data.segments[0]
    (ref,), _, _ = simulate(fitted, replace(short_data, segments=(seg,)))
    U = torch.as_tensor(((seg.U - fitted.u_mean) / fitted.u_scale)[None])
    inf = torch.full((1,), torch.inf, dtype=torch.float64)
    sim = _Sim(options=fitted.options, n_experts=3, net=build_network(fitted, torch.device("cpu")).double(), U=U,
               H=torch.as_tensor(np.diff(seg.t)[None]), lo=-inf, hi=inf, d_scale=torch.as_tensor(fitted.d_scale), si=[1],
               ei=[0, 1], record_gate=False)
    z0 = torch.as_tensor((seg.y0 - fitted.y_mean) / fitted.y_scale)[None]
    with torch.no_grad():
        got = sim.rollout(z0)[0].numpy() * fitted.y_scale + fitted.y_mean
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5)


def test_standard_day_correction_factors_and_raw_unit_predictions():
    from enginebench.methods.moe import correction_factors

    U = np.array([[101.325 * 0.9, 288.15 * 1.21, 5.0], [101.325, 288.15, 5.0]])
    fu, fy = correction_factors({"WF": {"P0": [101.325, 1.0], "T1": [288.15, 0.5]}}, ["P0", "T1", "COL"], ["WF"], U)
    np.testing.assert_allclose(fy[:, 0], [0.9 * 1.1, 1.0], rtol=1e-12)  # delta sqrt(theta)
    np.testing.assert_array_equal(fu, 1.0)
    fu, _ = correction_factors({"COL": {"P0": [101.325, -1.0]}}, ["P0", "T1", "COL"], ["WF"], U)
    np.testing.assert_allclose(fu[:, 2], [1 / 0.9, 1.0], rtol=1e-12)
    with pytest.raises(MethodError, match="<= 0 at row 1"):
        correction_factors({"WF": {"COL": [1.0, 1.0]}}, ["COL"], ["WF"], np.array([[1.0], [-1.0]]))
    with pytest.raises(MethodError, match="neither a target"):
        correction_factors({"NG": {"COL": [1.0, 1.0]}}, ["COL"], ["WF"], np.ones((2, 1)))
    # a target that is (an uncorrected system's output) x a known input factor: the corrected fit is the
    # uncorrected fit of the original data, and its predictions come back multiplied by the factor
    data = two_regime_samples(11, 3, 300)
    k = [1.0 + 0.2 * np.sin(0.05 * s.t) for s in data.segments]
    segs = tuple(replace(s, U=np.c_[s.U, f], y=s.y * f[:, None], y0=s.y0 * f[0]) for s, f in zip(data.segments, k))
    scaled = replace(data, segments=segs, input_names=data.input_names + ("p",))
    opts = dict(scheduler=["v"], expert_inputs=["u", "v"], batch_size=2048, device="cpu", dtype="float64")
    hp = {"n_experts": 2, "epochs": 30, "lr": 1e-2}
    plain = MoE(**opts)
    ref = plain.predict(plain.fit(data, hp, np.random.default_rng(0)), data.without_targets())
    corrected = MoE(**opts, correct={"z": {"p": [1.0, 1.0]}})
    pred = corrected.predict(corrected.fit(scaled, hp, np.random.default_rng(0)), scaled.without_targets())
    for p, r, f in zip(pred, ref, k):
        np.testing.assert_allclose(p[:, 0], r[:, 0] * f, rtol=1e-9, atol=1e-12)


def test_schedulers_are_held_at_the_edge_of_their_training_range(model):
    _, fitted = model
    inside = local_coefficients(fitted, np.array([[fitted.probe.max() * 0 + 1.0]]))  # v = 1 is the training max
    far = local_coefficients(fitted, np.array([[25.0]]))
    np.testing.assert_allclose(far["A"], inside["A"], rtol=1e-6)
    np.testing.assert_allclose(far["gate"], inside["gate"], atol=1e-7)
    free = copy.deepcopy(fitted)
    free.weights["v_lo"] = np.full_like(free.weights["v_lo"], -np.inf)
    free.weights["v_hi"] = np.full_like(free.weights["v_hi"], np.inf)
    assert not np.allclose(local_coefficients(free, np.array([[25.0]]))["A"], inside["A"], rtol=1e-3)


# -- epochs as early stopping: one training run checkpointed -----------------------------------------
def test_fit_grid_checkpoints_equal_separate_fits_of_each_epoch_count(train, test_data):
    method = MoE(scheduler=["v"], batch_size=256, device="cpu", sim_weight=1.0, shooting_window=20.0)
    grid = [{"n_experts": 2, "epochs": e, "lr": lr} for lr in (1e-2, 3e-2) for e in (6, 2, 4)]
    got = dict(method.fit_grid(train, grid, np.random.default_rng(5)))
    assert sorted(got) == list(range(6))
    rng = np.random.default_rng(5)  # two training runs: each lr's run draws its seed and probe once
    for run in ([0, 1, 2], [3, 4, 5]):
        state = rng.bit_generator.state
        for i in run:
            rng.bit_generator.state = state
            alone = method.fit(train, grid[i], rng)
            assert got[i].params == alone.params and got[i].loss_history == alone.loss_history
            assert len(alone.loss_history) == grid[i]["epochs"]
            for name, w in alone.weights.items():
                assert np.array_equal(got[i].weights[name], w), name
            assert np.array_equal(got[i].probe, alone.probe)
    # the longer run goes on from the shorter one's model: its first epochs' losses are the same
    assert got[0].loss_history[:2] == got[1].loss_history
    view = test_data.without_targets()
    assert not np.allclose(np.concatenate(method.predict(got[0], view)), np.concatenate(method.predict(got[1], view)))


def test_the_number_of_experts_and_the_learning_rate_declare_hard_bounds():
    from enginebench.methods.moe import MoE

    bounds = MoE().search_bounds(None)
    assert bounds["n_experts"] == (1, 8) and bounds["lr"] == (1e-5, 0.1) and "beta2" not in bounds
