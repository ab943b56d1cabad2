"""MoE's options and hyperparameters: their declaration (defaults, meaning, checks) and the hyperparameter checks.

Time-based options default to a number of samples, so they follow the data's sample
period: ``derivative_window`` (input derivatives' Savitzky-Golay window) is 24 samples and
``shooting_window`` (training windows of the simulation-error term) 240 samples when left
at None; a number gives seconds, as before. At the turboshaft's 12 Hz both equal the
former 2 s and 20 s. ``init`` accepts only "lstsq" (the sign-bounded least-squares warm
start); the output-error start (``init = "output_error"``) added nothing in the turboshaft
experiments and was removed, and so was the unused random start.

The searched hyperparameters' candidates are options too (``experts_grid``, ``beta1_grid``,
``beta2_grid``, ``k_grid``, ``gate_hidden_grid``, ``lr_grid``, ``epochs_grid``; ``search_space``
reads them): the defaults are the space always searched; 3 or more evenly spaced values span
a range for ``[selection] search = "random"`` or ``"bayes"``.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.declare import (Declaration, Invalid, anything, choice, flag, is_number, is_whole, listing, number,
                                 positive, table, text, whole)
from enginebench.errors import MethodError
from enginebench.method import Params
from enginebench.methods.numerics.derivatives import SOLVERS as DERIVATIVE_SOLVERS
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
MIN_GRADIENT_STEPS = 2000
"""``epochs_grid = None``: the fewest gradient steps a default training takes. 100 epochs of 512-row minibatches
give them from 10,240 training rows on (the turboshaft-moe paper's records are far longer); on a record of 1,000
rows (two minibatches an epoch) 100 epochs would be 200 steps, too few for the gate and experts to move far from
their least-squares start, so the epochs follow the record: ceil(2000 / minibatches per epoch)."""
SHOOTING_WINDOW_SAMPLES = 240
"""``shooting_window = None``: the simulation-error windows' length in sample steps (20 s at 12 Hz)."""

SIGN_WORDS = {"+": 1, "positive": 1, "-": -1, "negative": -1, "free": 0}


def window_steps(window_s: float | None, h: float, default_samples: int) -> int:
    """A window option in sample steps: ``round(window_s / h)`` for seconds, ``default_samples`` for None."""
    return int(default_samples) if window_s is None else int(round(window_s / h))


DERIVATIVES_MESSAGE = "{name}={value} must map input columns to an order 1 or 2, e.g. {'COL': 1, 'NR': 2}"
CORRECT_MESSAGE = ("{name}={value} must map columns to {input: [reference > 0, exponent]}, e.g. "
                   "{'WF': {'P0': [101.325, 1.0], 'T1': [288.15, 0.5]}} for WF / (delta sqrt(theta))")
NAMES_MESSAGE = "{name}={value} must be a list of input column names or None"


def _grid_message(what: str, example: str) -> str:
    return ("{name}={value} must be a non-empty list of " + what + ", the candidates model selection searches (e.g. "
            + example + "); 3 or more evenly spaced values span a range for search random or bayes")


GRID_OPTIONS = {"n_experts": "experts_grid", "beta1": "beta1_grid", "beta2": "beta2_grid", "k": "k_grid",
                "gate_hidden": "gate_hidden_grid", "lr": "lr_grid", "epochs": "epochs_grid"}
"""Searched hyperparameter -> the option that lists its candidates."""


def _init(value: Any) -> Any:
    if value != "lstsq":
        raise Invalid("{name}={value}; only 'lstsq' (the sign-bounded least-squares start) is available: the "
                      "output-error and random starts were removed; leave init out")
    return value


def _signs(value: Any) -> Any:
    if isinstance(value, Mapping):
        for col, word in value.items():
            if word not in SIGN_WORDS:
                raise Invalid("{name}[" + repr(col) + "]=" + repr(word) + "; use '+', '-' or 'free'")
    elif value not in ("stable", "none"):
        raise Invalid("{name}={value}; use 'stable', 'none' or a mapping {column: '+' or '-'} such as "
                      "{'TRQ': '-', 'WF': '+'}")
    return value


def _derivatives(value: Any) -> Any:
    if not all(isinstance(c, str) and is_whole(n) and n in (1, 2) for c, n in value.items()):
        raise Invalid(DERIVATIVES_MESSAGE)
    return value


def _reference_pair(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) == 2 and all(is_number(x) and np.isfinite(x) for x in v) and v[0] > 0


def _correct(value: Any) -> Any:
    if not all(isinstance(col, str) and isinstance(by, Mapping) and by
               and all(isinstance(c, str) and _reference_pair(v) for c, v in by.items()) for col, by in value.items()):
        raise Invalid(CORRECT_MESSAGE)
    return value


def _device(value: Any) -> Any:
    resolve_device(value, "method 'moe': option device")
    return value


OPTIONS = Declaration(
    listing("scheduler", None, "input columns that schedule gate and experts; None = all inputs", items="str",
            nullable=True, min_items=0, message=NAMES_MESSAGE),
    flag("scheduler_state", False, "also schedule on the state (quasi-LPV)"),
    listing("expert_inputs", None, "input columns in the experts' regressors [z; u; 1]; None = all inputs",
            items="str", nullable=True, min_items=0, message=NAMES_MESSAGE),
    table("input_derivatives", None, "input derivatives added to the regressors, {column: highest order 1 or 2} "
          "(turboshaft-moe's dNR', dNR'', COL'), from a cubic Savitzky-Golay fit over derivative_window", nullable=True,
          check=_derivatives, message=DERIVATIVES_MESSAGE),
    positive("derivative_window", None, "window of the input derivatives; None = "
             f"{DERIVATIVE_WINDOW_SAMPLES} samples", nullable=True, unit="s",
             message="{name}={value} must be a positive number of seconds (or None for the default in samples)"),
    table("correct", None, "standard-day correction {column: {input: [reference, exponent]}}: models column / "
          "prod (input/reference)^exponent, predicted back in raw units", nullable=True, check=_correct,
          message=CORRECT_MESSAGE),
    flag("bias", True, "a constant term in each expert's regressors"),
    anything("signs", "stable", "sign constraints: 'stable' (own-state coefficients < 0), 'none', or "
             "{column: '+' | '-' | 'free'}", check=_signs, type_label="'stable' | 'none' | table"),
    choice("competitive", "alpha2", "competitive-term weights of the gate loss: seed eq. 4c's alpha^2, or alpha",
           ("alpha2", "alpha")),
    whole("expert_hidden", 16, "hidden units of each expert's network (schedulers -> local coefficients)", low=1,
          message="{name}={value} must be a positive integer"),
    whole("batch_size", 512, "training rows per gradient step", low=1, unit="rows",
          message="{name}={value} must be a positive integer"),
    positive("tv_alpha", 0.05, "total-variation regularisation of the derivative targets (standardised output "
             "units, time in samples)", message="{name}={value} must be a positive number"),
    choice("tv_order", 0, "order of the total-variation regularisation", (0, 1)),
    choice("tv_solver", "admm", "solver of the order-0 TV problem: batched ADMM checked for optimality, or the "
           "derivative package's Lasso (stops at its iteration cap short of the optimum; earlier results)",
           DERIVATIVE_SOLVERS),
    choice("integrator", "rk4", "simulation's integration scheme", ("rk4", "euler")),
    choice("input_interp", "linear", "inputs between samples: linear interpolation or hold", ("linear", "hold")),
    positive("envelope", 10.0, "divergence: y leaving [min - e range, max + e range] of the training outputs",
             message="{name}={value} must be a positive number"),
    whole("probe_points", 512, "training scheduling points (a draw) probed for the frozen-stability verdict", low=1,
          message="{name}={value} must be a positive integer"),
    flag("clip_schedulers", True, "hold schedulers at the edge of their training range when simulating",
         message="{name}={value} must be true or false"),
    anything("init", "lstsq", "where the experts start: the sign-bounded least-squares fit of the derivatives "
             "(the only start kept)", check=_init, type_label="choice: lstsq"),
    positive("max_time_constant", None, "frozen-stability margin: every expert's own-state coefficient <= "
             "-1/max_time_constant; None = only < 0", nullable=True, unit="s",
             message="{name}={value} must be a positive number of seconds or None"),
    number("sim_weight", 0.0, "weight of the open-loop simulation error over shooting_window windows added to "
           "the derivative loss; 0 = the turboshaft-moe paper's derivative-only training", low=0,
           message="{name}={value} must be a finite number >= 0"),
    positive("shooting_window", None, "length of the simulation-error windows; None = "
             f"{SHOOTING_WINDOW_SAMPLES} sample steps", nullable=True, unit="s",
             message="{name}={value} must be a positive number of seconds (or None for the default in samples)"),
    text("device", "cpu", "torch device: cpu, auto, cuda or cuda:INDEX (cpu by default: at the default minibatch a "
         "CUDA step waits on kernel launches, 0.7x one CPU core on an H100; docs/benchmarks.md)", check=_device,
         message="{name}={value} must be a string ('auto', 'cpu', 'cuda', 'cuda:0')"),
    choice("dtype", "float32", "torch floating-point precision", ("float32", "float64")),
    whole("cpu_threads", 1, "torch intra-op threads on CPU while fitting and simulating; None = leave as is",
          low=1, nullable=True, message="{name}={value} must be a positive integer or None"),
    flag("batch_grid", True, "train a grid's runs side by side in one batched loop (derivative loss only, "
         "sim_weight = 0); false trains them one by one, as fit does", message="{name}={value} must be true or false"),
    flag("compile", True, "torch.compile the training step of long fits (>= 20,000 gradient steps; eager where "
         "torch.compile is missing or fails)", message="{name}={value} must be true or false"),
    # the searched hyperparameters' candidates (model selection tries their product, or the ranges they span)
    listing("experts_grid", (2, 3, 4), "numbers of experts searched", items="int", low=1, searches=("n_experts",),
            bound=(1, 8), message=_grid_message("whole numbers >= 1", "[2, 3, 4]")),
    listing("beta1_grid", (1.0,), "weights of the collaborative loss term searched (seed eq. 4)", items="float",
            low=0, searches=("beta1",), message=_grid_message("numbers >= 0", "[0.1, 1.0]")),
    listing("beta2_grid", (0.1, 1.0), "weights of the competitive loss term searched (seed eq. 4)", items="float",
            low=0, searches=("beta2",), message=_grid_message("numbers >= 0", "[0.1, 1.0]")),
    listing("k_grid", (1.0,), "softplus sharpness k of the signed coefficients searched (seed eq. 6)",
            items="float", low=0, low_open=True, searches=("k",),
            message=_grid_message("numbers > 0", "[0.5, 1.0, 2.0]")),
    listing("gate_hidden_grid", (16,), "hidden units of the gate network searched", items="int", low=1,
            searches=("gate_hidden",), message=_grid_message("whole numbers >= 1", "[8, 16, 32]")),
    listing("lr_grid", (1e-3, 1e-2), "Adam learning rates searched", items="float", low=0, low_open=True,
            searches=("lr",), bound=(1e-5, 0.1), message=_grid_message("numbers > 0", "[1e-4, 1e-3, 1e-2]")),
    listing("epochs_grid", None, f"training epochs searched; None = {HYPERPARAMETERS['epochs']}, or on a short "
            f"record as many as give {MIN_GRADIENT_STEPS} gradient steps (epochs x minibatches of batch_size rows)",
            items="int", low=1, nullable=True, searches=("epochs",),
            message=_grid_message("whole numbers >= 1", "[50, 100, 150]")),
)
"""Every option of ``moe``: default, kind, unit and meaning."""


def default_options() -> dict[str, Any]:
    """Every option of ``moe`` with its default (``OPTIONS`` says what each means)."""
    return OPTIONS.defaults()


def default_epochs(rows: int, batch_size: int) -> int:
    """``epochs_grid = None``'s epochs for ``rows`` training rows: 100, or enough for ``MIN_GRADIENT_STEPS`` steps."""
    batches = max(1, -(-int(rows) // int(batch_size)))
    return max(int(HYPERPARAMETERS["epochs"]), -(-MIN_GRADIENT_STEPS // batches))


def search_space(options: Params, rows: int | None = None) -> dict[str, np.ndarray]:
    """The searched hyperparameters' candidates from the ``*_grid`` options (integers as int arrays, the rest
    float), in ``HYPERPARAMETERS`` order; ``epochs_grid = None`` from the ``rows`` training rows
    (``default_epochs``; 100 when they are not known)."""
    values = {name: options[GRID_OPTIONS[name]] for name in HYPERPARAMETERS}
    if values["epochs"] is None:
        values["epochs"] = [HYPERPARAMETERS["epochs"] if rows is None else default_epochs(rows, options["batch_size"])]
    return {name: np.array(values[name], dtype=int if isinstance(HYPERPARAMETERS[name], int) else float)
            for name in HYPERPARAMETERS}


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

