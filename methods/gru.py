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

from typing import TYPE_CHECKING, Any

from enginebench.methods.neural_sim import NetConfig, NeuralSimFit, NeuralSimulator, declaration

if TYPE_CHECKING:
    from torch import nn

NAME = "gru"


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
        from enginebench.methods.neural_nets import GRUNet  # torch: imported when a network is built

        return GRUNet(config)

    def model_facts(self, net: nn.Module, fitted: NeuralSimFit) -> dict[str, Any]:
        return {"model": "h(t) = GRU(u(t), h(t-1)), y = W h + b, h(t0-1) = tanh(encoder(init window)); "
                         "standardised signals"}
