"""``neural-ss``: a neural state-space model in the SUBNET style, trained on the free-run (simulation) loss.

Model, on standardised signals (training mean and SD)::

    x(t0)  = E(u(t0-L..t0-1), y(t0-L..t0-1))             encoder: linear + MLP of the init window
    x(t+1) = A x(t) + B u(t) + f(x(t), u(t))              state transition: linear skip + MLP
    y(t)   = C x(t) + D u(t) + h(x(t), u(t))              output map: linear skip + MLP

f and h are the two heads of one MLP (``layers`` tanh layers of ``hidden`` units, nx + ny
outputs): sharing the hidden layers halves the cost of a simulated step, which is the
whole cost of training. The input part of the first layer and of the linear skip is
computed for all time steps at once; a step is then one product with x, the hidden
layers and one output product.

Training, early stopping, the init window, the batched free run and divergence are
``methods/neural_sim.py`` (shared with ``gru``). Defaults and why:

- nx = 8 states per target (at most 16): a mechanical mode needs 2, the rest is room for
  the nonlinearity and an input filter; the search is that one value unless ``nx`` lists
  several (training is the cost, so nothing is searched by default). 4 states and an
  8-sample encoder window were the first defaults: 8 states and 32 samples lowered
  Silverbox's test RMSE from 5.35 to 3.41 mV and a short tanks-like record's from 0.52 to
  0.25 V (docs/methods.md).
- lags = 4 nx samples (at most a quarter of the shortest record): enough measured
  samples to observe nx states with noise, on slow systems too.
- horizon T = 100 samples (at most half the longest record's fitting part): long enough
  that the loss sees the model's own feedback over many steps, short enough that
  gradients through the recursion stay tame.
- 3,000 Adam steps of 256 subsections, lr 1e-3 decaying to 1e-4, 32 hidden units x 2 layers
  (the linear skip carries the linear dynamics, the MLP only the nonlinearity), early
  stopping on the free-run error of the last 15 % of every training record: a cost
  bounded independently of the record length (minutes on two CPU cores).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from enginebench.methods.neural_sim import NetConfig, NeuralSimFit, NeuralSimulator, declaration

if TYPE_CHECKING:
    from torch import nn

NAME = "neural-ss"


class NeuralSS(NeuralSimulator):
    """Neural state space (SUBNET style): encoder of the init window, linear + MLP transition and output."""

    name = NAME
    summary = ("neural state space (SUBNET style): encoder from the init window, x+ = Ax + Bu + f(x, u), "
               "y = Cx + Du + h(x, u), trained on the free-run loss of subsections (torch)")
    state_per_target = 8
    max_state = 16
    lags_per_state = 4
    declared_options = declaration("state size nx: None = 8 per target, at most 16",
                                   "hidden units of each MLP layer (encoder, state transition and output map)",
                                   lags_per_state=lags_per_state)

    def network(self, config: NetConfig) -> nn.Module:
        from enginebench.methods.neural_nets import StateSpaceNet  # torch: imported when a network is built

        return StateSpaceNet(config)

    def model_facts(self, net: nn.Module, fitted: NeuralSimFit) -> dict[str, Any]:
        """The linear skip's A and its spectral radius (standardised units; the MLP adds to it)."""
        A = net.linear.weight[:, :fitted.config.nx][:fitted.config.nx].detach().double().numpy()
        radius = float(np.abs(np.linalg.eigvals(A)).max()) if A.size else 0.0
        return {"model": "x(t+1) = A x + B u + f(x, u), y = C x + D u + h(x, u), x(t0) = encoder(init window); "
                         "f, h one tanh MLP with two heads; standardised signals",
                "linear_skip_A": A.tolist(), "linear_skip_spectral_radius": radius}
