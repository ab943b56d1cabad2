"""``gru``: a recurrent baseline, a GRU over the inputs started from the init window, trained on the free-run loss.

Model, on standardised signals (training mean and SD)::

    h(t0-1) = tanh(E(u(t0-L..t0-1), y(t0-L..t0-1)))      encoder: linear + MLP of the init window
    h(t)    = GRU(u(t), h(t-1))                           one GRU layer of nx units
    y(t)    = W h(t) + b                                  linear readout

The tanh keeps the encoded state inside the range a GRU's hidden state takes. Training,
early stopping, the init window, the batched free run and divergence are
``methods/neural_sim.py`` (shared with ``neural-ss``): the same loss on the same
subsections, so the two compare as model structures, not as training recipes. The
recurrence runs in torch's fused GRU kernel, so a step costs less than a neural-ss step.

Defaults: nx = 32 hidden units per target (at most 64): a GRU has no linear skip and
needs more units than a state-space model has states; the encoder's MLP has ``hidden``
units; everything else as ``neural-ss``.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from enginebench.methods.neural_sim import Encoder, NetConfig, NeuralSimFit, NeuralSimulator, declaration

NAME = "gru"


class GRUNet(nn.Module):
    """Encoder to the GRU's hidden state, one GRU layer over the inputs, linear readout."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.encoder = Encoder(cfg.lags, cfg.nu, cfg.ny, cfg.nx, cfg.hidden, cfg.layers)
        self.gru = nn.GRU(cfg.nu, cfg.nx, batch_first=True)
        self.readout = nn.Linear(cfg.nx, cfg.ny)

    def forward(self, past_u: torch.Tensor, past_y: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Outputs (batch, T, ny) of a free run over inputs ``u`` (batch, T, nu) from the encoded window."""
        h0 = torch.tanh(self.encoder(past_u, past_y))
        if u.shape[1] == 0:
            return u.new_zeros((u.shape[0], 0, self.readout.out_features))
        states, _ = self.gru(u, h0.unsqueeze(0).contiguous())
        return self.readout(states)


class GRU(NeuralSimulator):
    """GRU baseline: encoder of the init window, GRU over the inputs, linear readout; free-run loss."""

    name = NAME
    summary = ("GRU baseline: hidden state encoded from the init window, one GRU layer over the inputs, linear "
               "readout, trained on the free-run loss of subsections like neural-ss (torch)")
    state_per_target = 32
    max_state = 64
    declared_options = declaration("GRU hidden units nx: None = 32 per target, at most 64",
                                   "hidden units of each layer of the encoder's MLP")

    def network(self, config: NetConfig) -> nn.Module:
        return GRUNet(config)

    def model_facts(self, net: nn.Module, fitted: NeuralSimFit) -> dict[str, Any]:
        return {"model": "h(t) = GRU(u(t), h(t-1)), y = W h + b, h(t0-1) = tanh(encoder(init window)); "
                         "standardised signals"}
