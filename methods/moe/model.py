"""The torch module of the physics-structured mixture of experts (turboshaft-moe, eqs. 3-6).

Each expert i is an LPV model: an MLP g_i of the schedulers v gives the coefficient
matrix G_i(v) (k outputs x q regressors) of dz/dt = G_i(v) [z; u; 1]. Chosen
coefficients carry a sign through h(x) = +-log(1 + e^{kx}) / k, so e.g. every expert's
own-state coefficient is negative for every v (frozen stability, turboshaft-moe appendix).
A softmax MLP gate alpha(v) mixes the experts. All experts are evaluated at once with
batched weights (no Python loop over experts).
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F


def _uniform(shape: tuple[int, ...], fan_in: int, gen: torch.Generator, dtype: torch.dtype) -> nn.Parameter:
    """U(-1/sqrt(fan_in), 1/sqrt(fan_in)) drawn from ``gen`` (torch's default linear init)."""
    bound = 1.0 / math.sqrt(max(fan_in, 1))
    return nn.Parameter((torch.rand(shape, generator=gen, dtype=dtype) * 2.0 - 1.0) * bound)


def signed_softplus(x: torch.Tensor, sign: torch.Tensor, k: float, margin: torch.Tensor | float = 0.0) -> torch.Tensor:
    """The turboshaft-moe paper's eq. 6 where ``sign`` is +-1, identity where it is 0.

    ``margin`` (>= 0, broadcast like ``sign``) shifts a constrained coefficient away from 0:
    sign (margin + log(1 + e^{kx}) / k), so its magnitude never falls below the margin
    (a frozen-stability margin on an own-state coefficient: its time constant is bounded).
    """
    return torch.where(sign != 0, sign * (margin + F.softplus(x, beta=k)), x)


class MixtureOfExperts(nn.Module):
    """Gate and LPV experts over ``n_sched`` scheduler inputs.

    ``sign`` is a (k, q) tensor of -1 / 0 / +1: the constrained sign of each coefficient
    (0 = free); ``margin`` an optional (k, q) tensor >= 0, the least magnitude of each
    constrained coefficient (``signed_softplus``). Parameters are drawn from the CPU generator ``gen`` for determinism.
    """

    def __init__(
        self,
        n_sched: int,
        n_out: int,
        n_reg: int,
        n_experts: int,
        expert_hidden: int,
        gate_hidden: int,
        sign: torch.Tensor,
        k: float,
        gen: torch.Generator,
        dtype: torch.dtype = torch.float32,
        margin: torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        if sign.shape != (n_out, n_reg):
            raise ValueError(f"sign must have shape ({n_out}, {n_reg}), got {tuple(sign.shape)}")
        self.n_out, self.n_reg, self.n_experts, self.k = n_out, n_reg, n_experts, float(k)
        m, h, p = n_experts, expert_hidden, n_out * n_reg
        self.w1 = _uniform((m, n_sched, h), n_sched, gen, dtype)
        self.b1 = _uniform((m, h), n_sched, gen, dtype)
        self.w2 = _uniform((m, h, p), h, gen, dtype)
        self.b2 = _uniform((m, p), h, gen, dtype)
        self.gw1 = _uniform((n_sched, gate_hidden), n_sched, gen, dtype)
        self.gb1 = _uniform((gate_hidden,), n_sched, gen, dtype)
        self.gw2 = _uniform((gate_hidden, m), gate_hidden, gen, dtype)
        self.gb2 = _uniform((m,), gate_hidden, gen, dtype)
        self.register_buffer("sign", sign.to(dtype))
        margin = torch.zeros((n_out, n_reg), dtype=dtype) if margin is None else margin.to(dtype)
        if margin.shape != (n_out, n_reg) or bool((margin < 0).any()):
            raise ValueError(f"margin must be a ({n_out}, {n_reg}) tensor >= 0, got shape {tuple(margin.shape)}")
        self.register_buffer("margin", margin)
        # schedulers are clamped to [v_lo, v_hi] (the training range once fitted): outside the
        # identified range the scheduled coefficients and the gate saturate instead of extrapolating
        self.register_buffer("v_lo", torch.full((n_sched,), -torch.inf, dtype=dtype))
        self.register_buffer("v_hi", torch.full((n_sched,), torch.inf, dtype=dtype))

    def clamp(self, v: torch.Tensor) -> torch.Tensor:
        """Schedulers held inside [v_lo, v_hi]."""
        return torch.maximum(torch.minimum(v, self.v_hi), self.v_lo)

    def coefficients(self, v: torch.Tensor) -> torch.Tensor:
        """Every expert's coefficient matrix at schedulers ``v`` (..., s) -> (..., M, k, q)."""
        hid = torch.tanh(torch.einsum("...s,msh->...mh", self.clamp(v), self.w1) + self.b1)
        raw = torch.einsum("...mh,mhp->...mp", hid, self.w2) + self.b2
        raw = raw.reshape(*raw.shape[:-1], self.n_out, self.n_reg)
        return signed_softplus(raw, self.sign, self.k, self.margin)

    def gate(self, v: torch.Tensor) -> torch.Tensor:
        """Softmax gate weights (..., M) at schedulers ``v`` (..., s)."""
        return torch.softmax(torch.tanh(self.clamp(v) @ self.gw1 + self.gb1) @ self.gw2 + self.gb2, dim=-1)

    def forward(self, v: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Expert predictions (n, M, k) of regressors ``x`` (n, q) and the gate (n, M)."""
        f = torch.einsum("nmkq,nq->nmk", self.coefficients(v), x)
        return f, self.gate(v)

    def mixed(self, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Gated coefficient matrix sum_i alpha_i G_i(v) (..., k, q) and the gate (..., M)."""
        alpha = self.gate(v)
        return torch.einsum("...m,...mkq->...kq", alpha, self.coefficients(v)), alpha


def moe_loss(
    f: torch.Tensor, alpha: torch.Tensor, target: torch.Tensor, beta1: float, beta2: float, competitive: str = "alpha2"
) -> torch.Tensor:
    """The turboshaft-moe paper's eq. 4: beta1 |y - sum_i a_i f_i|^2 + beta2 sum_i w_i |y - f_i|^2, mean over rows.

    ``w_i = alpha_i^2`` as printed in the paper (eq. 4c) or ``alpha_i`` (Jacobs et al.'s
    competitive weighting) with ``competitive="alpha"``.
    """
    mix = torch.einsum("nm,nmk->nk", alpha, f)
    coll = ((target - mix) ** 2).sum(-1)
    weight = alpha**2 if competitive == "alpha2" else alpha
    comp = (weight * ((target[:, None, :] - f) ** 2).sum(-1)).sum(-1)
    return (beta1 * coll + beta2 * comp).mean()
