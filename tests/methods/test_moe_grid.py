"""A MoE grid trained side by side (``batch_grid``, methods/moe/grid.py) gives each run the model it gets
alone: the same draws, weights, loss history and probe points (float64, eager: equal to rounding), with
runs of fewer experts padded and unaffected; a diverged run fails as alone; sim_weight > 0 and
``batch_grid = false`` train one by one."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.errors import MethodError
from enginebench.methods.moe import MoE
from enginebench.methods.moe import grid as grid_training
from enginebench.methods.moe import training

from helpers import two_state_samples

GRID = [
    {"n_experts": m, "beta2": b2, "lr": lr, "epochs": e}
    for m in (2, 3) for b2 in (0.1, 1.0) for lr in (1e-3, 1e-2) for e in (2, 4)
]


def fit_both(grid, **options):
    """fit_grid's models side by side and one by one, from the same generator seed."""
    return {flag: dict(MoE(scheduler=["v"], batch_size=128, dtype="float64", batch_grid=flag, **options)
                       .fit_grid(two_state_samples(), grid, np.random.default_rng(3)))
            for flag in (True, False)}


def test_side_by_side_runs_equal_one_by_one_runs():
    got = fit_both(GRID)
    assert sorted(got[True]) == sorted(got[False]) == list(range(len(GRID)))
    for i, params in enumerate(GRID):
        a, b = got[True][i], got[False][i]
        assert a.params == b.params and a.params["n_experts"] == params["n_experts"]
        assert len(a.loss_history) == params["epochs"]
        np.testing.assert_allclose(a.loss_history, b.loss_history, rtol=1e-12)
        np.testing.assert_array_equal(a.probe, b.probe)
        assert a.weights.keys() == b.weights.keys()
        for name, w in b.weights.items():
            assert a.weights[name].shape == w.shape, name  # padded experts removed again
            np.testing.assert_allclose(a.weights[name], w, rtol=1e-10, atol=1e-12, err_msg=name)
    # the runs differ from one another (each its own draws, rate and loss weights)
    assert not np.allclose(got[True][0].weights["w2"], got[True][2].weights["w2"])


def test_a_single_run_and_simulation_error_training_go_one_by_one(monkeypatch):
    calls = []
    monkeypatch.setattr(grid_training, "train_side_by_side", lambda runs, o: calls.append(len(runs)))
    fit_both(GRID[:2])  # one run (two epoch counts of it)
    fit_both(GRID[:4], sim_weight=1.0, shooting_window=2.0)  # two runs with the simulation term
    assert calls == []
    got = fit_both(GRID[:4])  # two derivative-loss runs: side by side (the stub packs no model)
    assert calls == [2] and got[True] == {} and len(got[False]) == 4


def test_a_diverging_run_fails_as_it_does_alone():
    grid = [{"n_experts": 2, "lr": 1e-3, "epochs": 2}, {"n_experts": 2, "lr": 1e30, "epochs": 2}]
    messages = []
    for flag in (True, False):
        with pytest.raises(MethodError) as err:
            dict(MoE(scheduler=["v"], batch_size=128, batch_grid=flag).fit_grid(
                two_state_samples(), grid, np.random.default_rng(0)))
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert messages[0].startswith("method 'moe': training diverged (loss ") and "lower lr=1e+30" in messages[0]


def test_adam_of_stacked_runs_equals_torch_adam_per_run():
    import torch

    g = torch.Generator().manual_seed(0)
    start = torch.randn((2, 5), generator=g, dtype=torch.float64)
    grads = [torch.randn((2, 5), generator=g, dtype=torch.float64) for _ in range(4)]
    flat = start.clone().requires_grad_()
    adam = grid_training._Adam(flat, [1e-3, 0.5])
    for grad in grads:
        flat.grad = grad.clone()
        adam.step()
    for j, lr in enumerate((1e-3, 0.5)):
        p = start[j].clone().requires_grad_()
        opt = torch.optim.Adam([p], lr=lr)
        for grad in grads:
            p.grad = grad[j].clone()
            opt.step()
        torch.testing.assert_close(flat.detach()[j], p.detach(), rtol=0, atol=1e-15)


@pytest.mark.slow
def test_compiled_side_by_side_equals_eager(monkeypatch):
    """Where torch.compile works, the compiled batched loss trains to the eager one's models (float64)."""
    monkeypatch.setattr(grid_training, "COMPILE_MIN_STEPS", 0)
    monkeypatch.setattr(training, "COMPILE_MIN_STEPS", 0)
    grid = GRID[:4]
    models = {c: dict(MoE(scheduler=["v"], batch_size=128, dtype="float64", compile=c)
                      .fit_grid(two_state_samples(), grid, np.random.default_rng(3))) for c in (False, True)}
    for i in range(len(grid)):
        np.testing.assert_allclose(models[True][i].loss_history, models[False][i].loss_history, rtol=1e-9)
        for name, ref in models[False][i].weights.items():
            np.testing.assert_allclose(models[True][i].weights[name], ref, rtol=1e-6, atol=1e-9, err_msg=name)


def test_a_failing_compiler_falls_back_to_the_eager_loss(monkeypatch):
    """torch.compile is an optimisation: when its function raises, the step runs eagerly, same models."""
    import torch

    def broken(fn, **kwargs):
        def raising(*args, **kw):
            raise RuntimeError("no compiler here")
        return raising

    monkeypatch.setattr(grid_training, "COMPILE_MIN_STEPS", 0)
    monkeypatch.setattr(grid_training, "_losses", {})
    monkeypatch.setattr(torch, "compile", broken)
    grid = GRID[:4]
    models = {c: dict(MoE(scheduler=["v"], batch_size=128, dtype="float64", compile=c)
                      .fit_grid(two_state_samples(), grid, np.random.default_rng(3))) for c in (True, False)}
    for i in range(len(grid)):
        assert models[True][i].loss_history == models[False][i].loss_history
        for name, ref in models[False][i].weights.items():
            np.testing.assert_array_equal(models[True][i].weights[name], ref, err_msg=name)


def test_per_step_gathers_when_the_shuffled_copy_would_be_large(monkeypatch):
    """Above SHUFFLED_COPY_BYTES the minibatches are gathered per step: the same rows, the same models."""
    grid = GRID[:4]
    ref = fit_both(grid)[True]
    monkeypatch.setattr(grid_training, "SHUFFLED_COPY_BYTES", 0)
    got = fit_both(grid)[True]
    for i in range(len(grid)):
        assert got[i].loss_history == ref[i].loss_history
        for name, w in ref[i].weights.items():
            np.testing.assert_array_equal(got[i].weights[name], w, err_msg=name)
