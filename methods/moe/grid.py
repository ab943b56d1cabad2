"""A grid's training runs trained side by side: one Adam loop over all runs' networks at once.

A MoE grid (experts x beta2 x lr, say) is a dozen independent training runs on the same
rows. Each run's step is a few small tensor operations on 512 rows, so a run spends most of
its time in per-operation overhead, not arithmetic. Here the runs' networks are stacked
along a leading axis and every step evaluates all of them in one vmapped call: each run keeps
its own initial weights, minibatch order (its own torch generator), loss weights and learning
rate, and since the runs share no parameter, the gradient of the summed loss is each run's
own gradient. Runs with fewer experts are padded to the group's largest count with experts
whose gate logit is a very large negative number: their gate weight is exactly 0, so they add
nothing to the loss and receive zero gradients (Adam leaves them where they are).

Runs are grouped by what changes the network's shape or a compiled graph (gate width, softplus
sharpness ``k``, checkpoints). The models equal the one-by-one runs' up to the summation order
of the batched kernels (tested in float64); ``batch_grid = false`` trains them one by one.
Only the derivative loss is batched: with ``sim_weight > 0`` each run trains on its own.
"""

from __future__ import annotations

import math
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import torch
from torch.func import functional_call, vmap

from enginebench.methods.moe.fitted import MoEFitted
from enginebench.methods.moe.model import MixtureOfExperts, moe_loss
from enginebench.methods.moe.preprocess import prepare
from enginebench.methods.moe.training import (
    COMPILE_MIN_STEPS, Run, _train, check_finite_loss, fit_mixture_path, start_run,
)
from enginebench.methods.numerics.device import cpu_threads
from enginebench.samples import Samples

SHUFFLED_COPY_BYTES = 1 << 30
"""Largest per-epoch shuffled copy of the runs' training rows (runs x rows x columns); beyond it each
step gathers its minibatches instead (the same rows in the same order, less memory)."""

EXPERT_AXIS = {"w1": 0, "b1": 0, "w2": 0, "b2": 0, "gw2": 1, "gb2": 0}
"""The axis along experts of each parameter of ``MixtureOfExperts`` (the gate's first layer has none)."""


def fit_mixture_grid(
    train: Samples, runs: Sequence[tuple[Mapping[str, Any], Sequence[int]]], o: Mapping[str, Any],
    rng: np.random.Generator,
) -> Iterator[tuple[int, list[MoEFitted]]]:
    """``(index in runs, models)`` for every run ``(params, checkpoints)``: each run's models packed at its
    checkpoints, as ``fit_mixture_path`` gives them. Every run draws from ``rng`` in the order of ``runs``
    before any training, as one-by-one runs do, so both paths start from the same weights."""
    if o["sim_weight"] > 0 or not o["batch_grid"] or len(runs) < 2:
        for j, (params, checkpoints) in enumerate(runs):
            yield j, fit_mixture_path(train, params, o, rng, checkpoints)
        return
    prepared = prepare(train, o)
    started = [start_run(train, params, o, rng, checkpoints, prepared) for params, checkpoints in runs]
    groups: dict[tuple[Any, ...], list[int]] = {}
    for j, run in enumerate(started):
        groups.setdefault((run.hp["gate_hidden"], run.hp["k"], run.epochs), []).append(j)
    with cpu_threads(o["cpu_threads"], started[0].device):
        for members in groups.values():
            group = [started[j] for j in members]
            if len(group) == 1:
                run = group[0]
                _train(run.net, prepared.V, prepared.X, prepared.D, run.hp, dict(o), run.gen, run.device, run.dtype,
                       compile=bool(o["compile"]), checkpoints=run.checkpoints())
            else:
                train_side_by_side(group, o)
            for j in members:
                started[j].net.eval()
                yield j, started[j].packed


def train_side_by_side(runs: Sequence[Run], o: Mapping[str, Any]) -> None:
    """Train ``runs`` (same prepared rows, gate width, ``k`` and checkpoints) in one loop; each run's
    ``pack`` is called at its checkpoints with its own loss history, its network holding its weights."""
    first = runs[0]
    p, device, dtype = first.prepared, first.device, first.dtype
    m = max(run.net.n_experts for run in runs)
    template = _template(first.net, m, device)
    names, shapes = _layout(template)
    flat = torch.stack([_flatten(run.net, m, names, shapes) for run in runs]).requires_grad_()
    buffers = {name: b for name, b in first.net.named_buffers()}
    adam = _Adam(flat, [run.hp["lr"] for run in runs])
    beta = torch.tensor([[run.hp["beta1"], run.hp["beta2"]] for run in runs], dtype=dtype, device=device)
    Vt, Xt, Dt = (torch.as_tensor(a, dtype=dtype, device=device) for a in (p.V, p.X, p.D))
    n, bs, epochs = len(Vt), int(o["batch_size"]), max(first.epochs)
    compile = bool(o["compile"]) and -(-n // bs) * epochs >= COMPILE_MIN_STEPS
    loss_fn = _loss(template, names, shapes, o["competitive"], compile)
    histories: list[list[float]] = [[] for _ in runs]
    width = Vt.shape[1] + Xt.shape[1] + Dt.shape[1]
    whole_epoch = len(runs) * n * width * Vt.element_size() <= SHUFFLED_COPY_BYTES
    for epoch in range(1, epochs + 1):
        perm = torch.stack([torch.randperm(n, generator=run.gen) for run in runs]).to(device)
        if whole_epoch:  # every run's rows shuffled once, then sliced; else gathered per step
            Vp, Xp, Dp = Vt[perm], Xt[perm], Dt[perm]
        total = torch.zeros(len(runs), dtype=dtype, device=device)
        for a in range(0, n, bs):
            if whole_epoch:
                v, x, d = Vp[:, a : a + bs], Xp[:, a : a + bs], Dp[:, a : a + bs]
            else:
                rows = perm[:, a : a + bs]
                v, x, d = Vt[rows], Xt[rows], Dt[rows]
            try:
                losses = loss_fn(flat, buffers, v, x, d, beta)
            except Exception:  # noqa: BLE001 - torch.compile is an optimisation: without a working compiler, eager
                loss_fn = _loss(template, names, shapes, o["competitive"], False)
                losses = loss_fn(flat, buffers, v, x, d, beta)
            flat.grad = None
            losses.sum().backward()
            adam.step()
            total += losses.detach() * v.shape[1]
        for history, mean in zip(histories, (total / n).tolist()):
            history.append(mean)
        if epoch in first.epochs:
            for j, run in enumerate(runs):
                _unflatten_into(run.net, flat.detach()[j], names, shapes)
                run.pack(histories[j])
    for history, run in zip(histories, runs):
        check_finite_loss(history, run.hp["lr"])


def _template(net: MixtureOfExperts, m: int, device: torch.device) -> MixtureOfExperts:
    """A network of ``net``'s shape with ``m`` experts (its own weights are never used)."""
    n_sched, h = net.w1.shape[1], net.w1.shape[2]
    return MixtureOfExperts(  # buffers copied: the runs' own are arguments of the loss, never aliases of these
        n_sched, net.n_out, net.n_reg, m, h, net.gw1.shape[1], net.sign.detach().cpu().clone(), net.k,
        torch.Generator(), net.sign.dtype, net.margin.detach().cpu().clone(),
    ).to(device)


def _layout(template: MixtureOfExperts) -> tuple[list[str], list[torch.Size]]:
    """Names and shapes of the parameters, in the order of the stacked vectors."""
    named = list(template.named_parameters())
    return [name for name, _ in named], [p.shape for _, p in named]


def _flatten(net: MixtureOfExperts, m: int, names: Sequence[str], shapes: Sequence[torch.Size]) -> torch.Tensor:
    """``net``'s parameters padded to ``m`` experts, as one vector: padded experts have zero weights and a
    gate bias no softmax can pick (their gate weight is exactly 0)."""
    params = dict(net.named_parameters())
    parts = []
    for name, shape in zip(names, shapes):
        t = params[name].detach()
        if name in EXPERT_AXIS and t.shape != shape:
            fill = torch.finfo(t.dtype).min / 4 if name == "gb2" else 0.0
            pad = torch.full(shape, fill, dtype=t.dtype, device=t.device)
            pad.narrow(EXPERT_AXIS[name], 0, t.shape[EXPERT_AXIS[name]]).copy_(t)
            t = pad
        parts.append(t.reshape(-1))
    return torch.cat(parts)


def _views(flat: torch.Tensor, names: Sequence[str], shapes: Sequence[torch.Size]) -> dict[str, torch.Tensor]:
    """Each parameter as a view of a run's vector (the inverse of ``_flatten``, padding kept)."""
    out, at = {}, 0
    for name, shape in zip(names, shapes):
        size = math.prod(shape)
        out[name] = flat[at : at + size].reshape(shape)
        at += size
    return out


def _unflatten_into(net: MixtureOfExperts, flat: torch.Tensor, names: Sequence[str], shapes: Sequence[torch.Size]) -> None:
    """Copy a run's trained vector back into its network, without the padded experts."""
    views = _views(flat, names, shapes)
    with torch.no_grad():
        for name, p in net.named_parameters():
            t = views[name]
            if name in EXPERT_AXIS:
                t = t.narrow(EXPERT_AXIS[name], 0, p.shape[EXPERT_AXIS[name]])
            p.copy_(t)


def _loss_function(template: MixtureOfExperts, names: Sequence[str], shapes: Sequence[torch.Size], competitive: str):
    """losses (runs,) of stacked parameter vectors (runs, P) on each run's minibatch (runs, rows, ...)."""

    def one(flat: torch.Tensor, buffers: dict[str, torch.Tensor], v: torch.Tensor, x: torch.Tensor,
            d: torch.Tensor, beta: torch.Tensor) -> torch.Tensor:
        f, alpha = functional_call(template, {**_views(flat, names, shapes), **buffers}, (v, x))
        return moe_loss(f, alpha, d, beta[0], beta[1], competitive)

    return vmap(one, in_dims=(0, None, 0, 0, 0, 0))


_losses: dict[tuple[Any, ...], Any] = {}


def _loss(template: MixtureOfExperts, names: Sequence[str], shapes: Sequence[torch.Size], competitive: str,
          compile: bool) -> Any:
    """``_loss_function`` for this network shape, through torch.compile when ``compile`` (once per process:
    the grid's groups and the worker's later jobs reuse it; eager where torch.compile is missing). Every
    parameter and buffer is an argument, so one template serves every run of the shape."""
    key = (tuple(names), tuple(shapes), template.k, competitive, template.sign.dtype, str(template.sign.device), compile)
    if key not in _losses:
        fn = _loss_function(template, names, shapes, competitive)
        compile_fn = getattr(torch, "compile", None) if compile else None
        _losses[key] = fn if compile_fn is None else compile_fn(fn, dynamic=False)
    return _losses[key]


class _Adam:
    """torch.optim.Adam's update (default betas and eps, no weight decay) of stacked runs, one learning
    rate per run: the same arithmetic, in the same order, as ``Adam(net.parameters(), lr)`` per run."""

    def __init__(self, flat: torch.Tensor, lrs: Sequence[float], betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.flat, self.betas, self.eps, self.t = flat, betas, eps, 0
        # float64, so that -lr / bias correction rounds to the run's dtype as torch's Python-float step size does
        self.neg_lr = -torch.tensor(list(lrs), dtype=torch.float64, device=flat.device)[:, None]
        self.m = torch.zeros_like(flat, memory_format=torch.preserve_format).detach()
        self.v = torch.zeros_like(self.m)

    @torch.no_grad()
    def step(self) -> None:
        b1, b2 = self.betas
        self.t += 1
        g = self.flat.grad
        self.m.lerp_(g, 1 - b1)
        self.v.mul_(b2).addcmul_(g, g, value=1 - b2)
        bc1, bc2_sqrt = 1 - b1**self.t, (1 - b2**self.t) ** 0.5
        step = (self.neg_lr / bc1).to(self.flat.dtype)
        denom = (self.v.sqrt() / bc2_sqrt).add_(self.eps)
        self.flat.add_((step * self.m) / denom)
