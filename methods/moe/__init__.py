"""``moe``: the turboshaft-moe paper's physics-structured mixture of experts, trained on derivatives, simulated open loop.

The state z is the target(s), the regressors are ``[z; u; 1]`` with u the run-time
inputs, and the schedulers v are a subset of the inputs (optionally plus the state:
quasi-LPV). Each expert is an LPV model dz/dt = G_i(v) [z; u; 1]; a softmax gate
alpha(v) mixes them (``model.py``). Training minimises the turboshaft-moe paper's collaborative +
competitive loss on dz/dt estimated by total-variation regularised differentiation
(``numerics/derivatives.py``), with Adam, on signals standardised with training statistics.
Prediction integrates all segments at once (padded, fixed step, RK4 or Euler at the
data's sample times) from the measured y0, and never reads a measured output after t0.
A trajectory that goes non-finite or leaves ``envelope`` times the training range of y
is stopped, held and flagged in ``SegmentPredictions.diverged``.

A derivative fit weights the fast dynamics and can leave the slow pole, and with it every
static gain, undetermined: when a controller integrates an error (the turboshaft FADEC's
PI on NR), dWF/dt is explained by the error alone and the fitted own-state coefficient
lands near 0 or on the wrong side, so the open-loop simulation drifts. Options that
address it, off by default (the paper's training): ``max_time_constant`` keeps every
own-state coefficient <= -1/max_time_constant (frozen-stability margin); ``sim_weight``
adds the simulation error of short windows to the loss; ``correct`` models standard-day
corrected columns (WF / (delta sqrt(theta))).

Every expert starts at the sign-bounded least-squares LTI fit of the derivatives (``init =
"lstsq"``, the only start: the output-error start added nothing and was removed).
Time-based options default to samples (``derivative_window`` 24, ``shooting_window`` 240),
a number gives seconds (``options.py``).

Modules, one job each: ``options`` (defaults, checks, hyperparameters), ``preprocess``
(training segments to schedulers, regressors and derivative targets), ``warmstart``
(least-squares start), ``training`` (Adam on the paper's loss, simulation-error windows),
``grid`` (a grid's training runs side by side in one batched loop), ``simulation`` (batched
open-loop simulation), ``explain`` (local systems, frozen stability, gates, describe),
``model`` (the torch module), ``fitted`` (the trained record), ``method`` (the Method class).
"""

from __future__ import annotations

import importlib
from typing import Any

from enginebench.methods.moe.method import MoE

_WHERE = {
    "describe": "explain", "frozen_stability": "explain", "gate_weights": "explain", "local_coefficients": "explain",
    "MoEFitted": "fitted", "build_network": "fitted",
    "MixtureOfExperts": "model", "moe_loss": "model", "signed_softplus": "model",
    "HYPERPARAMETERS": "options", "default_options": "options", "resolve_params": "options",
    "correction_factors": "preprocess", "input_derivative": "preprocess",
    "affine_prefix_scan": "simulation", "simulate": "simulation",
    "lstsq_coefficients": "warmstart", "warm_start": "warmstart",
}
"""The package's names and their modules: imported on first use (PEP 562), so that loading the ``MoE`` class
(``enginebench methods list``) imports no torch, scipy.signal or derivative."""


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        value = getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "HYPERPARAMETERS", "MixtureOfExperts", "MoE", "MoEFitted", "affine_prefix_scan", "build_network",
    "correction_factors", "default_options", "describe", "frozen_stability", "gate_weights", "input_derivative",
    "local_coefficients", "lstsq_coefficients", "moe_loss", "resolve_params", "signed_softplus", "simulate",
    "warm_start",
]
