"""A fitted torch model as ONNX graphs: the code behind ``enginebench export --onnx`` (``docs/models.md``).

A method that can be exported to ONNX returns an ``OnnxModel`` from its ``onnx_model`` hook: a torch network
with two methods, ``initial_state(past_u, past_y)`` (the state at the first simulated row from the init
window's last ``lags`` rows) and ``step(u, state) -> (y, state_next)`` (one sample), both on standardised
signals, with the standardisation and the envelope of its free run. ``write_onnx`` exports two graphs, in
physical units (the standardisation is inside them), batch 1:

* ``OUT.onnx``, the step a rig calls every sample: inputs ``u`` (1, inputs) and ``state`` (1, n_state),
  outputs ``y`` (1, targets) and ``state_next`` (1, n_state);
* ``OUT.encoder.onnx``, called once at the start: inputs ``past_u`` (1, lags, inputs) and ``past_y``
  (1, lags, targets), the last ``lags`` rows of the init window (edge-padded with its first row when the
  window is shorter), output ``state`` (1, n_state), the state of the first row after the window.

``OnnxRunner`` runs them with onnxruntime the way the toolkit's free run does (``methods/freerun.py``): the
init window's measured outputs are the first rows, the model's from there, and a run that leaves the envelope
(or turns non-finite) is held at its last good row. Both files carry the model's facts as ONNX metadata
(``metadata_props``, key ``enginebench``: JSON). torch, onnx, onnxscript and onnxruntime are imported
inside the functions (the ``onnx`` extra).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from enginebench.errors import MethodError

ENCODER_SUFFIX = ".encoder.onnx"
METADATA_KEY = "enginebench"
OPSET = 18


@dataclass(frozen=True)
class OnnxModel:
    """A fitted network's initial state and step for ONNX (see the module docstring)."""

    method: str
    inputs: tuple[str, ...]
    targets: tuple[str, ...]
    lags: int
    """Rows of the init window the encoder reads."""
    n_state: int
    dtype: str
    """"float32" or "float64": the graphs' floating-point type (the network's)."""
    network: Any
    """A torch module with ``initial_state(past_u, past_y)`` and ``step(u, state) -> (y, state_next)``."""
    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray
    lower: np.ndarray | None = None
    """Envelope (physical units); None: outputs are never held."""
    upper: np.ndarray | None = None


def require_onnx() -> None:
    """MethodError (one line) when the ``onnx`` extra (onnx, onnxscript, onnxruntime) is not installed."""
    missing = []
    for name in ("onnx", "onnxscript", "onnxruntime"):
        try:
            __import__(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise MethodError(f"ONNX export needs {', '.join(missing)}, not installed here; install the extra: "
                          "pip install 'enginebench[onnx]'")


def encoder_path(step_path: Path) -> Path:
    """``OUT.encoder.onnx`` beside ``OUT.onnx``."""
    step_path = Path(step_path)
    stem = step_path.name[:-len(".onnx")] if step_path.name.endswith(".onnx") else step_path.name
    return step_path.with_name(stem + ENCODER_SUFFIX)


def _modules(model: OnnxModel) -> tuple[Any, Any]:
    import torch
    from torch import nn

    dtype = torch.float64 if model.dtype == "float64" else torch.float32

    def buf(values: np.ndarray) -> torch.Tensor:
        return torch.as_tensor(np.asarray(values, dtype=np.float64), dtype=dtype)

    class Scaled(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = model.network
            self.register_buffer("u_mean", buf(model.u_mean))
            self.register_buffer("u_std", buf(model.u_std))
            self.register_buffer("y_mean", buf(model.y_mean))
            self.register_buffer("y_std", buf(model.y_std))

    class Step(Scaled):
        def forward(self, u: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            ys, nxt = self.net.step((u - self.u_mean) / self.u_std, state)
            return ys * self.y_std + self.y_mean, nxt

    class Encoder(Scaled):
        def forward(self, past_u: torch.Tensor, past_y: torch.Tensor) -> torch.Tensor:
            return self.net.initial_state((past_u - self.u_mean) / self.u_std, (past_y - self.y_mean) / self.y_std)

    return Step().to(dtype).eval(), Encoder().to(dtype).eval()


def _export(module: Any, args: tuple, names: tuple[list[str], list[str]], path: Path, facts: dict[str, Any]) -> None:
    import logging
    import warnings

    import onnx
    import torch

    quiet = logging.getLogger("torch.onnx")  # 'torchvision is not installed' notes of the exporter's registry
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(module, args, dynamo=True, input_names=names[0], output_names=names[1],
                                        opset_version=OPSET, verbose=False, optimize=True)
    finally:
        quiet.setLevel(level)
    proto = program.model_proto
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps(facts)
    onnx.checker.check_model(proto)
    onnx.save(proto, str(path))


def write_onnx(model: OnnxModel, out: Path, facts: dict[str, Any]) -> tuple[Path, Path]:
    """Export the step (``out``) and the encoder (``OUT.encoder.onnx``); ``facts`` go into their metadata."""
    import torch

    require_onnx()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    step, encoder = _modules(model)
    dtype = torch.float64 if model.dtype == "float64" else torch.float32
    nu, ny = len(model.inputs), len(model.targets)
    info = {**facts, "method": model.method, "inputs": list(model.inputs), "targets": list(model.targets),
            "lags": int(model.lags), "n_state": int(model.n_state), "dtype": model.dtype,
            "envelope": None if model.lower is None else {"lower": np.asarray(model.lower).tolist(),
                                                          "upper": np.asarray(model.upper).tolist()},
            "step_graph": out.name, "encoder_graph": encoder_path(out).name}
    _export(step, (torch.zeros(1, nu, dtype=dtype), torch.zeros(1, model.n_state, dtype=dtype)),
            (["u", "state"], ["y", "state_next"]), out, {**info, "graph": "step"})
    enc = encoder_path(out)
    _export(encoder, (torch.zeros(1, model.lags, nu, dtype=dtype), torch.zeros(1, model.lags, ny, dtype=dtype)),
            (["past_u", "past_y"], ["state"]), enc, {**info, "graph": "encoder"})
    return out, enc


def _last_rows(values: np.ndarray, lags: int) -> np.ndarray:
    if len(values) >= lags:
        return values[len(values) - lags:]
    return np.concatenate([np.repeat(values[:1], lags - len(values), axis=0), values])


class OnnxRunner:
    """The exported graphs in onnxruntime (one thread), run as the toolkit's free run."""

    def __init__(self, step_path: Path, encoder: Path | None = None) -> None:
        require_onnx()
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        self.step = ort.InferenceSession(str(step_path), opts, providers=["CPUExecutionProvider"])
        self.encoder = ort.InferenceSession(str(encoder or encoder_path(step_path)), opts,
                                            providers=["CPUExecutionProvider"])
        meta = self.step.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
        self.facts: dict[str, Any] = json.loads(meta) if meta else {}
        self.dtype = np.float64 if self.facts.get("dtype") == "float64" else np.float32
        self.lags = int(self.facts.get("lags", self.encoder.get_inputs()[0].shape[1]))
        env = self.facts.get("envelope")
        self.lower = None if env is None else np.asarray(env["lower"], dtype=np.float64)
        self.upper = None if env is None else np.asarray(env["upper"], dtype=np.float64)

    def simulate(self, U: np.ndarray, window: np.ndarray, *, timing: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The trajectory (n, targets) over inputs ``U`` (n, inputs) from the init window's measured outputs
        ``window`` (N >= 1 rows: rows 0..N-1 of the result), and the time of each step call in seconds."""
        U = np.asarray(U, dtype=np.float64)
        window = np.asarray(window, dtype=np.float64)
        N, n = len(window), len(U)
        past_u = _last_rows(U[:N], self.lags)[None].astype(self.dtype)
        past_y = _last_rows(window, self.lags)[None].astype(self.dtype)
        state = self.encoder.run(None, {"past_u": past_u, "past_y": past_y})[0]
        traj = np.empty((n, window.shape[1]))
        traj[:N] = window[:n]
        times = np.empty(max(n - N, 0))
        inputs = U.astype(self.dtype)
        run = self.step.run
        for t in range(N, n):
            start = time.perf_counter() if timing else 0.0
            y, state = run(None, {"u": inputs[t:t + 1], "state": state})
            if timing:
                times[t - N] = time.perf_counter() - start
            traj[t] = y[0]
        if self.lower is not None and self.upper is not None:
            from enginebench.methods.freerun import Envelope

            traj = Envelope(self.lower, self.upper).clip_run(traj, N)[0]
        return traj, times[:n - N] if timing else np.empty(0)


def onnx_exportable(method_cls: type) -> bool:
    """Whether a method class offers ONNX graphs (overrides ``Method.onnx_model``)."""
    from enginebench.method import Method

    base = getattr(Method, "onnx_model", None)
    return base is not None and getattr(method_cls, "onnx_model", base) is not base
