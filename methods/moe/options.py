"""MoE's options and hyperparameters: defaults, meaning and the checks run when a method is built.

Time-based options default to a number of samples, so they follow the data's sample
period: ``derivative_window`` (input derivatives' Savitzky-Golay window) is 24 samples and
``shooting_window`` (training windows of the simulation-error term) 240 samples when left
at None; a number gives seconds, as before. At the turboshaft's 12 Hz both equal the
former 2 s and 20 s. ``init`` accepts only "lstsq" (the sign-bounded least-squares warm
start); the output-error start (``init = "output_error"``) added nothing in the turboshaft
experiments and was removed, and so was the unused random start.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.errors import MethodError
from enginebench.methods.base import Params
from enginebench.methods.numerics.device import resolve_device

HYPERPARAMETERS: dict[str, Any] = {
    "n_experts": 3,
    "beta1": 1.0,
    "beta2": 1.0,
    "k": 1.0,
    "gate_hidden": 16,
    "lr": 1e-3,
    "epochs": 100,
}
"""Defaults of the searched hyperparameters (small, so that a fit takes seconds)."""

DERIVATIVE_WINDOW_SAMPLES = 24
"""``derivative_window = None``: the input derivatives' window in samples (2 s at 12 Hz)."""
SHOOTING_WINDOW_SAMPLES = 240
"""``shooting_window = None``: the simulation-error windows' length in sample steps (20 s at 12 Hz)."""

SIGN_WORDS = {"+": 1, "positive": 1, "-": -1, "negative": -1, "free": 0}


def window_steps(window_s: float | None, h: float, default_samples: int) -> int:
    """A window option in sample steps: ``round(window_s / h)`` for seconds, ``default_samples`` for None."""
    return int(default_samples) if window_s is None else int(round(window_s / h))


def default_options() -> dict[str, Any]:
    """Every option of ``moe`` with its default (what each means is written beside it)."""
    return {
        "scheduler": None,  # input names that schedule gate and experts; None = all inputs
        "scheduler_state": False,  # also schedule on the state (quasi-LPV)
        "expert_inputs": None,  # input names in the regressors [z; u; 1]; None = all inputs
        # input derivatives added to the regressors (seed 003's u_WF = [dNR, dNR', dNR'', COL, COL']):
        # {column: highest order 1 or 2}, from a cubic Savitzky-Golay fit over derivative_window seconds
        "input_derivatives": None,
        "derivative_window": None,  # seconds; None = DERIVATIVE_WINDOW_SAMPLES (24) samples
        # standard-day correction (seed 003, after Volponi 1998): {column: {input: [reference, exponent]}}
        # models column / prod (input/reference)^exponent; e.g. WF/(delta sqrt(theta)) is
        # {"WF": {"P0": [101.325, 1.0], "T1": [288.15, 0.5]}}. Targets are predicted back in raw units.
        "correct": None,
        "bias": True,
        "signs": "stable",  # "stable" (own-state coefficients < 0), "none", or {column: "+"/"-"}
        "competitive": "alpha2",  # competitive-term weights: seed eq. 4c alpha^2, or "alpha"
        "expert_hidden": 16,
        "batch_size": 512,
        "tv_alpha": 0.05,  # TV regularisation in standardised-output units, time in samples
        "tv_order": 0,
        "integrator": "rk4",  # or "euler"
        "input_interp": "linear",  # inputs between samples: "linear" or "hold"
        "envelope": 10.0,  # divergence when y leaves [min - e*range, max + e*range] of training
        "probe_points": 512,
        "clip_schedulers": True,  # hold schedulers at the edge of their training range when simulating
        # where the experts start (plus small scheduled parts): the sign-bounded least-squares fit of the
        # derivatives, the only start kept ("output_error" and "random" were removed)
        "init": "lstsq",
        # frozen-stability margin: every expert's own-state coefficient stays <= -1/max_time_constant
        # (1/s), i.e. no local time constant slower than this many seconds; None = only < 0
        "max_time_constant": None,
        # sim_weight > 0 adds sim_weight x the mean squared open-loop simulation error (standardised)
        # of shooting_window-second training windows, each started from its measured first value, to
        # seed 003's derivative loss; 0 = the seed's derivative-only training
        "sim_weight": 0.0,
        "shooting_window": None,  # seconds; None = SHOOTING_WINDOW_SAMPLES (240) sample steps
        "device": "auto",  # "auto" | "cpu" | "cuda[:index]"
        "dtype": "float32",  # or "float64"
        "cpu_threads": 1,  # torch intra-op threads on CPU while fitting/simulating; None = leave as is
    }


def check_options(o: Mapping[str, Any]) -> None:
    """Raise MethodError naming the first bad option, its value and what it should be."""
    choices = {
        "competitive": ("alpha2", "alpha"),
        "integrator": ("rk4", "euler"),
        "input_interp": ("linear", "hold"),
        "dtype": ("float32", "float64"),
        "tv_order": (0, 1),
    }
    if o["init"] != "lstsq":
        raise MethodError(
            f"method 'moe': option init={o['init']!r}; only 'lstsq' (the sign-bounded least-squares start) is "
            "available: the output-error and random starts were removed; leave init out"
        )
    for key, allowed in choices.items():
        if o[key] not in allowed:
            raise MethodError(f"method 'moe': option {key}={o[key]!r}; use one of {', '.join(map(repr, allowed))}")
    if not isinstance(o["clip_schedulers"], bool):
        raise MethodError(f"method 'moe': option clip_schedulers={o['clip_schedulers']!r} must be true or false")
    for key in ("expert_hidden", "batch_size", "probe_points"):
        if not (isinstance(o[key], (int, np.integer)) and o[key] >= 1):
            raise MethodError(f"method 'moe': option {key}={o[key]!r} must be a positive integer")
    if o["cpu_threads"] is not None and not (isinstance(o["cpu_threads"], (int, np.integer)) and o["cpu_threads"] >= 1):
        raise MethodError(f"method 'moe': option cpu_threads={o['cpu_threads']!r} must be a positive integer or None")
    for key in ("tv_alpha", "envelope", "derivative_window", "shooting_window"):
        if key.endswith("_window") and o[key] is None:
            continue
        if not (isinstance(o[key], (int, float)) and np.isfinite(o[key]) and o[key] > 0):
            unit = " of seconds (or None for the default in samples)" if key.endswith("_window") else ""
            raise MethodError(f"method 'moe': option {key}={o[key]!r} must be a positive number{unit}")
    if not (isinstance(o["sim_weight"], (int, float)) and not isinstance(o["sim_weight"], bool)
            and np.isfinite(o["sim_weight"]) and o["sim_weight"] >= 0):
        raise MethodError(f"method 'moe': option sim_weight={o['sim_weight']!r} must be a finite number >= 0")
    tmax = o["max_time_constant"]
    if tmax is not None and not (
        isinstance(tmax, (int, float)) and not isinstance(tmax, bool) and np.isfinite(tmax) and tmax > 0
    ):
        raise MethodError(f"method 'moe': option max_time_constant={tmax!r} must be a positive number of seconds or None")
    if not (o["signs"] in ("stable", "none") or isinstance(o["signs"], Mapping)):
        raise MethodError(
            f"method 'moe': option signs={o['signs']!r}; use 'stable', 'none' or a mapping "
            "{column: '+' or '-'} such as {'TRQ': '-', 'WF': '+'}"
        )
    if isinstance(o["signs"], Mapping):
        for col, word in o["signs"].items():
            if word not in SIGN_WORDS:
                raise MethodError(f"method 'moe': option signs[{col!r}]={word!r}; use '+', '-' or 'free'")
    if o["input_derivatives"] is not None:
        if not isinstance(o["input_derivatives"], Mapping) or not all(
            isinstance(c, str) and isinstance(n, (int, np.integer)) and not isinstance(n, bool) and n in (1, 2)
            for c, n in o["input_derivatives"].items()
        ):
            raise MethodError(
                f"method 'moe': option input_derivatives={o['input_derivatives']!r} must map input columns to "
                "an order 1 or 2, e.g. {'COL': 1, 'NR': 2}"
            )
    if o["correct"] is not None and not (
        isinstance(o["correct"], Mapping)
        and all(
            isinstance(col, str) and isinstance(by, Mapping) and by
            and all(
                isinstance(c, str) and isinstance(v, (list, tuple)) and len(v) == 2
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v) and v[0] > 0
                for c, v in by.items()
            )
            for col, by in o["correct"].items()
        )
    ):
        raise MethodError(
            f"method 'moe': option correct={o['correct']!r} must map columns to {{input: [reference > 0, exponent]}}, "
            "e.g. {'WF': {'P0': [101.325, 1.0], 'T1': [288.15, 0.5]}} for WF / (delta sqrt(theta))"
        )
    for key in ("scheduler", "expert_inputs"):
        if o[key] is not None and (isinstance(o[key], str) or not all(isinstance(c, str) for c in o[key])):
            raise MethodError(f"method 'moe': option {key}={o[key]!r} must be a list of input column names or None")
    resolve_device(o["device"], "method 'moe': option device")


def resolve_params(params: Params) -> dict[str, Any]:
    """Hyperparameters with defaults filled in and checked; raises MethodError naming the bad one."""
    unknown = set(params) - set(HYPERPARAMETERS)
    if unknown:
        raise MethodError(f"method 'moe': unknown hyperparameter(s) {', '.join(sorted(unknown))}; known: {', '.join(HYPERPARAMETERS)}")
    hp = {**HYPERPARAMETERS, **dict(params)}
    for key in ("n_experts", "gate_hidden", "epochs"):
        if float(hp[key]) != int(hp[key]) or int(hp[key]) < 1:
            raise MethodError(f"method 'moe': hyperparameter {key}={hp[key]!r} must be a positive integer")
        hp[key] = int(hp[key])
    for key in ("beta1", "beta2", "k", "lr"):
        hp[key] = float(hp[key])
        if not np.isfinite(hp[key]) or hp[key] < 0 or (key in ("k", "lr") and hp[key] == 0):
            raise MethodError(f"method 'moe': hyperparameter {key}={hp[key]!r} must be a finite number > 0 (beta1, beta2 >= 0)")
    if hp["beta1"] + hp["beta2"] == 0:
        raise MethodError("method 'moe': beta1 and beta2 are both 0, so the loss is empty; make at least one positive")
    return hp

