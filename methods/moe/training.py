"""Training: the turboshaft-moe paper's collaborative + competitive loss on the TV derivatives, with Adam, from the
least-squares warm start; optionally plus the open-loop simulation error of short training windows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch

from enginebench.errors import MethodError
from enginebench.methods.moe.fitted import MoEFitted, torch_dtype
from enginebench.methods.moe.model import MixtureOfExperts, moe_loss
from enginebench.methods.moe.options import SHOOTING_WINDOW_SAMPLES, resolve_params, window_steps
from enginebench.methods.moe.preprocess import Prepared, margin_matrix, prepare
from enginebench.methods.moe.simulation import _Sim
from enginebench.methods.moe.warmstart import lstsq_coefficients, warm_start
from enginebench.methods.numerics.device import cpu_threads, resolve_device
from enginebench.samples import Samples


def fit_mixture(
    train: Samples, params: Mapping[str, Any], o: Mapping[str, Any], rng: np.random.Generator, fused: bool = True,
) -> MoEFitted:
    """Prepare the training samples, start every expert at the least-squares model, train, and pack the result.

    ``fused=False`` trains on the former per-step loop (``_train``'s reference path, for benchmarks)."""
    hp = resolve_params(params)
    return fit_mixture_path(train, params, o, rng, [hp["epochs"]], fused)[0]


def fit_mixture_path(
    train: Samples, params: Mapping[str, Any], o: Mapping[str, Any], rng: np.random.Generator,
    checkpoints: Sequence[int], fused: bool = True,
) -> list[MoEFitted]:
    """One training run of ``params`` packed after each number of epochs in ``checkpoints`` (ascending).

    The model after e epochs is the model ``fit_mixture`` returns for ``epochs = e`` with the same
    draws (``rng`` gives the torch seed, then the probe points, before training), so model selection
    scores several epoch counts of one run: early stopping chosen on the validation simulation error.
    """
    run = start_run(train, params, o, rng, checkpoints)
    with cpu_threads(o["cpu_threads"], run.device):
        shoot = None
        if o["sim_weight"] > 0:
            if o["scheduler_state"]:
                raise MethodError(
                    "method 'moe': sim_weight > 0 trains on simulated LPV trajectories; a state-scheduled "
                    "(quasi-LPV) model is not supported: set scheduler_state=False or sim_weight=0"
                )
            p = run.prepared
            shoot = _Shooting(p.Us, p.Z, p.T, o["shooting_window"], p.si, p.ei, p.stats["d_scale"])
        _train(run.net, run.prepared.V, run.prepared.X, run.prepared.D, run.hp, o, run.gen, run.device, run.dtype,
               shoot, fused=fused, compile=bool(o.get("compile", True)), checkpoints=run.checkpoints())
    run.net.eval()
    return run.packed


@dataclass
class Run:
    """One training run set up and not yet trained: its network at the warm start, its torch generator
    (the minibatch order), and ``pack``, which stores the network after an epoch count as a ``MoEFitted``."""

    hp: dict[str, Any]
    prepared: Prepared
    net: MixtureOfExperts
    gen: torch.Generator
    device: torch.device
    dtype: torch.dtype
    epochs: tuple[int, ...]
    pack: Callable[[list[float]], None]
    packed: list[MoEFitted]

    def checkpoints(self) -> dict[int, Callable[[list[float]], None]]:
        """Epoch count -> ``pack``, as ``_train`` takes them."""
        return {e: self.pack for e in self.epochs}


def start_run(
    train: Samples, params: Mapping[str, Any], o: Mapping[str, Any], rng: np.random.Generator,
    checkpoints: Sequence[int], prepared: Prepared | None = None,
) -> Run:
    """Prepare the training samples (or take ``prepared``), draw the torch seed and the probe points from
    ``rng``, build the network and start every expert at the least-squares model."""
    hp = resolve_params({**params, "epochs": max(checkpoints)})
    p = prepare(train, o) if prepared is None else prepared
    sign, d_scale, V, X = p.sign, p.stats["d_scale"], p.V, p.X
    margin = margin_matrix(o["max_time_constant"], sign, d_scale, train.target_names)
    device, dtype = resolve_device(o["device"], "method 'moe'"), torch_dtype(o["dtype"])
    gen = torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))
    n_probe = min(o["probe_points"], len(V))
    probe = V[np.sort(rng.choice(len(V), size=n_probe, replace=False))]
    net = MixtureOfExperts(
        V.shape[1], len(train.target_names), X.shape[1], hp["n_experts"], o["expert_hidden"], hp["gate_hidden"],
        torch.as_tensor(sign), hp["k"], gen, dtype, torch.as_tensor(margin),
    )
    theta = lstsq_coefficients(X, p.D, sign, margin)
    warm_start(net, theta, sign, hp["k"], margin)
    init_info: dict[str, Any] = {"init": "lstsq", "theta": theta.tolist()}
    net = net.to(device)
    packed: list[MoEFitted] = []

    def pack(history: list[float]) -> None:
        check_finite_loss(history, hp["lr"])
        weights = {k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}
        if o["clip_schedulers"]:
            weights["v_lo"] = V.min(0).astype(weights["v_lo"].dtype)
            weights["v_hi"] = V.max(0).astype(weights["v_hi"].dtype)
        packed.append(MoEFitted(
            params={**hp, "epochs": len(history)}, options=dict(o), input_names=tuple(train.input_names),
            target_names=tuple(train.target_names), scheduler_inputs=tuple(p.scheduler_inputs),
            expert_inputs=tuple(p.expert_inputs), sign=sign, **p.stats, weights=weights, probe=probe,
            loss_history=list(history), derived=p.derived, init_info=init_info,
        ))

    return Run(hp, p, net, gen, device, dtype, tuple(sorted(int(e) for e in checkpoints)), pack, packed)


class _Shooting:
    """Training windows for the simulation-error term: every segment cut into windows of
    ``window_s`` seconds (``SHOOTING_WINDOW_SAMPLES`` steps when None) from a random offset per
    epoch, each simulated open loop from its measured first value (multiple shooting), batched
    over windows."""

    def __init__(self, Us: Sequence[np.ndarray], Zs: Sequence[np.ndarray], Ts: Sequence[np.ndarray],
                 window_s: float | None, si: list[int], ei: list[int], d_scale: np.ndarray) -> None:
        self.Us, self.Zs, self.Ts, self.si, self.ei, self.d_scale = Us, Zs, Ts, si, ei, d_scale
        h = float(np.median(np.concatenate([np.diff(t) for t in Ts if len(t) > 1])))
        steps = window_steps(window_s, h, SHOOTING_WINDOW_SAMPLES)
        self.width = int(max(2, min(steps + 1, min(len(z) for z in Zs))))

    def cut(self, gen: torch.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(U (S, W, n_u), H (S, W-1), Z (S, W, k)) of this epoch's windows."""
        W = self.width
        offset = int(torch.randint(0, W, (1,), generator=gen))
        starts = [
            (j, a) for j, z in enumerate(self.Zs) for a in range(offset if len(z) - offset >= W else 0, len(z) - W + 1, W)
        ]
        idx = np.arange(W)
        U = np.stack([self.Us[j][a + idx] for j, a in starts])
        Z = np.stack([self.Zs[j][a + idx] for j, a in starts])
        H = np.stack([np.diff(self.Ts[j][a + idx]) for j, a in starts])
        return U, H, Z

    def loss(self, net: MixtureOfExperts, o: dict[str, Any], U: torch.Tensor, H: torch.Tensor, Z: torch.Tensor,
             fused: bool = True, d_scale: torch.Tensor | None = None) -> torch.Tensor:
        """Mean squared simulation error (standardised units) of windows ``U``, ``H``, ``Z``
        (``fused``: ``_Sim``'s one-network-call path; False its reference path). ``d_scale``:
        the derivative scale as a tensor of Z's dtype and device (made here when None)."""
        inf = torch.full((Z.shape[-1],), torch.inf, dtype=Z.dtype, device=Z.device)
        if d_scale is None:
            d_scale = torch.as_tensor(self.d_scale, dtype=Z.dtype, device=Z.device)
        sim = _Sim(
            options=o, n_experts=net.n_experts, net=net, U=U, H=H, lo=-inf, hi=inf, d_scale=d_scale,
            si=self.si, ei=self.ei, record_gate=False, fused=fused,
        )
        return ((sim.rollout(Z[:, 0]) - Z) ** 2).mean()


COMPILE_MIN_STEPS = 20_000
"""Gradient steps (epochs x minibatches) from which ``compile=True`` compiles the step: torch.compile
takes about a minute on two busy cores and pays back only over long fits (see docs/benchmarks.md)."""


def step_loss(
    net: MixtureOfExperts, v: torch.Tensor, x: torch.Tensor, d: torch.Tensor, beta: torch.Tensor,
    competitive: str, windows: tuple[torch.Tensor, ...] | None, sim_weight: torch.Tensor,
    o: dict[str, Any], shoot: _Shooting | None, d_scale: torch.Tensor | None, fused: bool = True,
) -> torch.Tensor:
    """One minibatch's loss: the turboshaft-moe paper's loss of rows (v, x, d) with ``beta`` = (beta1, beta2), plus
    ``sim_weight`` times the simulation error of ``windows`` = (U, H, Z) when given."""
    f, alpha = net(v, x)
    loss = moe_loss(f, alpha, d, beta[0], beta[1], competitive)
    if windows is not None and shoot is not None:
        loss = loss + sim_weight * shoot.loss(net, o, *windows, fused=fused, d_scale=d_scale)
    return loss


_compiled: dict[str, Any] = {}


def compiled_step_loss() -> Any:
    """``step_loss`` through torch.compile (made once per process, so the grid's fits share its
    compiled graphs), or None where torch.compile is missing."""
    if "fn" not in _compiled:
        compile_fn = getattr(torch, "compile", None)
        _compiled["fn"] = None if compile_fn is None else compile_fn(step_loss)
    return _compiled["fn"]


def _train(
    net: MixtureOfExperts, V: np.ndarray, X: np.ndarray, D: np.ndarray, hp: dict[str, Any], o: dict[str, Any],
    gen: torch.Generator, device: torch.device, dtype: torch.dtype, shoot: _Shooting | None = None,
    fused: bool = True, compile: bool = False, checkpoints: Mapping[int, Callable[[list[float]], None]] | None = None,
) -> list[float]:
    """Adam on the turboshaft-moe paper's loss with shuffled minibatches; returns the mean loss per epoch.

    With ``shoot`` (option sim_weight > 0) every step adds sim_weight times the simulation error of
    a share of the epoch's windows (each window once per epoch): the derivative loss weights
    the fast dynamics, the simulation error the slow pole and the static gains that an
    open-loop prediction accumulates.

    ``fused`` (the default) shuffles each epoch's rows and windows once into contiguous
    tensors that every step slices (no per-step gathers) and simulates windows on
    ``_Sim``'s fused path; the minibatches, their order and the random draws are the same
    as with ``fused=False`` (the former loop, kept as the reference for tests and benchmarks).
    ``compile`` runs each step's loss through torch.compile when the fit has at least
    ``COMPILE_MIN_STEPS`` steps (not bitwise equal to eager: the compiled kernels sum in another
    order); where torch.compile is missing or fails, the step runs eagerly. ``checkpoints``: epoch
    count -> a function called with the history after that epoch (``fit_mixture_path`` packs the
    model there); training stops after the last checkpoint's epoch when it comes before ``epochs``.
    """
    Vt, Xt, Dt = (torch.as_tensor(a, dtype=dtype, device=device) for a in (V, X, D))
    opt = torch.optim.Adam(net.parameters(), lr=hp["lr"])
    n, bs = len(Vt), int(o["batch_size"])
    n_steps = -(-n // bs)
    beta = torch.tensor([hp["beta1"], hp["beta2"]], dtype=dtype, device=device)
    sim_weight = torch.tensor(float(o["sim_weight"]), dtype=dtype, device=device)
    dsc = None if shoot is None else torch.as_tensor(shoot.d_scale, dtype=dtype, device=device)
    loss_fn = step_loss
    if compile and fused and n_steps * hp["epochs"] >= COMPILE_MIN_STEPS:
        loss_fn = compiled_step_loss() or step_loss
    history: list[float] = []
    checkpoints = dict(checkpoints or {})
    last = max(checkpoints, default=hp["epochs"])
    net.train()
    for _ in range(min(hp["epochs"], last)):
        perm = torch.randperm(n, generator=gen).to(device)
        if shoot is not None:
            Uw, Hw, Zw = (torch.as_tensor(a, dtype=dtype, device=device) for a in shoot.cut(gen))
            wperm = torch.randperm(len(Zw), generator=gen).to(device)
            per = -(-len(Zw) // n_steps)
            if fused:
                Uw, Hw, Zw = Uw[wperm], Hw[wperm], Zw[wperm]
        if fused:
            Vp, Xp, Dp = Vt[perm], Xt[perm], Dt[perm]
        total = torch.zeros((), dtype=dtype, device=device)
        for step, a in enumerate(range(0, n, bs)):
            if fused:
                v, x, d = Vp[a : a + bs], Xp[a : a + bs], Dp[a : a + bs]
            else:
                idx = perm[a : a + bs]
                v, x, d = Vt[idx], Xt[idx], Dt[idx]
            windows = None
            if shoot is not None:
                lo, hi = step * per, min((step + 1) * per, len(Zw))
                if hi > lo:
                    if fused:
                        windows = (Uw[lo:hi], Hw[lo:hi], Zw[lo:hi])
                    else:
                        w = wperm[lo:hi]
                        windows = (Uw[w], Hw[w], Zw[w])
            args = (net, v, x, d, beta, o["competitive"], windows, sim_weight, o, shoot, dsc, fused)
            if loss_fn is step_loss:
                loss = step_loss(*args)
            else:
                try:
                    loss = loss_fn(*args)
                except Exception:  # noqa: BLE001 - torch.compile is an optimisation: without a working compiler, eager
                    loss_fn = step_loss
                    loss = step_loss(*args)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.detach() * len(v)
        history.append(float(total) / n)
        if len(history) in checkpoints:
            checkpoints[len(history)](history)
    net.eval()
    check_finite_loss(history, hp["lr"])
    return history


def check_finite_loss(history: list[float], lr: float) -> None:
    """MethodError when the last epoch's loss is not finite (training diverged)."""
    if not np.isfinite(history[-1]):
        raise MethodError(f"method 'moe': training diverged (loss {history[-1]}); lower lr={lr} or check the data")
