"""``moe``: seed 003's physics-structured mixture of experts, trained on derivatives, simulated open loop.

The state z is the target(s), the regressors are ``[z; u; 1]`` with u the run-time
inputs, and the schedulers v are a subset of the inputs (optionally plus the state:
quasi-LPV). Each expert is an LPV model dz/dt = G_i(v) [z; u; 1]; a softmax gate
alpha(v) mixes them (``moe_model.py``). Training minimises seed 003's collaborative +
competitive loss on dz/dt estimated by total-variation regularised differentiation
(``derivatives.py``), with Adam, on signals standardised with training statistics.
Prediction integrates all segments at once (padded, fixed step, RK4 or Euler at the
data's sample times) from the measured y0, and never reads a measured output after t0.
A trajectory that goes non-finite or leaves ``envelope`` times the training range of y
is stopped, held and flagged in ``SegmentPredictions.diverged``.

A derivative fit weights the fast dynamics and can leave the slow pole, and with it every
static gain, undetermined: when a controller integrates an error (the turboshaft FADEC's
PI on NR), dWF/dt is explained by the error alone and the fitted own-state coefficient
lands near 0 or on the wrong side, so the open-loop simulation drifts. Options that
address it, off by default (seed 003's training): ``init="output_error"`` starts every
expert at the LTI model whose open-loop simulation best fits the training trajectories;
``max_time_constant`` keeps every own-state coefficient <= -1/max_time_constant
(frozen-stability margin); ``sim_weight`` adds the simulation error of short windows to
the loss; ``correct`` models standard-day corrected columns (WF / (delta sqrt(theta))).
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np
import torch
from scipy.optimize import lsq_linear
from scipy.signal import lfilter, savgol_filter

from enginebench.datasets.samples import Samples
from enginebench.errors import DataError, MethodError
from enginebench.methods.base import Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.numerics.derivatives import tv_derivative
from enginebench.methods.moe_model import MixtureOfExperts, moe_loss

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

_SIGN_WORDS = {"+": 1, "positive": 1, "-": -1, "negative": -1, "free": 0}


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
    """How the experts were started: ``init``, the warm-start coefficients ``theta`` (network units) and,
    for init="output_error", each target's chosen ``time_constant_s`` and standardised ``simulation_mse``."""

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


class MoE(Method):
    """Mixture of LPV experts with frozen-stability sign constraints (seed 003)."""

    name = "moe"
    family = "hybrid"
    modes = frozenset({"simulation"})
    summary = "mixture of LPV experts with frozen stability, trained on TV derivatives (seed 003)"

    @classmethod
    def default_options(cls) -> dict[str, Any]:
        return {
            "scheduler": None,  # input names that schedule gate and experts; None = all inputs
            "scheduler_state": False,  # also schedule on the state (quasi-LPV)
            "expert_inputs": None,  # input names in the regressors [z; u; 1]; None = all inputs
            # input derivatives added to the regressors (seed 003's u_WF = [dNR, dNR', dNR'', COL, COL']):
            # {column: highest order 1 or 2}, from a Savitzky-Golay fit over derivative_window seconds
            "input_derivatives": None,
            "derivative_window": 2.0,
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
            # where the experts start (plus small scheduled parts): "output_error" = the LTI model whose
            # open-loop simulation best fits the training trajectories (pole by grid search, the rest by
            # sign-bounded least squares), "lstsq" = the sign-bounded least-squares fit of the derivatives,
            # "random" = torch's default initialisation
            "init": "lstsq",
            # frozen-stability margin: every expert's own-state coefficient stays <= -1/max_time_constant
            # (1/s), i.e. no local time constant slower than this many seconds; None = only < 0
            "max_time_constant": None,
            "oe_poles": 24,  # poles tried by init="output_error" (log-spaced time constants)
            # sim_weight > 0 adds sim_weight x the mean squared open-loop simulation error (standardised)
            # of shooting_window-second training windows, each started from its measured first value, to
            # seed 003's derivative loss; 0 = the seed's derivative-only training
            "sim_weight": 0.0,
            "shooting_window": 20.0,
            "device": "auto",  # "auto" | "cpu" | "cuda"
            "dtype": "float32",  # or "float64"
            "cpu_threads": 1,  # torch intra-op threads on CPU while fitting/simulating; None = leave as is
        }

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        o = self.options
        choices = {
            "competitive": ("alpha2", "alpha"),
            "integrator": ("rk4", "euler"),
            "input_interp": ("linear", "hold"),
            "device": ("auto", "cpu", "cuda"),
            "dtype": ("float32", "float64"),
            "tv_order": (0, 1),
            "init": ("output_error", "lstsq", "random"),
        }
        for key, allowed in choices.items():
            if o[key] not in allowed:
                raise MethodError(f"method 'moe': option {key}={o[key]!r}; use one of {', '.join(map(repr, allowed))}")
        if not isinstance(o["clip_schedulers"], bool):
            raise MethodError(f"method 'moe': option clip_schedulers={o['clip_schedulers']!r} must be true or false")
        for key in ("expert_hidden", "batch_size", "probe_points", "oe_poles"):
            if not (isinstance(o[key], (int, np.integer)) and o[key] >= 1):
                raise MethodError(f"method 'moe': option {key}={o[key]!r} must be a positive integer")
        if o["cpu_threads"] is not None and not (isinstance(o["cpu_threads"], (int, np.integer)) and o["cpu_threads"] >= 1):
            raise MethodError(f"method 'moe': option cpu_threads={o['cpu_threads']!r} must be a positive integer or None")
        for key in ("tv_alpha", "envelope", "derivative_window", "shooting_window"):
            if not (isinstance(o[key], (int, float)) and np.isfinite(o[key]) and o[key] > 0):
                raise MethodError(f"method 'moe': option {key}={o[key]!r} must be a positive number")
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
                if word not in _SIGN_WORDS:
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
        if o["device"] == "cuda" and not torch.cuda.is_available():
            raise MethodError("method 'moe': option device='cuda' but torch sees no CUDA device; use device='auto' or 'cpu'")

    def search_space(self, data: Samples) -> SearchSpace:
        return {
            "n_experts": np.array([2, 3, 4]),
            "beta1": np.array([1.0]),
            "beta2": np.array([0.1, 1.0]),
            "k": np.array([1.0]),
            "gate_hidden": np.array([16]),
            # from the least-squares warm start a small rate refines; a large one may trade
            # simulation accuracy for derivative fit: the validation RMAE decides
            "lr": np.array([1e-3, 1e-2]),
            "epochs": np.array([HYPERPARAMETERS["epochs"]]),
        }

    # -- training -------------------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> MoEFitted:
        self.check_mode(train.mode)
        hp = resolve_params(params)
        o = self.options
        sched_in = _names(o["scheduler"], train.input_names, "scheduler")
        derived = _derived_columns(o["input_derivatives"], train.input_names)
        names = tuple(train.input_names) + tuple(d[0] for d in derived)
        expert_in = _names(o["expert_inputs"], names, "expert_inputs")
        expert_in += [d[0] for d in derived if d[0] not in expert_in]  # asked-for derivatives always join
        if not sched_in and not o["scheduler_state"]:
            raise MethodError("method 'moe': no scheduler: name at least one input in option scheduler or set scheduler_state=True")
        sign = _sign_matrix(o["signs"], train.target_names, expert_in, o["bias"])
        U, Y, T = _training_segments(train)
        corr = [correction_factors(o["correct"], train.input_names, train.target_names, u) for u in U]
        U = [u / fu for u, (fu, _) in zip(U, corr)]
        Y = [y / fy for y, (_, fy) in zip(Y, corr)]
        U = [_augment(u, t, derived, train.input_names, o["derivative_window"]) for u, t in zip(U, T)]
        U_all, Y_all = np.concatenate(U), np.concatenate(Y)
        u_mean, u_scale = U_all.mean(0), _scale(U_all)
        y_mean, y_scale = Y_all.mean(0), _scale(Y_all)
        Z = [(y - y_mean) / y_scale for y in Y]
        # TV derivative with time counted in samples, so that tv_alpha does not depend on dt
        dZ = []
        for seg, z, t in zip(train.segments, Z, T):
            try:
                dZ.append(tv_derivative(z, (t - t[0]) / train.dt, o["tv_alpha"], order=o["tv_order"]) / train.dt)
            except DataError as exc:
                raise DataError(f"method 'moe', training segment {seg.id!r}: {exc}") from None
        dZ_all = np.concatenate(dZ)
        d_scale = np.sqrt((dZ_all**2).mean(0))
        d_scale = np.where(d_scale > 0, d_scale, 1.0)
        Us = (U_all - u_mean) / u_scale
        Z_all = np.concatenate(Z)
        si = [train.input_names.index(c) for c in sched_in]
        ei = [names.index(c) for c in expert_in]
        V = np.hstack([Us[:, si]] + ([Z_all] if o["scheduler_state"] else []))
        X = np.hstack([Z_all, Us[:, ei]] + ([np.ones((len(Z_all), 1))] if o["bias"] else []))

        margin = _margin_matrix(o["max_time_constant"], sign, d_scale, train.target_names)
        device, dtype = _device(o["device"]), _dtype(o["dtype"])
        gen = torch.Generator().manual_seed(int(rng.integers(0, 2**63 - 1)))
        net = MixtureOfExperts(
            V.shape[1], len(train.target_names), X.shape[1], hp["n_experts"], o["expert_hidden"], hp["gate_hidden"],
            torch.as_tensor(sign), hp["k"], gen, dtype, torch.as_tensor(margin),
        )
        init_info: dict[str, Any] = {"init": o["init"]}
        if o["init"] == "lstsq":
            theta = lstsq_coefficients(X, dZ_all / d_scale, sign, margin)
        elif o["init"] == "output_error":
            edges = np.cumsum([len(z) for z in Z])[:-1]
            theta, tau, mse = output_error_coefficients(
                np.split(X, edges), Z, T, sign, margin * d_scale[:, None], d_scale, o["max_time_constant"], o["oe_poles"],
            )
            init_info.update(time_constant_s=tau.tolist(), simulation_mse=mse.tolist())
        if o["init"] != "random":
            warm_start(net, theta, sign, hp["k"], margin)
            init_info["theta"] = theta.tolist()
        net = net.to(device)
        with _cpu_threads(o["cpu_threads"], device):
            shoot = None
            if o["sim_weight"] > 0:
                if o["scheduler_state"]:
                    raise MethodError(
                        "method 'moe': sim_weight > 0 trains on simulated LPV trajectories; a state-scheduled "
                        "(quasi-LPV) model is not supported: set scheduler_state=False or sim_weight=0"
                    )
                edges = np.cumsum([len(z) for z in Z])[:-1]
                shoot = _Shooting(np.split(Us, edges), Z, T, o["shooting_window"], si, ei, d_scale)
            history = _train(net, V, X, dZ_all / d_scale, hp, o, gen, device, dtype, shoot)
        if o["clip_schedulers"]:
            net.v_lo.copy_(torch.as_tensor(V.min(0), dtype=dtype))
            net.v_hi.copy_(torch.as_tensor(V.max(0), dtype=dtype))
        n_probe = min(o["probe_points"], len(V))
        probe = V[np.sort(rng.choice(len(V), size=n_probe, replace=False))]
        return MoEFitted(
            params=hp, options=dict(o), input_names=tuple(train.input_names), target_names=tuple(train.target_names),
            scheduler_inputs=tuple(sched_in), expert_inputs=tuple(expert_in), sign=sign,
            u_mean=u_mean, u_scale=u_scale, y_mean=y_mean, y_scale=y_scale, d_scale=d_scale,
            y_min=Y_all.min(0), y_max=Y_all.max(0),
            weights={k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()},
            probe=probe, loss_history=history, derived=derived, init_info=init_info,
        )

    # -- prediction -------------------------------------------------------------------------
    def predict(self, fitted: MoEFitted, data: Samples) -> SegmentPredictions:
        self.check_mode(data.mode)
        traj, _, diverged = simulate(fitted, data)
        return SegmentPredictions([y[s.rows] for y, s in zip(traj, data.segments)], diverged)

    def describe(self, fitted: MoEFitted) -> dict[str, Any]:
        """Expert count, hyperparameters, local linear systems and the frozen-stability verdict."""
        names = fitted.scheduler_names
        net = build_network(fitted, torch.device("cpu"))
        with torch.no_grad():
            gate = net.gate(torch.as_tensor(fitted.probe, dtype=_dtype(fitted.options["dtype"]))).numpy()
        # representative points: the median training scheduler point and each expert's home point
        pts = np.vstack([np.median(fitted.probe, axis=0), fitted.probe[np.argmax(gate, axis=0)]])
        labels = ["median"] + [f"expert {i} dominant" for i in range(gate.shape[1])]
        raw = _unstandardise_sched(fitted, pts)
        loc = local_coefficients(fitted, raw)
        systems = [
            {
                "label": lab,
                "scheduler": dict(zip(names, map(float, raw[j]))),
                "gate": loc["gate"][j].tolist(),
                "A": loc["A"][j].tolist(),
                "B": loc["B"][j].tolist(),
                "c": loc["c"][j].tolist(),
            }
            for j, lab in enumerate(labels)
        ]
        return {
            "n_experts": int(fitted.params["n_experts"]),
            "hyperparameters": {k: _plain(v) for k, v in fitted.params.items()},
            "state": list(fitted.target_names),
            "inputs": list(fitted.expert_inputs),
            "schedulers": list(names),
            "signs": {
                f"d{t}/dt <- {c}": ("+" if s > 0 else "-")
                for t, row in zip(fitted.target_names, fitted.sign)
                for c, s in zip(fitted.regressor_names, row)
                if s != 0
            },
            "local_systems": systems,
            "frozen_stability": frozen_stability(fitted),
            "warm_start": {k: v for k, v in fitted.init_info.items() if k != "theta"},
            # local systems are in corrected units for the columns named here (option correct)
            "corrected": {c: dict(by) for c, by in (fitted.options.get("correct") or {}).items()},
            "max_time_constant_s": fitted.options.get("max_time_constant"),
            "sim_weight": fitted.options.get("sim_weight", 0.0),
            "final_loss": fitted.loss_history[-1] if fitted.loss_history else None,
        }


# -- public helpers -------------------------------------------------------------------------
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


def build_network(fitted: MoEFitted, device: torch.device) -> MixtureOfExperts:
    """The torch module of ``fitted`` on ``device`` (weights copied from the stored arrays)."""
    hp, dtype = fitted.params, _dtype(fitted.options["dtype"])
    net = MixtureOfExperts(
        len(fitted.scheduler_names), len(fitted.target_names), len(fitted.regressor_names), hp["n_experts"],
        fitted.options["expert_hidden"], hp["gate_hidden"], torch.as_tensor(fitted.sign), hp["k"],
        torch.Generator().manual_seed(0), dtype,
    )
    state = {k: torch.as_tensor(v) for k, v in fitted.weights.items()}
    state.setdefault("margin", torch.zeros_like(torch.as_tensor(fitted.sign)))  # models fitted before margins existed
    net.load_state_dict(state)
    return net.to(device).eval()


def local_coefficients(fitted: MoEFitted, points: np.ndarray) -> dict[str, np.ndarray]:
    """The local linear systems dy/dt = A y + B u + c at scheduler ``points``, in raw units.

    ``points`` is (P, n_sched) in raw units, columns in ``fitted.scheduler_names`` order.
    Returns ``gate`` (P, M) and the gated ``A`` (P, k, k), ``B`` (P, k, n_u), ``c``
    (P, k), plus each expert's ``expert_A`` (P, M, k, k), ``expert_B``, ``expert_c``.
    """
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if points.shape[1] != len(fitted.scheduler_names):
        raise MethodError(
            f"method 'moe': scheduler points have {points.shape[1]} columns; expected {len(fitted.scheduler_names)} "
            f"({', '.join(fitted.scheduler_names)})"
        )
    net = build_network(fitted, torch.device("cpu"))
    v = torch.as_tensor(_standardise_sched(fitted, points), dtype=_dtype(fitted.options["dtype"]))
    with torch.no_grad():
        G = net.coefficients(v).double().numpy()  # (P, M, k, q)
        gate = net.gate(v).double().numpy()
    k, ne = len(fitted.target_names), len(fitted.expert_inputs)
    ei = [fitted.augmented_names.index(c) for c in fitted.expert_inputs]
    u_mean, u_scale = fitted.u_mean[ei], fitted.u_scale[ei]
    row = (fitted.y_scale * fitted.d_scale)[:, None]  # dy_j/dt = y_scale_j d_scale_j (G [z; u; 1])_j
    A = G[..., :k] * row / fitted.y_scale
    B = G[..., k : k + ne] * row / u_scale
    g1 = G[..., k + ne] if fitted.options["bias"] else np.zeros(G.shape[:-1])
    c = g1 * row[:, 0] - A @ fitted.y_mean - B @ u_mean
    mix = lambda a: np.einsum("pm,pm...->p...", gate, a)  # noqa: E731
    return {"gate": gate, "A": mix(A), "B": mix(B), "c": mix(c), "expert_A": A, "expert_B": B, "expert_c": c}


def frozen_stability(fitted: MoEFitted) -> dict[str, Any]:
    """Seed 003's frozen-stability verdict over the training scheduler points.

    ``state_coefficients_negative``: every expert's own-state coefficient is < 0 at every
    probe point (what the sign constraint promises, checked in floating point: a
    softplus that underflows to 0 fails it). ``max_real_eigenvalue``: of the gated A(v)
    over the probe points. ``stable`` needs both; for one output the first implies the
    second, for several outputs cross-couplings can still destabilise A(v). With the
    state among the schedulers (quasi-LPV) A(v) is the frozen coefficient, not a Jacobian.
    """
    loc = local_coefficients(fitted, _unstandardise_sched(fitted, fitted.probe))
    diag = np.diagonal(loc["expert_A"], axis1=-2, axis2=-1)  # (P, M, k)
    eig = np.linalg.eigvals(loc["A"]).real
    return {
        "state_coefficients_negative": bool((diag < 0).all()),
        "max_state_coefficient": float(diag.max()),
        "max_real_eigenvalue": float(eig.max()),
        "stable": bool((diag < 0).all() and eig.max() < 0),
        "n_points": int(len(fitted.probe)),
    }


def gate_weights(fitted: MoEFitted, data: Samples) -> list[np.ndarray]:
    """Gate weights over time, one (N, n_experts) array per segment (rows as in ``predict``).

    With the state among the schedulers the gate is evaluated along the simulated
    trajectory (as in seed 003's figures), never the measured one.
    """
    _, gates, _ = simulate(fitted, data, record_gate=True)
    return [g[s.rows] for g, s in zip(gates, data.segments)]


def simulate(
    fitted: MoEFitted, data: Samples, record_gate: bool = False, stepwise: bool | None = None
) -> tuple[list[np.ndarray], list[np.ndarray] | None, np.ndarray]:
    """Open-loop simulation of every segment of ``data`` from its y0, batched over segments.

    Returns the trajectories (one (N_s, k) array per segment over all its raw rows), the
    gate weights at every sample (when ``record_gate``), and the per-segment diverged flags.
    ``stepwise`` forces (True) or forbids (False) evaluating the network at every
    integrator stage; by default only state-scheduled models need it, and LPV models use
    the equivalent affine step computed for whole chunks at once.
    """
    with _cpu_threads(fitted.options["cpu_threads"], _device(fitted.options["device"])), torch.no_grad():
        return _simulate(fitted, data, record_gate, stepwise)


def _simulate(
    fitted: MoEFitted, data: Samples, record_gate: bool, stepwise: bool | None = None
) -> tuple[list[np.ndarray], list[np.ndarray] | None, np.ndarray]:
    o = fitted.options
    segs = data.segments
    if data.mode != "simulation":
        raise MethodError(f"method 'moe' simulates open loop: give samples in mode 'simulation', not {data.mode!r}")
    if tuple(data.target_names) != fitted.target_names:
        raise MethodError(f"method 'moe': fitted for targets {fitted.target_names}, asked for {tuple(data.target_names)}")
    missing = [c for c in fitted.input_names if c not in data.input_names]
    if missing:
        raise MethodError(f"method 'moe': the data lack input column(s) {', '.join(missing)} that the model was fitted on")
    if not segs:
        return [], ([] if record_gate else None), np.zeros(0, dtype=bool)
    col = [data.input_names.index(c) for c in fitted.input_names]
    device, dtype = _device(o["device"]), _dtype(o["dtype"])
    lens = np.array([len(s.U) for s in segs])
    S, L, k = len(segs), int(lens.max()), len(fitted.target_names)
    U = np.empty((S, L, len(fitted.augmented_names)))
    H = np.zeros((S, L - 1))
    z0 = np.empty((S, k))
    f_out = []  # per segment: the correction factors of the targets (raw = corrected x factor)
    for j, s in enumerate(segs):
        if s.y0 is None:
            raise MethodError(f"method 'moe': segment {s.id!r} has no initial output y0 (samples must be in mode 'simulation')")
        u = s.U[:, col]
        if not (np.isfinite(u).all() and np.isfinite(s.y0).all()):
            raise MethodError(f"method 'moe': segment {s.id!r} holds NaN or inf in its inputs or y0; clean or drop it")
        fu, fy = correction_factors(o.get("correct"), fitted.input_names, fitted.target_names, u)
        u = u / fu
        f_out.append(fy)
        u = _augment(u, s.t, fitted.derived, fitted.input_names, o["derivative_window"])
        U[j, : len(u)], U[j, len(u) :] = u, u[-1]
        h = np.diff(s.t)
        if (h <= 0).any():
            raise MethodError(f"method 'moe': segment {s.id!r}: time does not increase at row {int(np.argmax(h <= 0)) + 1}")
        H[j, : len(h)] = h  # padding steps have h = 0: the state stays put
        z0[j] = (s.y0 / fy[0] - fitted.y_mean) / fitted.y_scale
    as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
    span = fitted.y_max - fitted.y_min
    sim = _Sim(
        options=o,
        n_experts=int(fitted.params["n_experts"]),
        net=build_network(fitted, device),
        U=as_t((U - fitted.u_mean) / fitted.u_scale),
        H=as_t(H),
        lo=as_t((fitted.y_min - o["envelope"] * span - fitted.y_mean) / fitted.y_scale),
        hi=as_t((fitted.y_max + o["envelope"] * span - fitted.y_mean) / fitted.y_scale),
        d_scale=as_t(fitted.d_scale),
        si=[fitted.input_names.index(c) for c in fitted.scheduler_inputs],
        ei=[fitted.augmented_names.index(c) for c in fitted.expert_inputs],
        record_gate=record_gate,
    )
    if stepwise is None:
        stepwise = bool(o["scheduler_state"])
    if not stepwise and o["scheduler_state"]:
        raise MethodError("method 'moe': a state-scheduled (quasi-LPV) model can only be simulated step by step")
    traj, gates, alive = (sim.stepwise if stepwise else sim.affine)(as_t(z0))
    Y = traj.double().cpu().numpy() * fitted.y_scale + fitted.y_mean
    out = [Y[j, : lens[j]] * f_out[j] for j in range(S)]
    G_out = None if gates is None else [g[: lens[j]] for j, g in enumerate(gates.double().cpu().numpy())]
    return out, G_out, ~alive.cpu().numpy()


@dataclass
class _Sim:
    """One batched simulation: standardised padded inputs (S, L, n_u), steps H (S, L-1), envelope."""

    options: dict[str, Any]
    n_experts: int
    net: MixtureOfExperts
    U: torch.Tensor
    H: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    d_scale: torch.Tensor
    si: list[int]
    ei: list[int]
    record_gate: bool

    def _regressors(self, z: torch.Tensor | None, u: torch.Tensor) -> torch.Tensor:
        """[z; u_e; 1] (..., q); with ``z=None`` only the input part [u_e; 1]."""
        parts = [] if z is None else [z]
        parts.append(u[..., self.ei])
        if self.options["bias"]:
            parts.append(torch.ones_like(u[..., :1]))
        return torch.cat(parts, dim=-1)

    def _ok(self, z: torch.Tensor) -> torch.Tensor:
        return torch.isfinite(z).all(-1) & ((z >= self.lo) & (z <= self.hi)).all(-1)

    def _outputs(self, S: int, L: int, k: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        traj = torch.empty((S, L, k), dtype=self.U.dtype, device=self.U.device)
        m = self.n_experts
        gates = torch.empty((S, L, m), dtype=self.U.dtype, device=self.U.device) if self.record_gate else None
        return traj, gates

    def stepwise(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """Any model (also quasi-LPV): the network is evaluated at every integrator stage."""
        o, (S, L, _), k = self.options, self.U.shape, z.shape[1]

        def rhs(zz: torch.Tensor, uu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            v = torch.cat([uu[:, self.si]] + ([zz] if o["scheduler_state"] else []), dim=1)
            G, alpha = self.net.mixed(v)
            return self.d_scale * torch.einsum("skq,sq->sk", G, self._regressors(zz, uu)), alpha

        step = _rk4 if o["integrator"] == "rk4" else _euler
        hold = o["input_interp"] == "hold"
        traj, gates = self._outputs(S, L, k)
        alive = torch.ones(S, dtype=torch.bool, device=z.device)
        traj[:, 0] = z
        for n in range(L - 1):
            u0, u1 = self.U[:, n], self.U[:, n + 1]
            z_next, alpha = step(rhs, z, u0, u0 if hold else u1, self.H[:, n : n + 1])
            if gates is not None:
                gates[:, n] = alpha
            alive &= self._ok(z_next)
            z = torch.where(alive[:, None], z_next, z)  # a diverged segment is held where it left
            traj[:, n + 1] = z
        if gates is not None:
            gates[:, L - 1] = rhs(z, self.U[:, L - 1])[1]
        return traj, gates, alive

    def _affine_parts(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """dz/dt = A z + w at inputs ``u`` (S, C, n_u): A (S, C, k, k), w (S, C, k), gate (S, C, M)."""
        G, alpha = self.net.mixed(u[..., self.si])
        k = G.shape[-2]
        A = self.d_scale[:, None] * G[..., :k]
        w = self.d_scale * torch.einsum("sckq,scq->sck", G[..., k:], self._regressors(None, u))
        return A, w, alpha

    def step_maps(self, a: int, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """LPV models: one RK4 or Euler step n -> n+1 (a <= n < b) is z' = Phi[n] z + gamma[n].

        Returns Phi (S, b-a, k, k), gamma (S, b-a, k) and the gate (S, b-a+1, M) at samples a..b.
        """
        o = self.options
        A, w, alpha = self._affine_parts(self.U[:, a : b + 1])  # at samples a..b
        k = A.shape[-1]
        eye = torch.eye(k, dtype=A.dtype, device=A.device)
        h = self.H[:, a:b, None]
        A0, w0 = A[:, :-1], w[:, :-1]
        if o["integrator"] == "euler":
            return eye + h[..., None] * A0, h * w0, alpha
        if o["input_interp"] == "hold":
            Am, wm, A1, w1 = A0, w0, A0, w0
        else:
            Am, wm, _ = self._affine_parts(0.5 * (self.U[:, a:b] + self.U[:, a + 1 : b + 1]))
            A1, w1 = A[:, 1:], w[:, 1:]
        hh = h[..., None]
        mv = lambda M, x: (M @ x[..., None])[..., 0]  # noqa: E731
        P1, q1 = A0, w0
        P2, q2 = Am @ (eye + 0.5 * hh * P1), mv(Am, 0.5 * h * q1) + wm
        P3, q3 = Am @ (eye + 0.5 * hh * P2), mv(Am, 0.5 * h * q2) + wm
        P4, q4 = A1 @ (eye + hh * P3), mv(A1, h * q3) + w1
        Phi = eye + hh / 6.0 * (P1 + 2 * P2 + 2 * P3 + P4)
        gamma = h / 6.0 * (q1 + 2 * q2 + 2 * q3 + q4)
        return Phi, gamma, alpha

    def rollout(self, z: torch.Tensor) -> torch.Tensor:
        """Differentiable open-loop trajectories (S, L, k) of an LPV model from ``z`` (S, k):
        no envelope, no divergence hold (for training on the simulation error)."""
        Phi, gamma, _ = self.step_maps(0, self.U.shape[1] - 1)
        M, c = affine_prefix_scan(Phi, gamma)
        return torch.cat([z[:, None], (M @ z[:, None, :, None])[..., 0] + c], dim=1)

    def affine(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """LPV models (schedulers free of the state): dz/dt = A(t) z + w(t), so one RK4 or Euler
        step is z' = Phi z + gamma with Phi, gamma computed for a whole chunk of steps at once;
        only the recurrence itself runs step by step."""
        (S, L, _), k = self.U.shape, z.shape[1]
        traj, gates = self._outputs(S, L, k)
        alive = torch.ones(S, dtype=torch.bool, device=z.device)
        traj[:, 0] = z
        width = S * self.n_experts * k * (k + len(self.ei) + 1) * 3
        chunk = int(np.clip(4_000_000 // max(width, 1), 16, max(L - 1, 16)))
        for a in range(0, L - 1, chunk):
            b = min(L - 1, a + chunk)
            Phi, gamma, alpha = self.step_maps(a, b)
            if gates is not None:
                gates[:, a : b + 1] = alpha
            part = torch.empty((S, b - a, k), dtype=z.dtype, device=z.device)
            zz = z
            for n in range(b - a):
                zz = (Phi[:, n] @ zz[..., None])[..., 0] + gamma[:, n]
                part[:, n] = zz
            # divergence: keep the valid prefix of each segment, hold its last valid state after
            valid = torch.cumprod(self._ok(part).to(torch.int8), dim=1).bool() & alive[:, None]
            n_valid = valid.sum(1)
            last = torch.where(
                (n_valid > 0)[:, None], part[torch.arange(S, device=z.device), (n_valid - 1).clamp(min=0)], z
            )
            part = torch.where(valid[..., None], part, last[:, None, :])
            traj[:, a + 1 : b + 1] = part
            z, alive = part[:, -1], valid[:, -1]
        return traj, gates, alive


def affine_prefix_scan(Phi: torch.Tensor, gamma: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """All prefixes of the affine recurrence z_{n+1} = Phi_n z_n + gamma_n in log2(N) batched steps.

    ``Phi`` (S, N, k, k), ``gamma`` (S, N, k). Returns (M, c) with z_{n+1} = M_n z_0 + c_n. The
    maps compose associatively, (M2, c2) o (M1, c1) = (M2 M1, M2 c1 + c2), so a Hillis-Steele scan
    (doubling the reach each round) replaces N sequential steps; differentiable, for training on
    simulated windows.
    """
    M, c = Phi, gamma
    d, N = 1, Phi.shape[1]
    while d < N:
        M, c = (
            torch.cat([M[:, :d], M[:, d:] @ M[:, :-d]], dim=1),
            torch.cat([c[:, :d], (M[:, d:] @ c[:, :-d, :, None])[..., 0] + c[:, d:]], dim=1),
        )
        d *= 2
    return M, c


# -- internals ---------------------------------------------------------------------------------
@contextmanager
def _cpu_threads(limit: int | None, device: torch.device) -> Iterator[None]:
    """Cap torch's intra-op threads on CPU for the duration, then restore them.

    The networks are tiny: per-op thread fan-out buys nothing and, on busy shared cores,
    each synchronised reduction (the gate's softmax) can stall for a scheduler quantum.
    Parallelism belongs to the runner's process pool.
    """
    before = torch.get_num_threads()
    if limit is None or device.type != "cpu" or limit >= before:
        yield
        return
    torch.set_num_threads(limit)
    try:
        yield
    finally:
        torch.set_num_threads(before)


Rhs = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]


def _euler(f: Rhs, z: torch.Tensor, u0: torch.Tensor, u1: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    k1, alpha = f(z, u0)
    return z + h * k1, alpha


def _rk4(f: Rhs, z: torch.Tensor, u0: torch.Tensor, u1: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Classical RK4 with the inputs linearly interpolated to the half step."""
    um = 0.5 * (u0 + u1)
    k1, alpha = f(z, u0)
    k2, _ = f(z + 0.5 * h * k1, um)
    k3, _ = f(z + 0.5 * h * k2, um)
    k4, _ = f(z + h * k3, u1)
    return z + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), alpha


class _Shooting:
    """Training windows for the simulation-error term: every segment cut into windows of
    ``window_s`` seconds from a random offset per epoch, each simulated open loop from its
    measured first value (multiple shooting), batched over windows."""

    def __init__(self, Us: Sequence[np.ndarray], Zs: Sequence[np.ndarray], Ts: Sequence[np.ndarray], window_s: float,
                 si: list[int], ei: list[int], d_scale: np.ndarray) -> None:
        self.Us, self.Zs, self.Ts, self.si, self.ei, self.d_scale = Us, Zs, Ts, si, ei, d_scale
        h = float(np.median(np.concatenate([np.diff(t) for t in Ts if len(t) > 1])))
        self.width = int(max(2, min(round(window_s / h) + 1, min(len(z) for z in Zs))))

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

    def loss(self, net: MixtureOfExperts, o: dict[str, Any], U: torch.Tensor, H: torch.Tensor, Z: torch.Tensor) -> torch.Tensor:
        """Mean squared simulation error (standardised units) of windows ``U``, ``H``, ``Z``."""
        inf = torch.full((Z.shape[-1],), torch.inf, dtype=Z.dtype, device=Z.device)
        sim = _Sim(
            options=o, n_experts=net.n_experts, net=net, U=U, H=H, lo=-inf, hi=inf,
            d_scale=torch.as_tensor(self.d_scale, dtype=Z.dtype, device=Z.device), si=self.si, ei=self.ei,
            record_gate=False,
        )
        return ((sim.rollout(Z[:, 0]) - Z) ** 2).mean()


def _train(
    net: MixtureOfExperts, V: np.ndarray, X: np.ndarray, D: np.ndarray, hp: dict[str, Any], o: dict[str, Any],
    gen: torch.Generator, device: torch.device, dtype: torch.dtype, shoot: _Shooting | None = None,
) -> list[float]:
    """Adam on seed 003's loss with shuffled minibatches; returns the mean loss per epoch.

    With ``shoot`` (option sim_weight > 0) every step adds sim_weight times the simulation error of
    a share of the epoch's windows (each window once per epoch): the derivative loss weights
    the fast dynamics, the simulation error the slow pole and the static gains that an
    open-loop prediction accumulates.
    """
    Vt, Xt, Dt = (torch.as_tensor(a, dtype=dtype, device=device) for a in (V, X, D))
    opt = torch.optim.Adam(net.parameters(), lr=hp["lr"])
    n, bs = len(Vt), int(o["batch_size"])
    n_steps = -(-n // bs)
    history = []
    net.train()
    for _ in range(hp["epochs"]):
        perm = torch.randperm(n, generator=gen).to(device)
        if shoot is not None:
            Uw, Hw, Zw = (torch.as_tensor(a, dtype=dtype, device=device) for a in shoot.cut(gen))
            wperm = torch.randperm(len(Zw), generator=gen).to(device)
            per = -(-len(Zw) // n_steps)
        total = torch.zeros((), dtype=dtype, device=device)
        for step, a in enumerate(range(0, n, bs)):
            idx = perm[a : a + bs]
            f, alpha = net(Vt[idx], Xt[idx])
            loss = moe_loss(f, alpha, Dt[idx], hp["beta1"], hp["beta2"], o["competitive"])
            if shoot is not None:
                w = wperm[step * per : (step + 1) * per]
                if len(w):
                    loss = loss + o["sim_weight"] * shoot.loss(net, o, Uw[w], Hw[w], Zw[w])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.detach() * len(idx)
        history.append(float(total) / n)
    net.eval()
    if not np.isfinite(history[-1]):
        raise MethodError(f"method 'moe': training diverged (loss {history[-1]}); lower lr={hp['lr']} or check the data")
    return history


def _training_segments(train: Samples) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Per-segment raw inputs, targets and times; whole segments with finite values only."""
    if not train.has_targets:
        raise MethodError("method 'moe': the training samples carry no targets")
    U, Y, T = [], [], []
    for s in train.segments:
        if len(s.rows) != len(s.U) or not np.array_equal(s.rows, np.arange(len(s.U))):
            raise MethodError(
                f"method 'moe': training segment {s.id!r} is a row subsample ({len(s.rows)} of {len(s.U)} rows); "
                "derivative targets need whole segments: resample by segment, not by row"
            )
        if len(s.U) < 3:
            raise MethodError(f"method 'moe': training segment {s.id!r} has {len(s.U)} rows; at least 3 are needed for derivatives")
        for what, a, names in (("inputs", s.U, train.input_names), ("targets", s.y, train.target_names)):
            bad = np.argwhere(~np.isfinite(a))
            if bad.size:
                r, c = bad[0]
                raise MethodError(f"method 'moe': training segment {s.id!r}, {what} column {names[c]!r}, row {r}: NaN or inf")
        U.append(s.U)
        Y.append(s.y)
        T.append(s.t)
    if not U:
        raise MethodError("method 'moe': the training samples are empty; give at least one segment")
    return U, Y, T


def _inverse_softplus(mag: np.ndarray, k: float) -> np.ndarray:
    """x with log(1 + e^{kx}) / k = mag (> 0), without overflow for large k mag."""
    km = np.asarray(k * mag, dtype=np.float64)
    return np.where(km > 30.0, mag, np.log(np.expm1(np.minimum(km, 30.0))) / k)


def _bounds(sign_row: np.ndarray, margin_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """lsq_linear bounds of one output's coefficients: sign -1 -> <= -margin, +1 -> >= margin, 0 free."""
    lo = np.where(sign_row > 0, margin_row, -np.inf)
    hi = np.where(sign_row < 0, -margin_row, np.inf)
    return lo, hi


def lstsq_coefficients(X: np.ndarray, D: np.ndarray, sign: np.ndarray, margin: np.ndarray | None = None) -> np.ndarray:
    """The linear model D ~ X theta^T (theta (k_out, q)) by least squares within the sign bounds.

    A constrained coefficient is bounded (scipy's ``lsq_linear``) instead of fitted freely and
    clipped: when the data prefer the wrong sign, the others adapt to the coefficient at its
    bound. A tiny ridge (1e-6 of the mean diagonal of X^T X) keeps collinear columns finite.
    """
    margin = np.zeros_like(sign) if margin is None else margin
    q = X.shape[1]
    ridge = np.sqrt(1e-6 * np.trace(X.T @ X) / q)
    Xr = np.vstack([X, ridge * np.eye(q)])
    theta = np.empty((D.shape[1], q))
    for j in range(D.shape[1]):
        lo, hi = _bounds(sign[j], margin[j])
        if np.isinf(lo).all() and np.isinf(hi).all():
            theta[j] = np.linalg.lstsq(Xr, np.r_[D[:, j], np.zeros(q)], rcond=None)[0]
        else:
            theta[j] = lsq_linear(Xr, np.r_[D[:, j], np.zeros(q)], bounds=(lo, hi), method="bvls").x
    return theta


def first_order_responses(X: np.ndarray, t: np.ndarray, a: float) -> np.ndarray:
    """Responses x_j of dx/dt = a x + X[:, j] from x(t0) = 0, trapezoidal rule on uniform steps (n, c).

    The trapezoid (Tustin) recurrence x[n+1] = p x[n] + q (X[n] + X[n+1]), p = (1 + a h/2) / (1 - a h/2),
    q = (h/2) / (1 - a h/2), is scipy's ``lfilter``; for a < 0 it is stable for every step h.
    """
    h = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    den = 1.0 - 0.5 * a * h
    p, q = (1.0 + 0.5 * a * h) / den, 0.5 * h / den
    return lfilter([q, q], [1.0, -p], X, axis=0, zi=-q * X[:1])[0]


def output_error_coefficients(
    Xs: Sequence[np.ndarray], Zs: Sequence[np.ndarray], Ts: Sequence[np.ndarray], sign: np.ndarray,
    margin_rate: np.ndarray, d_scale: np.ndarray, max_time_constant: float | None, n_poles: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The LTI model dz_j/dt = a_j z_j + b_j^T x_{-j} whose open-loop simulation best fits the training segments.

    ``Xs`` are the per-segment regressors [z; u; 1] (standardised), ``Zs`` the standardised
    targets, ``Ts`` the times. For a fixed pole a the simulated output from the measured z(t0)
    is linear in b (separable least squares): z(t) = e^{a (t-t0)} z(t0) + sum_i b_i x_i(t) with
    x_i the response of dx/dt = a x + (regressor i). So each pole on a log grid of time
    constants (from the sample step to ``max_time_constant``, or to the longest segment) costs
    one sign-bounded least squares, and the pole with the least simulation error wins. Other
    targets (several outputs) enter as measured regressors. ``margin_rate`` is the margin in
    1/s. Returns theta (k, q) in network units (divided by ``d_scale``), the chosen time
    constants (s) and the training simulation MSEs (standardised units).

    Fitting derivatives weights the fast part of the dynamics; this weights what an open-loop
    simulation gets wrong: the slow pole and the static gains.
    """
    k, q = sign.shape[0], Xs[0].shape[1]
    dts = [float(np.median(np.diff(t))) for t in Ts if len(t) > 1]
    longest = max(float(t[-1] - t[0]) for t in Ts)
    tau_hi = longest if max_time_constant is None else float(max_time_constant)
    tau_lo = min(min(dts) if dts else 1.0, tau_hi)
    taus = np.geomspace(tau_lo, tau_hi, n_poles) if tau_hi > tau_lo else np.array([tau_hi])
    theta, best_tau, best_mse = np.zeros((k, q)), np.zeros(k), np.full(k, np.inf)
    for j in range(k):
        if sign[j, j] > 0:
            raise MethodError(
                f"method 'moe': init='output_error' fits a stable pole, but the own-state coefficient of target {j} "
                "is constrained positive; use init='lstsq' or a '-' / 'free' sign"
            )
        others = [i for i in range(q) if i != j]
        lo, hi = _bounds(sign[j, others], margin_rate[j, others])
        y = np.concatenate([z[:, j] for z in Zs])
        for tau in taus:
            a = -1.0 / tau
            R, free = [], []
            for x, z, t in zip(Xs, Zs, Ts):
                R.append(first_order_responses(x[:, others], t, a))
                h = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
                free.append(z[0, j] * ((1.0 + 0.5 * a * h) / (1.0 - 0.5 * a * h)) ** np.arange(len(z)))
            R_all, target = np.vstack(R), y - np.concatenate(free)
            if np.isinf(lo).all() and np.isinf(hi).all():
                b = np.linalg.lstsq(R_all, target, rcond=None)[0]
            else:
                b = lsq_linear(R_all, target, bounds=(lo, hi), method="bvls").x
            mse = float(np.mean((target - R_all @ b) ** 2))
            if mse < best_mse[j]:
                best_mse[j], best_tau[j] = mse, tau
                theta[j, j], theta[j, others] = a / d_scale[j], b / d_scale[j]
    return theta, best_tau, best_mse


def warm_start(
    net: MixtureOfExperts, theta: np.ndarray, sign: np.ndarray, k: float, margin: np.ndarray | None = None,
    shrink: float = 0.1,
) -> None:
    """Start every expert at the linear model theta (k_out, q; network units).

    Fitting scheduled coefficients on derivative targets from a random start leaves the
    slow part of the dynamics (the pole and static gain that dominate an open-loop
    simulation) poorly determined. Each expert's output bias is set to theta (through the
    inverse of the signed softplus; a constrained coefficient at or inside its bound starts
    1e-2 beyond it, since the softplus never reaches 0) and its scheduled part is scaled by
    ``shrink``, so Adam refines a good LTI model into an LPV mixture instead of searching
    from noise.
    """
    margin = np.zeros_like(sign) if margin is None else margin
    raw = np.array(theta, dtype=np.float64)
    on = sign != 0
    excess = np.maximum(sign[on] * raw[on] - margin[on], 1e-2)  # what the softplus must carry
    raw[on] = _inverse_softplus(excess, k)
    with torch.no_grad():
        net.b2.copy_(torch.as_tensor(raw.reshape(-1), dtype=net.b2.dtype).expand_as(net.b2))
        net.w2.mul_(shrink)


def _margin_matrix(max_time_constant: float | None, sign: np.ndarray, d_scale: np.ndarray, targets: Sequence[str]) -> np.ndarray:
    """(k, q) least magnitudes of the constrained coefficients, network units: 1/(tau_max d_scale) on own states."""
    margin = np.zeros_like(sign)
    if max_time_constant is None:
        return margin
    k = len(targets)
    wrong = [t for j, t in enumerate(targets) if sign[j, j] >= 0]
    if wrong:
        raise MethodError(
            f"method 'moe': option max_time_constant bounds own-state coefficients below 0, but target(s) "
            f"{', '.join(wrong)} have no '-' sign; use signs='stable' or {{'{wrong[0]}': '-'}}"
        )
    margin[np.arange(k), np.arange(k)] = 1.0 / (float(max_time_constant) * d_scale)
    return margin


def correction_factors(
    spec: Mapping[str, Mapping[str, Sequence[float]]] | None, inputs: Sequence[str], targets: Sequence[str], U: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Standard-day correction factors prod (U[:, c] / reference)^exponent from the raw inputs ``U`` (n, n_u).

    Returns (input factors (n, n_u), target factors (n, k)), 1 where a column is not corrected;
    the corrected value of a column is its raw value divided by its factor.
    """
    fu, fy = np.ones((len(U), len(inputs))), np.ones((len(U), len(targets)))
    if not spec:
        return fu, fy
    for col, by in spec.items():
        if col in inputs:
            out, j = fu, list(inputs).index(col)
        elif col in targets:
            out, j = fy, list(targets).index(col)
        else:
            raise MethodError(
                f"method 'moe': option correct names {col!r}, neither a target ({', '.join(targets)}) nor an input "
                f"({', '.join(inputs)})"
            )
        for c, (ref, exponent) in by.items():
            if c not in inputs:
                raise MethodError(f"method 'moe': option correct[{col!r}] uses {c!r}, not among the inputs ({', '.join(inputs)})")
            if c in spec:
                raise MethodError(f"method 'moe': option correct[{col!r}] uses {c!r}, which is itself corrected; correct by raw columns only")
            ratio = U[:, list(inputs).index(c)] / float(ref)
            if not (ratio > 0).all():
                raise MethodError(
                    f"method 'moe': option correct[{col!r}]: input {c!r} is <= 0 at row {int(np.argmax(~(ratio > 0)))}; "
                    "correction factors need positive values (absolute pressures and temperatures)"
                )
            out[:, j] *= ratio ** float(exponent)
    return fu, fy


def _derived_columns(spec: Mapping[str, int] | None, inputs: Sequence[str]) -> tuple[tuple[str, str, int], ...]:
    """(name, column, order) of every asked-for input derivative, orders 1..n per column."""
    if not spec:
        return ()
    unknown = [c for c in spec if c not in inputs]
    if unknown:
        raise MethodError(
            f"method 'moe': option input_derivatives names {', '.join(map(repr, unknown))}, not among the run-time "
            f"inputs ({', '.join(inputs)})"
        )
    return tuple((f"d{c}/dt" if n == 1 else f"d{n}{c}/dt{n}", c, n) for c, top in spec.items() for n in range(1, int(top) + 1))


def input_derivative(x: np.ndarray, t: np.ndarray, order: int, window_s: float) -> np.ndarray:
    """Smoothed ``order``-th time derivative of the columns of ``x`` (n, c) sampled at times ``t``.

    A cubic Savitzky-Golay fit over about ``window_s`` seconds (scipy; the edges use the fit of
    the first / last window). Needs only the inputs, so it is the same at fit and run time;
    like the seed's TV-differentiated input derivatives it is not causal. Segments too short
    for a cubic window fall back to repeated central differences.
    """
    n = len(x)
    if n < 2:
        return np.zeros_like(x, dtype=np.float64)
    h = float(np.median(np.diff(t)))
    w = min(int(round(window_s / h)) | 1, n if n % 2 else n - 1)
    if w >= 5:
        return savgol_filter(x, w, 3, deriv=order, delta=h, axis=0, mode="interp")
    d = np.asarray(x, dtype=np.float64)
    for _ in range(order):
        d = np.gradient(d, t, axis=0) if len(d) > 1 else np.zeros_like(d)
    return d


def _augment(u: np.ndarray, t: np.ndarray, derived: Sequence[tuple[str, str, int]], inputs: Sequence[str], window_s: float) -> np.ndarray:
    """The raw inputs ``u`` (n, n_u) followed by the derived input derivatives (n, len(derived))."""
    if not derived:
        return u
    cols = [input_derivative(u[:, [list(inputs).index(c)]], t, n, window_s) for _, c, n in derived]
    return np.hstack([u] + cols)


def _names(chosen: Sequence[str] | None, available: Sequence[str], option: str) -> list[str]:
    if chosen is None:
        return list(available)
    unknown = [c for c in chosen if c not in available]
    if unknown:
        raise MethodError(
            f"method 'moe': option {option} names {', '.join(map(repr, unknown))}, not among the run-time inputs "
            f"({', '.join(available)})"
        )
    return list(chosen)


def _sign_matrix(signs: Any, targets: Sequence[str], inputs: Sequence[str], bias: bool) -> np.ndarray:
    """(k, q) signs over [z; u; 1]: a target name constrains its own-state coefficient, an input its column."""
    k, q = len(targets), len(targets) + len(inputs) + int(bias)
    sign = np.zeros((k, q))
    if signs == "stable":
        sign[np.arange(k), np.arange(k)] = -1
    elif isinstance(signs, Mapping):
        for name, word in signs.items():
            if name in targets:
                j = list(targets).index(name)
                sign[j, j] = _SIGN_WORDS[word]
            elif name in inputs:
                sign[:, k + list(inputs).index(name)] = _SIGN_WORDS[word]
            else:
                raise MethodError(
                    f"method 'moe': option signs names {name!r}, which is neither a target ({', '.join(targets)}) "
                    f"nor an expert input ({', '.join(inputs)})"
                )
    return sign


def _standardise_sched(fitted: MoEFitted, raw: np.ndarray) -> np.ndarray:
    si = [fitted.input_names.index(c) for c in fitted.scheduler_inputs]
    mean = np.r_[fitted.u_mean[si], fitted.y_mean if fitted.options["scheduler_state"] else []]
    scale = np.r_[fitted.u_scale[si], fitted.y_scale if fitted.options["scheduler_state"] else []]
    return (raw - mean) / scale


def _unstandardise_sched(fitted: MoEFitted, std: np.ndarray) -> np.ndarray:
    zero = _standardise_sched(fitted, np.zeros(std.shape[-1]))
    unit = _standardise_sched(fitted, np.ones(std.shape[-1])) - zero
    return (std - zero) / unit


def _scale(values: np.ndarray) -> np.ndarray:
    """Column standard deviations usable as divisors (a constant column keeps scale 1)."""
    s = values.std(0)
    return np.where(s > 1e-9 * (1.0 + np.abs(values.mean(0))), s, 1.0)


def _device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise MethodError("method 'moe': device='cuda' but torch sees no CUDA device; use device='auto' or 'cpu'")
    return torch.device(name)


def _dtype(name: str) -> torch.dtype:
    return torch.float64 if name == "float64" else torch.float32


def _plain(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v
