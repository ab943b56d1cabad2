"""A trained MoE as plain arrays (picklable, device-free) and the torch module rebuilt from it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from enginebench.methods.moe.model import MixtureOfExperts


@dataclass
class MoEFitted:
    """A trained mixture: weights as numpy arrays plus everything needed to rebuild and simulate it."""

    params: dict[str, Any]
    options: dict[str, Any]
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    scheduler_inputs: tuple[str, ...]
    expert_inputs: tuple[str, ...]
    sign: np.ndarray
    """(k, q) constrained sign of each coefficient of [z; u; 1]: -1, 0 (free) or +1."""
    u_mean: np.ndarray
    u_scale: np.ndarray
    y_mean: np.ndarray
    y_scale: np.ndarray
    d_scale: np.ndarray
    """Scale of the standardised state's derivative (1/s): the network predicts dz/dt / d_scale."""
    y_min: np.ndarray
    y_max: np.ndarray
    weights: dict[str, np.ndarray]
    probe: np.ndarray
    """Standardised training scheduler points used for the frozen-stability verdict."""
    loss_history: list[float] = field(default_factory=list)
    derived: tuple[tuple[str, str, int], ...] = ()
    """Input derivatives among the regressors: (name, input column, order), e.g. ("dCOL/dt", "COL", 1).
    Their statistics follow the raw inputs' in ``u_mean`` / ``u_scale``."""
    init_info: dict[str, Any] = field(default_factory=dict)
    """How the experts were started: ``init`` ("lstsq") and the warm-start coefficients ``theta`` (network units)."""

    @property
    def augmented_names(self) -> tuple[str, ...]:
        """The raw inputs followed by the derived input derivatives (columns of ``u_mean``)."""
        return self.input_names + tuple(d[0] for d in self.derived)

    @property
    def scheduler_names(self) -> tuple[str, ...]:
        return self.scheduler_inputs + (self.target_names if self.options["scheduler_state"] else ())

    @property
    def regressor_names(self) -> tuple[str, ...]:
        return self.target_names + self.expert_inputs + (("1",) if self.options["bias"] else ())


def build_network(fitted: MoEFitted, device: torch.device) -> MixtureOfExperts:
    """The torch module of ``fitted`` on ``device`` (weights copied from the stored arrays)."""
    hp, dtype = fitted.params, torch_dtype(fitted.options["dtype"])
    net = MixtureOfExperts(
        len(fitted.scheduler_names), len(fitted.target_names), len(fitted.regressor_names), hp["n_experts"],
        fitted.options["expert_hidden"], hp["gate_hidden"], torch.as_tensor(fitted.sign), hp["k"],
        torch.Generator().manual_seed(0), dtype,
    )
    state = {k: torch.as_tensor(v) for k, v in fitted.weights.items()}
    state.setdefault("margin", torch.zeros_like(torch.as_tensor(fitted.sign)))  # models fitted before margins existed
    net.load_state_dict(state)
    return net.to(device).eval()


def standardise_sched(fitted: MoEFitted, raw: np.ndarray) -> np.ndarray:
    si = [fitted.input_names.index(c) for c in fitted.scheduler_inputs]
    mean = np.r_[fitted.u_mean[si], fitted.y_mean if fitted.options["scheduler_state"] else []]
    scale = np.r_[fitted.u_scale[si], fitted.y_scale if fitted.options["scheduler_state"] else []]
    return (raw - mean) / scale


def unstandardise_sched(fitted: MoEFitted, std: np.ndarray) -> np.ndarray:
    zero = standardise_sched(fitted, np.zeros(std.shape[-1]))
    unit = standardise_sched(fitted, np.ones(std.shape[-1])) - zero
    return (std - zero) / unit


def torch_dtype(name: str) -> torch.dtype:
    return torch.float64 if name == "float64" else torch.float32

