"""The torch networks of ``neural-ss`` and ``gru`` (``methods/neural_sim.py`` trains and simulates them).

A module of its own so that importing the method classes (``enginebench methods list``,
``methods show``) imports no torch: ``NeuralSimulator.network`` imports this module
when a network is first built.
"""

from __future__ import annotations

import torch
from torch import nn

from enginebench.methods.neural_sim import NetConfig


def mlp(n_in: int, n_out: int, hidden: int, layers: int) -> nn.Sequential:
    """``layers`` tanh layers of ``hidden`` units and a linear output layer."""
    parts: list[nn.Module] = []
    width = n_in
    for _ in range(layers):
        parts += [nn.Linear(width, hidden), nn.Tanh()]
        width = hidden
    parts.append(nn.Linear(width, n_out))
    return nn.Sequential(*parts)


class Encoder(nn.Module):
    """Initial state from the window's inputs and outputs: a linear map plus an MLP of the flattened window."""

    def __init__(self, lags: int, nu: int, ny: int, n_state: int, hidden: int, layers: int) -> None:
        super().__init__()
        width = lags * (nu + ny)
        self.linear = nn.Linear(width, n_state)
        self.mlp = mlp(width, n_state, hidden, layers)

    def forward(self, past_u: torch.Tensor, past_y: torch.Tensor) -> torch.Tensor:
        z = torch.cat([past_u, past_y], dim=-1).flatten(1)
        return self.linear(z) + self.mlp(z)


class StateSpaceNet(nn.Module):
    """``neural-ss``: encoder, and one step x(t) -> (x(t+1), y(t)) as a linear skip plus a two-headed MLP."""

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        self.nx, self.ny = cfg.nx, cfg.ny
        self.encoder = Encoder(cfg.lags, cfg.nu, cfg.ny, cfg.nx, cfg.hidden, cfg.layers)
        self.linear = nn.Linear(cfg.nx + cfg.nu, cfg.nx + cfg.ny)  # [[A, B], [C, D]] and a constant
        self.mlp = mlp(cfg.nx + cfg.nu, cfg.nx + cfg.ny, cfg.hidden, cfg.layers)  # [f; h]

    def forward(self, past_u: torch.Tensor, past_y: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Outputs (batch, T, ny) of a free run over inputs ``u`` (batch, T, nu) from the encoded window."""
        x = self.encoder(past_u, past_y)
        nx, m = self.nx, self.nx + self.ny
        first: nn.Linear = self.mlp[0]  # type: ignore[assignment]
        rest = self.mlp[1:]
        w_x = torch.cat([self.linear.weight[:, :nx], first.weight[:, :nx]]).T.contiguous()
        w_u = torch.cat([self.linear.weight[:, nx:], first.weight[:, nx:]]).T
        drive = torch.matmul(u.transpose(0, 1), w_u) + torch.cat([self.linear.bias, first.bias])  # (T, batch, m + H)
        ys = []
        for t in range(u.shape[1]):
            z = torch.addmm(drive[t], x, w_x)
            out = z[:, :m] + rest(z[:, m:])
            ys.append(out[:, nx:])
            x = out[:, :nx]
        if not ys:
            return u.new_zeros((u.shape[0], 0, self.ny))
        return torch.stack(ys, dim=1)

    def initial_state(self, past_u: torch.Tensor, past_y: torch.Tensor) -> torch.Tensor:
        """x(t0) (batch, nx) from the encoder window (the exported ONNX encoder, ``methods/export/onnx.py``)."""
        return self.encoder(past_u, past_y)

    def step(self, u: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of ``forward`` as its own graph: (y(t), x(t+1)) from u(t) (batch, nu) and x(t) (batch, nx)."""
        z = torch.cat([x, u], dim=-1)
        out = self.linear(z) + self.mlp(z)
        return out[:, self.nx:], out[:, :self.nx]


class GRUNet(nn.Module):
    """``gru``: encoder to the GRU's hidden state, one GRU layer over the inputs, linear readout."""

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

    def initial_state(self, past_u: torch.Tensor, past_y: torch.Tensor) -> torch.Tensor:
        """h(t0 - 1) (batch, nx) from the encoder window (the exported ONNX encoder, ``methods/export/onnx.py``)."""
        return torch.tanh(self.encoder(past_u, past_y))

    def step(self, u: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of ``forward`` as its own graph: (y(t), h(t)) from u(t) (batch, nu) and h(t - 1) (batch, nx)."""
        states, last = self.gru(u.unsqueeze(1), h.unsqueeze(0).contiguous())
        return self.readout(states[:, 0]), last[0]


__all__ = ["Encoder", "GRUNet", "StateSpaceNet", "mlp"]
