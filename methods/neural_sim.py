"""Shared machinery of the torch simulation-mode methods ``neural-ss`` and ``gru``: data, training, free run.

Both methods are networks that map an initialisation window (the last ``lags`` measured
inputs and outputs before a start time) through an encoder to an initial state, then run
free on the inputs alone. They differ only in the network (``methods/neural_ss.py``,
``methods/gru.py``); everything else is here, so both are trained and simulated the same
way:

- Signals are standardised with the training mean and standard deviation (SD 0 counts as 1).
- Training minimises the multi-step free-run (simulation) error: random subsections of
  ``horizon`` samples of the training records, each started from its own encoder window
  (the ``lags`` samples before it, edge-padded before a record's first row, as at
  prediction time), mean squared standardised error over the subsection, Adam with a
  cosine decay of the learning rate to ``lr_final`` x lr over ``steps``, gradient norm
  clipped. A batch whose loss is not finite is skipped (counted in ``describe``).
- Early stopping: the last ``val_fraction`` of every training record is held out and
  simulated in free run from its own encoder window (the samples before it) every
  ``steps / validations`` gradient steps; the weights with the lowest free-run error are
  kept, and training stops after ``patience`` validations without improvement.
- Prediction: a segment's measured outputs are used only inside its init window
  (``y_init``, or ``y0`` alone: ``methods/freerun.py``); the encoder reads the window's
  last ``lags`` rows (edge-padded when the window is shorter), the network runs free from
  the first row after it. Segments with equally long windows are simulated as one batch.
  A run that turns non-finite or leaves the envelope of the training outputs is held at
  its last good value and flagged diverged (``SegmentPredictions.diverged``).
- Determinism: every draw comes from the ``rng`` given to ``fit`` (the torch seed of the
  initial weights, then the subsection starts), so one seed gives one model on one device.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Sequence

import numpy as np

from enginebench.declare import Declaration, Invalid, anything, choice, is_whole, number, positive, text, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.freerun import (ENVELOPE, Envelope, Trajectory, check_prediction_inputs, init_window,
                                         training_trajectories)
from enginebench.methods.numerics.device import cpu_threads, resolve_device
from enginebench.samples import Samples

if TYPE_CHECKING:  # torch is imported where a network is built or run, not here: listing methods imports no torch
    import torch
    from torch import nn

HORIZON_SAMPLES = 100
"""``horizon = None``: the training subsections' length in samples (at most half the longest fitting part)."""
GRAD_CLIP = 1.0
"""Largest gradient norm of one Adam step (free-run losses have steep walls early in training)."""


# --------------------------------------------------------------------------- options
def _sizes(value: Any) -> Any:
    values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
    if not values or not all(is_whole(v) and v >= 1 for v in values):
        raise Invalid("{name}={value} must be a whole number >= 1 or a list of them (or None to derive it from "
                      "the number of targets)")
    return value


def _device(value: Any) -> Any:
    resolve_device(value, "option device")
    return value


def declaration(state_meaning: str, hidden_meaning: str, lags_per_state: int = 2) -> Declaration:
    """The options both methods share; ``state_meaning`` and ``hidden_meaning`` say what nx and hidden are,
    ``lags_per_state`` the default encoder window per state (the class's ``lags_per_state``)."""
    return Declaration(
        anything("nx", None, state_meaning + "; a list is searched by model selection", check=_sizes,
                 unit="states", type_label="int >= 1 | list[int] | None", searches=("nx",), edges="high"),
        whole("lags", None, "encoder window: measured inputs and outputs before the start that set the initial "
              f"state; None = {lags_per_state} nx, at most a quarter of the shortest training record", low=1, nullable=True,
              unit="samples"),
        whole("horizon", None, f"length T of the training subsections (free-run loss); None = {HORIZON_SAMPLES}, "
              "at most half the longest training record's fitting part", low=1, nullable=True, unit="samples"),
        whole("batch_size", 256, "training subsections per gradient step", low=1, unit="subsections"),
        whole("hidden", 32, hidden_meaning, low=1, unit="units"),
        whole("layers", 2, "hidden layers of each MLP (tanh)", low=1, unit="layers"),
        whole("steps", 3000, "most Adam steps (one batch of subsections each); early stopping may end sooner",
              low=1, unit="steps"),
        positive("lr", 1e-3, "Adam learning rate at the start (standardised signals)", unit="1"),
        number("lr_final", 0.1, "learning rate at the last step as a fraction of lr (cosine decay over steps; "
               "1 = constant)", low=0.0, high=1.0, low_open=True, unit="1"),
        number("val_fraction", 0.15, "held-out end of each training record for early stopping on its free-run "
               "error; 0 = none (the last weights are kept)", low=0.0, high=0.5, high_open=True, unit="1"),
        whole("validations", 30, "free-run validations over the run (every steps / validations steps)", low=1,
              unit="validations"),
        whole("patience", 10, "stop after this many validations without a better free-run error", low=1,
              unit="validations"),
        ENVELOPE,
        text("device", "cpu", "torch device: cpu, cuda, cuda:INDEX or auto (CUDA when available)", check=_device,
             message="{name}={value} must be a string ('cpu', 'cuda', 'cuda:0' or 'auto')"),
        choice("dtype", "float32", "torch floating-point precision", ("float32", "float64")),
        whole("cpu_threads", 1, "torch intra-op threads on CPU while fitting and simulating; None = leave as is",
              low=1, nullable=True, unit="threads"),
    )


# --------------------------------------------------------------------------- networks (the modules: neural_nets.py)
@dataclass(frozen=True)
class NetConfig:
    """Sizes of a network: inputs, outputs, state, encoder window, MLP width and depth."""

    nu: int
    ny: int
    nx: int
    lags: int
    hidden: int
    layers: int


# --------------------------------------------------------------------------- fitted model
@dataclass(frozen=True)
class NeuralSimFit:
    """A trained network as plain arrays (picklable, device-free) with its standardisation and envelope."""

    config: NetConfig
    weights: dict[str, np.ndarray]
    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    envelope: Envelope
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    dtype: str
    info: dict[str, Any] = field(default_factory=dict)


def _torch_dtype(name: str) -> torch.dtype:
    import torch

    return torch.float64 if name == "float64" else torch.float32


def _stats(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = values.mean(axis=0)
    sd = values.std(axis=0)
    return mean, np.where(sd > 0, sd, 1.0)


# --------------------------------------------------------------------------- data for training
@dataclass
class _Windows:
    """Standardised training records, each edge-padded with ``lags`` copies of its first row, stacked."""

    U: torch.Tensor
    Y: torch.Tensor
    lags: int
    starts: np.ndarray
    """Padded positions of the first simulated sample of every training subsection."""
    val_starts: np.ndarray
    val_lengths: np.ndarray

    def batch(self, positions: np.ndarray, length: int) -> tuple[torch.Tensor, ...]:
        """(past_u, past_y, u, y) of subsections starting at padded ``positions``, ``length`` samples long."""
        import torch

        idx = torch.as_tensor(positions[:, None] + np.arange(-self.lags, length), device=self.U.device)
        U, Y = self.U[idx], self.Y[idx]
        return U[:, :self.lags], Y[:, :self.lags], U[:, self.lags:], Y[:, self.lags:]


def _windows(traj: Sequence[Trajectory], std: tuple[np.ndarray, ...], lags: int, horizon: int, val_fraction: float,
             device: torch.device, dtype: torch.dtype) -> _Windows:
    import torch

    u_mean, u_std, y_mean, y_std = std
    Us, Ys, starts, val_starts, val_lengths = [], [], [], [], []
    offset = 0
    for tr in traj:
        n = len(tr.Y)
        tail = int(math.floor(val_fraction * n)) if val_fraction > 0 else 0
        if tail and n - tail < 2:
            tail = 0
        fit = n - tail
        u = (tr.U - u_mean) / u_std
        y = (tr.Y - y_mean) / y_std
        Us.append(np.concatenate([np.repeat(u[:1], lags, axis=0), u]))
        Ys.append(np.concatenate([np.repeat(y[:1], lags, axis=0), y]))
        if fit - horizon >= 1:  # starts k = 1 .. fit - horizon: the subsection [k, k + horizon) lies in the fitting part
            starts.append(offset + lags + np.arange(1, fit - horizon + 1))
        if tail:
            val_starts.append(offset + lags + fit)
            val_lengths.append(tail)
        offset += n + lags
    if not starts:
        raise MethodError("option horizon: every training record is shorter than horizon + 1 samples; lower horizon")
    return _Windows(
        U=torch.as_tensor(np.concatenate(Us), dtype=dtype, device=device),
        Y=torch.as_tensor(np.concatenate(Ys), dtype=dtype, device=device), lags=lags,
        starts=np.concatenate(starts), val_starts=np.array(val_starts, dtype=np.int64),
        val_lengths=np.array(val_lengths, dtype=np.int64))


def _validation_error(net: nn.Module, w: _Windows) -> float:
    """Mean squared standardised free-run error of the held-out record ends (inf when non-finite)."""
    import torch

    longest = int(w.val_lengths.max())
    total, count = 0.0, 0
    with torch.no_grad():
        past_u, past_y, u, y = w.batch(w.val_starts, 1)
        # each block's inputs and outputs up to its own length; beyond it the rows are the next record's (ignored)
        idx = torch.as_tensor(np.minimum(w.val_starts[:, None] + np.arange(longest), len(w.U) - 1), device=w.U.device)
        pred = net(past_u, past_y, w.U[idx])
        err = (pred - w.Y[idx]) ** 2
        mask = torch.as_tensor(np.arange(longest)[None, :] < w.val_lengths[:, None], device=err.device)
        total = float(err[mask].sum())
        count = int(mask.sum()) * err.shape[-1]
    value = total / max(count, 1)
    return value if math.isfinite(value) else math.inf


# --------------------------------------------------------------------------- the method
class NeuralSimulator(Method):
    """Base of the torch free-run methods: options, defaults, training loop and batched free run.

    Subclasses set ``name``, ``summary``, ``declared_options`` and ``state_per_target``
    and implement ``network`` (the torch module for a configuration) and ``model_facts``.
    """

    family = "data-driven"
    modes = frozenset({"simulation"})
    joint_targets = True  # one network for every target: nx grows with them, the loss sums their standardised errors
    state_per_target: ClassVar[int] = 4
    max_state: ClassVar[int] = 16
    lags_per_state: ClassVar[int] = 2
    """``lags = None``: this many encoder samples per state, at most a quarter of the shortest record."""

    # -- to override ------------------------------------------------------------------------
    def network(self, config: NetConfig) -> nn.Module:
        """The untrained torch module: ``forward(past_u, past_y, u) -> y`` over (batch, time, signals)."""
        raise NotImplementedError

    def model_facts(self, net: nn.Module, fitted: NeuralSimFit) -> dict[str, Any]:
        """Method-specific entries of ``describe``."""
        return {}

    # -- grid ---------------------------------------------------------------------------------
    def derived_nx(self, n_targets: int) -> int:
        """``nx = None``: ``state_per_target`` states per target, at most ``max_state``."""
        return int(min(self.max_state, self.state_per_target * max(1, n_targets)))

    def search_space(self, data: Samples) -> SearchSpace:
        """The state size nx: as given (a list is searched) or one value derived from the number of targets."""
        given = self.options["nx"]
        if given is None:
            return {"nx": np.array([self.derived_nx(len(data.target_names))])}
        values = list(given) if isinstance(given, (list, tuple, np.ndarray)) else [given]
        return {"nx": np.array(sorted({int(v) for v in values}))}

    def _nx(self, params: Params, n_targets: int) -> int:
        unknown = set(params) - {"nx"}
        if unknown:
            raise MethodError(f"method {self.name!r}: unknown hyperparameter(s) {', '.join(sorted(unknown))}; "
                              "it has nx")
        value = params.get("nx", self.derived_nx(n_targets))
        if isinstance(value, (bool, np.bool_)) or np.ndim(value) or not float(value).is_integer() or value < 1:
            raise MethodError(f"method {self.name!r}: hyperparameter nx must be a whole number >= 1, got {value!r}")
        return int(value)

    def _device(self) -> torch.device:
        return resolve_device(self.options["device"], f"method {self.name!r}: option device")

    # -- fitting ------------------------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> NeuralSimFit:
        """Train on the free-run loss of random subsections, early-stopped on held-out record ends."""
        import torch

        self.check_mode(train.mode)
        o = self.options
        traj = training_trajectories(self.name, train)
        k, c = len(train.target_names), len(train.input_names)
        nx = self._nx(params, k)
        shortest = min(len(t.Y) for t in traj)
        lags = int(o["lags"]) if o["lags"] is not None else max(1, min(self.lags_per_state * nx, shortest // 4))
        val_fraction = float(o["val_fraction"])
        longest_fit = max(len(t.Y) - int(math.floor(val_fraction * len(t.Y))) for t in traj)
        if longest_fit < 2:
            raise MethodError(f"method {self.name!r}: the longest training record has {longest_fit} fitting rows; "
                              "give records of at least 2 samples (or lower val_fraction)")
        horizon = int(o["horizon"]) if o["horizon"] is not None else max(1, min(HORIZON_SAMPLES, longest_fit // 2))
        U_all = np.concatenate([t.U for t in traj])
        Y_all = np.concatenate([t.Y for t in traj])
        u_mean, u_std = _stats(U_all)
        y_mean, y_std = _stats(Y_all)
        config = NetConfig(nu=c, ny=k, nx=nx, lags=lags, hidden=int(o["hidden"]), layers=int(o["layers"]))
        device, dtype = self._device(), _torch_dtype(o["dtype"])
        seed = int(rng.integers(0, 2**63 - 1))
        with cpu_threads(o["cpu_threads"], device):
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                net = self.network(config).to(dtype)
            net = net.to(device)
            w = _windows(traj, (u_mean, u_std, y_mean, y_std), lags, horizon, val_fraction, device, dtype)
            info = self._train(net, w, horizon, rng)
        weights = {name: t.detach().cpu().numpy().copy() for name, t in net.state_dict().items()}
        info.update(lags=lags, horizon=horizon, device=str(device))
        return NeuralSimFit(config=config, weights=weights, u_mean=u_mean, u_std=u_std, y_mean=y_mean, y_std=y_std,
                            envelope=Envelope.around(Y_all, float(o["envelope"])),
                            input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                            dtype=o["dtype"], info=info)

    def _train(self, net: nn.Module, w: _Windows, horizon: int, rng: np.random.Generator) -> dict[str, Any]:
        """Adam on the free-run loss; keeps the weights of the best validation (all in place on ``net``)."""
        import torch

        o = self.options
        steps, batch = int(o["steps"]), min(int(o["batch_size"]), len(w.starts))
        every = max(1, steps // int(o["validations"]))
        lr, final = float(o["lr"]), float(o["lr_final"])
        opt = torch.optim.Adam(net.parameters(), lr=lr)
        validate = len(w.val_starts) > 0
        best, best_state, best_step, stale = math.inf, None, 0, 0
        order, pos, epochs, skipped, last_loss, done = rng.permutation(w.starts), 0, 0, 0, math.nan, 0
        history: list[tuple[int, float]] = []
        for step in range(1, steps + 1):
            if pos + batch > len(order):
                order, pos, epochs = rng.permutation(w.starts), 0, epochs + 1
            past_u, past_y, u, y = w.batch(order[pos:pos + batch], horizon)
            pos += batch
            loss = torch.mean((net(past_u, past_y, u) - y) ** 2)
            done = step
            if not torch.isfinite(loss):
                skipped += 1
            else:
                for group in opt.param_groups:  # cosine from lr to lr x lr_final over the step budget
                    group["lr"] = lr * (final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * (step - 1) / steps)))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), GRAD_CLIP)
                opt.step()
                last_loss = float(loss.detach())
            if validate and (step % every == 0 or step == steps):
                net.eval()
                score = _validation_error(net, w)
                net.train()
                history.append((step, score))
                if score < best:
                    best, best_state, best_step, stale = score, copy.deepcopy(net.state_dict()), step, 0
                else:
                    stale += 1
                    if stale >= int(o["patience"]):
                        break
        if best_state is not None:
            net.load_state_dict(best_state)
        net.eval()
        return {"steps_run": done, "best_step": best_step if validate else done,
                "epochs": round(epochs + pos / max(len(order), 1), 3), "skipped_steps": skipped,
                "train_mse_last": _finite(last_loss), "validation_mse": _finite(best) if validate else None,
                "stopped_early": bool(validate and done < steps),
                "validation_history": [[s, _finite(v)] for s, v in history],
                "subsections": int(len(w.starts)), "batch_size": batch}

    # -- prediction ---------------------------------------------------------------------------
    def _rebuild(self, fitted: NeuralSimFit, device: torch.device) -> nn.Module:
        import torch

        with torch.random.fork_rng(devices=[]):
            net = self.network(fitted.config).to(_torch_dtype(fitted.dtype))
        net.load_state_dict({k: torch.as_tensor(v) for k, v in fitted.weights.items()})
        return net.to(device).eval()

    def predict(self, fitted: NeuralSimFit, data: Samples) -> SegmentPredictions:
        """Free run of every segment from its init window; segments with equal windows in one batch."""
        import torch

        check_prediction_inputs(self.name, data, len(fitted.input_names))
        if not data.segments:
            return SegmentPredictions([], [])
        k, L = len(fitted.target_names), fitted.config.lags
        device, dtype = self._device(), _torch_dtype(fitted.dtype)
        windows = [init_window(self.name, s, k) for s in data.segments]
        out: list[np.ndarray | None] = [None] * len(data.segments)
        flags = np.zeros(len(data.segments), dtype=bool)
        groups: dict[int, list[int]] = {}
        for i, win in enumerate(windows):
            groups.setdefault(len(win), []).append(i)
        with cpu_threads(self.options["cpu_threads"], device):
            net = self._rebuild(fitted, device)
            for N, members in groups.items():
                U = [(np.asarray(data.segments[i].U, dtype=np.float64) - fitted.u_mean) / fitted.u_std
                     for i in members]
                W = [(windows[i] - fitted.y_mean) / fitted.y_std for i in members]
                longest = max(len(u) for u in U) - N
                past_u = np.stack([_last_rows(u[:N], L) for u in U])
                past_y = np.stack([_last_rows(wy, L) for wy in W])
                future = np.stack([_padded(u[N:], longest) for u in U])
                if longest > 0:
                    with torch.no_grad():
                        sim = net(*(torch.as_tensor(a, dtype=dtype, device=device) for a in (past_u, past_y, future)))
                    sim = sim.cpu().numpy().astype(np.float64)
                else:
                    sim = np.empty((len(members), 0, k))
                for r, i in enumerate(members):
                    s = data.segments[i]
                    n = len(s.U)
                    with np.errstate(over="ignore", invalid="ignore"):
                        free = sim[r, :n - N] * fitted.y_std + fitted.y_mean
                    traj = np.concatenate([windows[i], free])[:n]
                    traj, flags[i] = fitted.envelope.clip_run(traj, N)
                    out[i] = traj[np.asarray(s.rows)]
        return SegmentPredictions(out, flags)  # type: ignore[arg-type]

    def onnx_model(self, fitted: NeuralSimFit) -> Any:
        """The network's encoder and one step (``initial_state``, ``step``) for ``export --onnx``."""
        import torch

        from enginebench.methods.export.onnx import OnnxModel

        return OnnxModel(method=self.name, inputs=fitted.input_names, targets=fitted.target_names,
                         lags=fitted.config.lags, n_state=fitted.config.nx, dtype=fitted.dtype,
                         network=self._rebuild(fitted, torch.device("cpu")), u_mean=fitted.u_mean,
                         u_std=fitted.u_std, y_mean=fitted.y_mean, y_std=fitted.y_std,
                         lower=fitted.envelope.lower, upper=fitted.envelope.upper)

    def describe(self, fitted: NeuralSimFit) -> dict[str, Any]:
        """Sizes, training facts (steps, early stopping, validation error), standardisation, envelope."""
        import torch

        net = self._rebuild(fitted, torch.device("cpu"))
        cfg = fitted.config
        return {
            "nx": cfg.nx, "lags": cfg.lags, "hidden": cfg.hidden, "layers": cfg.layers,
            "parameters": int(sum(p.numel() for p in net.parameters())),
            **{k: v for k, v in fitted.info.items()},
            **self.model_facts(net, fitted),
            "standardisation": {"y_mean": fitted.y_mean.tolist(), "y_std": fitted.y_std.tolist(),
                                "u_mean": fitted.u_mean.tolist(), "u_std": fitted.u_std.tolist()},
            "envelope": {"lower": fitted.envelope.lower.tolist(), "upper": fitted.envelope.upper.tolist()},
        }


def _finite(value: float) -> float | None:
    """``value``, or None when it is nan or inf (describe's output is stored as JSON)."""
    return float(value) if math.isfinite(value) else None


def _last_rows(values: np.ndarray, lags: int) -> np.ndarray:
    """The last ``lags`` rows of ``values`` (n >= 1, ...), edge-padded with its first row when shorter."""
    if len(values) >= lags:
        return values[len(values) - lags:]
    return np.concatenate([np.repeat(values[:1], lags - len(values), axis=0), values])


def _padded(values: np.ndarray, length: int) -> np.ndarray:
    """``values`` (n, c) extended to ``length`` rows with its last row (zeros when empty)."""
    if len(values) >= length:
        return values[:length]
    fill = values[-1:] if len(values) else np.zeros((1, values.shape[1]))
    return np.concatenate([values, np.repeat(fill, length - len(values), axis=0)])


__all__ = ["NetConfig", "NeuralSimFit", "NeuralSimulator", "declaration"]
