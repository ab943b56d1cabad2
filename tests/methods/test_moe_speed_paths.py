"""MoE's fast training paths equal the former ones (issue 18): the fused simulation (one network call
for samples and RK4 midpoints, 1 x 1 maps as elementwise products), the fused epoch loop (rows and
windows shuffled once, then sliced), the cached TV derivatives and, where torch.compile works, the
compiled step: the same losses, gradients, simulated trajectories and trained weights on small problems.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.methods.moe import MoE, affine_prefix_scan, resolve_params, training as tr
from enginebench.methods.moe.model import MixtureOfExperts
from enginebench.methods.moe.preprocess import prepare
from enginebench.methods.moe.simulation import _Sim
from enginebench.methods.moe.training import fit_mixture
from enginebench.methods.numerics import derivatives

from helpers import two_state_samples

F64 = torch.float64


def random_sim(k: int, integrator: str = "rk4", interp: str = "linear", fused: bool = True, seed: int = 0,
               S: int = 3, L: int = 41) -> tuple[_Sim, torch.Tensor]:
    """A _Sim of a random stable-signed mixture (k states, 3 inputs of which 2 schedule) and random z0."""
    g = torch.Generator().manual_seed(seed)
    n_u, q = 3, k + 3 + 1
    sign = torch.zeros((k, q), dtype=F64)
    sign[range(k), range(k)] = -1
    net = MixtureOfExperts(2, k, q, 3, 8, 8, sign, 1.0, torch.Generator().manual_seed(seed), F64)
    U = torch.randn((S, L, n_u), generator=g, dtype=F64)
    H = 0.05 + 0.05 * torch.rand((S, L - 1), generator=g, dtype=F64)
    inf = torch.full((k,), torch.inf, dtype=F64)
    o = {"integrator": integrator, "input_interp": interp, "bias": True, "scheduler_state": False}
    sim = _Sim(options=o, n_experts=3, net=net, U=U, H=H, lo=-inf, hi=inf, d_scale=torch.full((k,), 0.7, dtype=F64),
               si=[0, 2], ei=[0, 1, 2], record_gate=True, fused=fused)
    return sim, torch.randn((S, k), generator=g, dtype=F64)


@pytest.mark.parametrize("k", [1, 2])
@pytest.mark.parametrize("integrator,interp", [("rk4", "linear"), ("rk4", "hold"), ("euler", "linear")])
def test_fused_step_maps_rollout_and_gradients_equal_the_reference(k, integrator, interp):
    """Same Phi, gamma, gate, rolled-out windows and parameter gradients of their squared error."""
    out = {}
    for fused in (False, True):
        sim, z0 = random_sim(k, integrator, interp, fused)
        Phi, gamma, alpha = sim.step_maps(0, sim.U.shape[1] - 1)
        traj = sim.rollout(z0)
        (traj**2).mean().backward()
        out[fused] = (Phi, gamma, alpha, traj, [p.grad.clone() for p in sim.net.parameters()])
    for ref, got in zip(out[False][:4], out[True][:4]):
        assert ref.shape == got.shape
        torch.testing.assert_close(got, ref, rtol=1e-12, atol=1e-13)
    for ref, got in zip(out[False][4], out[True][4]):
        torch.testing.assert_close(got, ref, rtol=1e-10, atol=1e-13)
    assert any(float(g.abs().max()) > 0 for g in out[True][4])  # the gradients are not trivially zero


@pytest.mark.parametrize("k", [1, 2])
def test_fused_affine_simulation_equals_the_reference_and_the_rollout(k):
    """The prediction path (chunked recurrence, elementwise for one state) gives the reference's
    trajectories, gates and divergence flags; without an envelope it equals the differentiable rollout."""
    res = {}
    for fused in (False, True):
        sim, z0 = random_sim(k, fused=fused, L=300)
        with torch.no_grad():
            res[fused] = (*sim.affine(z0), sim.rollout(z0))
    (t0, g0, a0, r0), (t1, g1, a1, r1) = res[False], res[True]
    torch.testing.assert_close(t1, t0, rtol=1e-11, atol=1e-12)
    torch.testing.assert_close(g1, g0, rtol=1e-12, atol=1e-13)
    assert torch.equal(a0, a1) and bool(a1.all())
    torch.testing.assert_close(r1, t1, rtol=1e-9, atol=1e-10)


def test_scalar_prefix_scan_is_exactly_the_matmul_scan_and_the_recurrence():
    g = torch.Generator().manual_seed(5)
    Phi = 1.0 + 0.1 * torch.randn((4, 53, 1, 1), generator=g, dtype=F64)
    gamma = torch.randn((4, 53, 1), generator=g, dtype=F64)
    M1, c1 = affine_prefix_scan(Phi, gamma)
    M0, c0 = affine_prefix_scan(Phi, gamma, fused=False)
    assert torch.equal(M1, M0) and torch.equal(c1, c0)  # a 1 x 1 matmul is one product: bitwise the same
    z = torch.zeros((4, 1), dtype=F64)
    for n in range(53):
        z = Phi[:, n, 0] * z + gamma[:, n]
        torch.testing.assert_close(c1[:, n], z, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("targets", [("y1",), ("y1", "y2")])
def test_fused_training_equals_the_reference_loop(targets):
    """fit_mixture with the fused loop: the same loss per epoch and trained weights as the former
    per-step loop (same minibatches, windows and draws), with the simulation term on."""
    data = two_state_samples()
    if targets == ("y1",):
        data = make_samples(Dataset("one", data_frame(data), Schema.from_roles(
            {"u": "input", "v": "input", "y2": "input", "y1": "output"}), 0.1), ["y1"], "simulation")
    o = MoE(scheduler=["v"], batch_size=128, dtype="float64", sim_weight=5.0, shooting_window=3.0,
            max_time_constant=2.0).options
    fits = [fit_mixture(data, {"n_experts": 2, "epochs": 4, "lr": 1e-2}, o, np.random.default_rng(7), fused=f)
            for f in (False, True)]
    np.testing.assert_allclose(fits[1].loss_history, fits[0].loss_history, rtol=1e-10)
    for name, ref in fits[0].weights.items():
        np.testing.assert_allclose(fits[1].weights[name], ref, rtol=1e-8, atol=1e-10, err_msg=name)
    assert fits[1].loss_history[-1] < fits[1].loss_history[0]


def data_frame(samples) -> pd.DataFrame:
    """The segments of two_state_samples back as a frame (to re-declare which columns are outputs)."""
    frames = []
    for s in samples.segments:
        frames.append(pd.DataFrame({"segment": s.id, "time": s.t, "u": s.U[:, 0], "v": s.U[:, 1],
                                    "y1": s.y[:, 0], "y2": s.y[:, 1]}))
    return pd.concat(frames, ignore_index=True)


def test_training_is_deterministic_under_a_seed_on_the_fused_path():
    data = two_state_samples(1)
    o = MoE(scheduler=["v"], batch_size=64, sim_weight=2.0, shooting_window=2.0, max_time_constant=2.0).options
    a, b = (fit_mixture(data, {"n_experts": 2, "epochs": 3}, o, np.random.default_rng(3)) for _ in range(2))
    assert a.loss_history == b.loss_history
    for name in a.weights:
        np.testing.assert_array_equal(a.weights[name], b.weights[name])


def test_tv_derivatives_are_cached_by_content_and_returned_as_copies(monkeypatch):
    """The grid's fits on the same rows solve the TV derivatives once; another alpha, order or signal
    solves again; a caller changing its result cannot change the kept one; prepare is unchanged."""
    data = two_state_samples(2)
    o = MoE(scheduler=["v"]).options
    derivatives.clear_cache()
    calls = []
    solve = derivatives.differentiate
    monkeypatch.setattr(derivatives, "differentiate", lambda *a, **k: calls.append(1) or solve(*a, **k))
    first = prepare(data, o)
    n_first = len(calls)
    assert n_first == len(data.segments)
    again = prepare(data, o)
    assert len(calls) == n_first  # from the cache
    np.testing.assert_array_equal(again.D, first.D)
    t = np.arange(200) * 0.1
    y = [np.sin(t)]
    d1 = derivatives.segment_derivatives(y, [t], 1e-3)
    d1[0][:] = 0.0
    d2 = derivatives.segment_derivatives(y, [t], 1e-3)
    assert np.abs(d2[0]).max() > 0.5  # the kept result was not changed through d1
    n = len(calls)
    derivatives.segment_derivatives(y, [t], 2e-3)
    derivatives.segment_derivatives(y, [t], 1e-3, order=1)
    derivatives.segment_derivatives([np.cos(t)], [t], 1e-3)
    assert len(calls) == n + 3
    derivatives.segment_derivatives(y, [t], 1e-3, cache=False)
    assert len(calls) == n + 4
    uncached = derivatives.segment_derivatives(y, [t], 1e-3, cache=False)
    np.testing.assert_array_equal(uncached[0], d2[0])
    assert len(derivatives._cache) <= derivatives.CACHE_SIZE
    derivatives.clear_cache()


def test_short_fits_never_compile_and_the_option_is_declared():
    """compile=True (the default) compiles only fits of at least COMPILE_MIN_STEPS steps."""
    assert MoE().options["compile"] is True
    calls = []
    real = tr.compiled_step_loss
    try:
        tr.compiled_step_loss = lambda: calls.append(1) or real()
        fit_mixture(two_state_samples(), {"epochs": 2}, MoE(scheduler=["v"]).options, np.random.default_rng(0))
    finally:
        tr.compiled_step_loss = real
    assert calls == []


@pytest.mark.slow
def test_compiled_step_equals_eager_training():
    """Where torch.compile works: the compiled step trains to the eager loop's losses and weights
    (float64; the compiled kernels may sum in another order). About a minute of compiling."""
    data = two_state_samples()
    o = MoE(scheduler=["v"], batch_size=128, dtype="float64", sim_weight=5.0, shooting_window=3.0,
            max_time_constant=2.0).options
    saved = tr.COMPILE_MIN_STEPS
    tr.COMPILE_MIN_STEPS = 0
    try:
        fits = [fit_mixture(data, {"n_experts": 2, "epochs": 3, "lr": 1e-2}, {**o, "compile": c},
                            np.random.default_rng(7)) for c in (False, True)]
    finally:
        tr.COMPILE_MIN_STEPS = saved
    if tr.compiled_step_loss() is None:
        pytest.skip("torch.compile unavailable: the step ran eagerly")
    np.testing.assert_allclose(fits[1].loss_history, fits[0].loss_history, rtol=1e-9)
    for name, ref in fits[0].weights.items():
        np.testing.assert_allclose(fits[1].weights[name], ref, rtol=1e-6, atol=1e-9, err_msg=name)
