"""An FMU (FMI 2.0 or 3.0, co-simulation or model exchange) as a dataset's physical model.

The import spec's ``[physical_model]`` table (:mod:`enginebench.datasets.fmu_spec`)
names the FMU, maps dataset columns to its inputs and outputs, and sets parameters.
At import, :func:`import_meta` opens the FMU once, checks every name against its model
description and stores the configuration, the FMU's absolute path and its sha256 in
the dataset's metadata (``meta["physical_model"] = "fmu"``, ``meta["fmu"]``).

:class:`FMUPhysicalModel` implements the :class:`~enginebench.physical.PhysicalModel`
protocol with fmpy: every segment is simulated from its first time stamp (as t = 0)
to its last, the mapped columns fed as input time series (linear between samples),
outputs sampled every dt and interpolated to the segment's time stamps. Parameters are
start values. The FMU is extracted and instantiated once per process and reset between
simulations; ``pm`` and the hybrid methods cache whole-segment results per segment
and parameter set through ``methods.pm.SimulationCache``. fmpy is an optional extra
(``pip install enginebench[fmu]``) imported only when an FMU is opened.
"""

from __future__ import annotations

import contextlib
import difflib
import hashlib
import shutil
import sys
import tempfile
import threading
import weakref
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from enginebench.errors import DataError

NAME = "fmu"
"""The physical-model name datasets with an FMU declare (``meta["physical_model"]``)."""
INSTALL = "FMU physical models need fmpy, which is not installed: pip install enginebench[fmu]"
DEFAULT_TOLERANCE = 1e-6


def require_fmpy() -> Any:
    """The fmpy module, or a one-line DataError saying how to install it."""
    try:
        import fmpy
        import fmpy.simulation  # noqa: F401 - simulate_fmu, instantiate_fmu
    except ImportError as exc:
        raise DataError(INSTALL) from exc
    return fmpy


def file_sha256(path: str | Path) -> str:
    """sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


# -- opening an FMU ------------------------------------------------------------------------
@dataclass
class FMUFile:
    """An FMU's model description with the interface chosen for simulation."""

    path: Path
    description: Any
    fmi_type: str
    variables: dict[str, Any] = field(default_factory=dict)

    @property
    def model_name(self) -> str:
        return str(self.description.modelName)

    def variable(self, name: str, where: str) -> Any:
        """The variable ``name``, or a DataError naming it, where it was asked for and close names."""
        var = self.variables.get(name)
        if var is None:
            lower = {n.lower(): n for n in self.variables}
            close = [lower[c] for c in difflib.get_close_matches(name.lower(), list(lower), n=3, cutoff=0.4)]
            hint = (f"close names: {', '.join(close)}" if close
                    else f"its variables: {', '.join(list(self.variables)[:12])}")
            raise DataError(f"{self.path}: the FMU has no variable {name!r} ({where}); {hint}")
        return var


def open_fmu(path: str | Path, fmi_type: str | None = None) -> FMUFile:
    """Read an FMU's model description and check that it can run here (one DataError line otherwise).

    ``fmi_type`` chooses between co-simulation and model exchange; left out, the one the
    FMU has is taken, and co-simulation where it has both.
    """
    fmpy = require_fmpy()
    from fmpy.model_description import read_model_description

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: FMU file not found; give the path of an .fmu file (relative to the import spec)")
    if not zipfile.is_zipfile(path):
        raise DataError(f"{path}: not an FMU (not a zip archive); export the model as an FMU again")
    try:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
    except (zipfile.BadZipFile, OSError) as exc:
        raise DataError(f"{path}: not an FMU ({_one_line(exc)}); export the model as an FMU again") from exc
    if "modelDescription.xml" not in names:
        raise DataError(f"{path}: not an FMU (no modelDescription.xml inside); export the model as an FMU again")
    try:
        md = read_model_description(str(path), validate=False)
    except Exception as exc:  # noqa: BLE001 - fmpy and lxml raise many kinds for a damaged description
        raise DataError(f"{path}: modelDescription.xml cannot be read ({_one_line(exc)}); the FMU is damaged: "
                        "export it again") from exc
    if not (md.fmiVersion == "2.0" or str(md.fmiVersion).startswith("3.")):
        raise DataError(f"{path}: FMI {md.fmiVersion} is not supported; export the model as an FMI 2.0 or 3.0 FMU")
    platforms = fmpy.supported_platforms(str(path))
    if fmpy.platform not in platforms:
        binaries = [p for p in platforms if p != "c-code"]
        sources = ("; it holds C sources: compile them with fmpy.util.compile_platform_binary"
                   if "c-code" in platforms else "")
        raise DataError(f"{path}: no binary for this platform ({fmpy.platform}); the FMU has binaries for "
                        f"{', '.join(binaries) or 'no platform'}{sources}; export it for {fmpy.platform}")
    present = [t for t, part in (("CoSimulation", md.coSimulation), ("ModelExchange", md.modelExchange))
               if part is not None]
    if not present:
        raise DataError(f"{path}: the FMU offers neither co-simulation nor model exchange; export it with one of them")
    if fmi_type is None:
        fmi_type = present[0]
    elif fmi_type not in present:
        raise DataError(f"{path}: fmi_type = {fmi_type!r} but the FMU offers only {', '.join(present)}; "
                        "change fmi_type in [physical_model]")
    return FMUFile(path, md, fmi_type, {v.name: v for v in md.modelVariables})


def _settable(var: Any) -> bool:
    """Whether a start value can be given to the variable (parameters, inputs, exact or approximate starts)."""
    if var.causality in ("parameter", "input"):
        return True
    return var.variability != "constant" and var.initial in ("exact", "approx")


def check_names(config: Mapping[str, Any], fmu: FMUFile, columns: Sequence[str] | None = None,
                origin: str | Path = "import spec") -> None:
    """Every name of a ``physical_model`` configuration against the FMU (and, given, the spec's columns)."""
    if columns is not None:
        for key in ("inputs", "outputs"):
            for column in config[key]:
                if column not in columns:
                    close = difflib.get_close_matches(column, list(columns), n=1)
                    hint = f"did you mean {close[0]!r}? " if close else ""
                    raise DataError(f"{origin}: [physical_model] {key}: {column!r} is not a column declared in "
                                    f"[columns]; {hint}the keys are the dataset's column names, the values the "
                                    "FMU's variables")
    for column, name in config["inputs"].items():
        var = fmu.variable(name, f"physical_model.inputs, column {column!r}")
        if var.causality != "input":
            raise DataError(f"{fmu.path}: variable {name!r} (physical_model.inputs, column {column!r}) is not an "
                            f"input of the FMU (causality {var.causality!r}); map the column to an input")
    for column, name in config["outputs"].items():
        fmu.variable(name, f"physical_model.outputs, column {column!r}")
    for key in ("parameters", "calibrate"):
        for name in config[key]:
            var = fmu.variable(name, f"physical_model.{key}")
            if not _settable(var):
                raise DataError(f"{fmu.path}: variable {name!r} (physical_model.{key}) cannot be given a value "
                                f"(causality {var.causality!r}, initial {var.initial!r}); set a parameter instead")


def import_meta(config: Mapping[str, Any], columns: Sequence[str], dt: float,
                origin: str | Path = "import spec") -> dict[str, Any]:
    """The dataset metadata of an FMU physical model: the checked configuration, the FMU's sha256 and dt."""
    fmu = open_fmu(config["fmu"], config.get("fmi_type"))
    check_names(config, fmu, columns, origin)
    return {**config, "fmi_type": fmu.fmi_type, "sha256": file_sha256(fmu.path), "dt": float(dt),
            "model_name": fmu.model_name}


# -- running it ----------------------------------------------------------------------------------
@contextlib.contextmanager
def _quiet_callbacks(messages: list[str]) -> Iterator[None]:
    """Errors raised inside fmpy's solver callbacks (model exchange) are kept as messages instead of printed.

    ctypes cannot pass an exception out of a callback; Python would print its traceback
    through ``sys.unraisablehook`` and the solver then fails on its own.
    """
    previous = sys.unraisablehook

    def keep(unraisable: Any) -> None:
        exc = unraisable.exc_value
        messages.append(_one_line(exc) if exc is not None else "solver callback failed")

    sys.unraisablehook = keep
    try:
        yield
    finally:
        sys.unraisablehook = previous


class SimulationFailed(DataError):
    """The FMU failed during a simulation (the message names the segment and the time)."""


_LOG_TO = threading.local()
"""``messages``: the list the FMU messages of this thread go to (the simulating runtime's, else None)."""
_KEPT_CALLBACKS: list[Any] = []
"""The callbacks (logger) of the latest FMI 1.0/2.0 instance made here, kept for the process. fmpy formats such an
FMU's messages through a native proxy that holds the latest logger it was given in one process-wide slot, and
sends every later message there, those of instances on fmpy's default callbacks included: a logger freed with its
instance left the slot dangling, and the next FMU message in the process was a segfault. So the logger is one
module-level function (``_fmu_log``), its ctypes callback kept alive, and it hands a message to the runtime
simulating on the calling thread."""


def _fmu_log(*args: Any) -> None:
    # FMI 2.0 loggers get (env, instance, status, category, message), FMI 3.0 ones (env, status, category, message)
    status, message = args[-3], args[-1]
    messages = getattr(_LOG_TO, "messages", None)
    if messages is not None and status >= 2 and message:
        messages.append(message.decode("utf-8", "replace") if isinstance(message, bytes) else str(message))


@contextlib.contextmanager
def _messages_to(messages: list[str]) -> Iterator[None]:
    """The FMU messages of this thread go to ``messages`` inside the block."""
    before, _LOG_TO.messages = getattr(_LOG_TO, "messages", None), messages
    try:
        yield
    finally:
        _LOG_TO.messages = before


class _Runtime:
    """One process's extracted FMU and its instance, reset between simulations."""

    def __init__(self, fmu: FMUFile) -> None:
        from fmpy import extract

        self.fmu = fmu
        self.unzipdir = extract(str(fmu.path), unzipdir=tempfile.mkdtemp(prefix="enginebench-fmu-"))
        self._cleanup = weakref.finalize(self, shutil.rmtree, self.unzipdir, True)
        self.instance: Any = None
        self.used = False
        self.lock = threading.Lock()
        self.messages: list[str] = []

    def ready(self) -> Any:
        """The instance, new or reset."""
        from fmpy.simulation import instantiate_fmu

        if self.instance is None:
            self.instance = instantiate_fmu(self.unzipdir, self.fmu.description, self.fmu.fmi_type,
                                            logger=_fmu_log)
            if getattr(self.instance, "callbacks", None) is not None:  # FMI 1.0/2.0: see _KEPT_CALLBACKS
                _KEPT_CALLBACKS[:] = [self.instance.callbacks]
            self.used = False
        elif self.used:
            self.instance.reset()
        self.used = True
        self.messages.clear()
        return self.instance

    def discard(self) -> None:
        """Drop an instance left in an unknown state (the next simulation instantiates anew)."""
        instance, self.instance = self.instance, None
        if instance is not None:
            try:
                instance.freeInstance()
            except Exception:  # noqa: BLE001 - a failed FMU may refuse even this; a new instance follows
                pass


class FMUPhysicalModel:
    """An FMU configured by an import spec's ``[physical_model]`` table (see the module docstring)."""

    def __init__(self, config: Mapping[str, Any]) -> None:
        self.config = dict(config)
        self.path = Path(self.config["fmu"])
        self.name = f"{NAME}:{self.path.stem}"
        self.inputs: tuple[str, ...] = tuple(self.config["inputs"])
        self.outputs: tuple[str, ...] = tuple(self.config["outputs"])
        self._fmu: FMUFile | None = None
        self._runtime: _Runtime | None = None

    @classmethod
    def for_dataset(cls, meta: Mapping[str, Any]) -> "FMUPhysicalModel":
        """The FMU a dataset's metadata names; a DataError when the file is gone or changed since the import."""
        config = meta.get(NAME)
        if not isinstance(config, Mapping) or "fmu" not in config:
            raise DataError("dataset metadata names physical model 'fmu' but holds no 'fmu' entry; re-import the "
                            "dataset from its import spec")
        path = Path(config["fmu"])
        if not path.is_file():
            raise DataError(f"{path}: FMU file not found (the dataset was imported with it); restore it or "
                            "re-import the dataset from its spec")
        now, then = file_sha256(path), config.get("sha256")
        if then and now != then:
            raise DataError(f"{path}: the FMU file changed since the dataset was imported (sha256 {then[:12]}... "
                            f"then, {now[:12]}... now); re-import the dataset from its spec, or restore the FMU")
        return cls(config)

    def __repr__(self) -> str:
        return f"FMUPhysicalModel({str(self.path)!r})"

    def __getstate__(self) -> dict[str, Any]:
        return {"config": self.config}  # worker processes open the FMU themselves

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"])

    @property
    def fmu(self) -> FMUFile:
        if self._fmu is None:
            self._fmu = open_fmu(self.path, self.config.get("fmi_type"))
            check_names(self.config, self._fmu)
        return self._fmu

    @property
    def dt(self) -> float | None:
        """The dataset's sample period, stored at import (the output interval of calibration runs)."""
        dt = self.config.get("dt")
        return float(dt) if dt else None

    @property
    def parameters(self) -> dict[str, float]:
        """The spec's parameter values."""
        return {k: float(v) for k, v in self.config["parameters"].items()}

    def start_value(self, name: str) -> float | None:
        """The FMU's own start value of a variable, if it declares one."""
        start = self.fmu.variable(name, "start value").start
        try:
            return None if start is None else float(start)
        except (TypeError, ValueError):
            return None

    # -- the protocol ------------------------------------------------------------------
    def calibrate(self, segments: Sequence[Mapping[str, np.ndarray]]) -> dict[str, Any]:
        """The spec's parameters, with those named in ``calibrate`` fitted to the segments' measured outputs."""
        if not self.config["calibrate"]:
            return self.parameters
        from enginebench.datasets.fmu_calibrate import fit_parameters

        return fit_parameters(self, segments, self.dt).after

    def simulate(self, params: Mapping[str, Any], segment: Mapping[str, np.ndarray],
                 dt: float) -> dict[str, np.ndarray]:
        """The mapped outputs over one segment (its first time stamp is the FMU's t = 0)."""
        t = np.asarray(segment["time"], dtype=float)
        missing = [c for c in self.inputs if c not in segment]
        if missing:
            raise DataError(f"{self.name}: segment lacks input column(s) {', '.join(missing)}")
        if len(t) == 0:
            return {c: np.empty(0) for c in self.outputs}
        rel = t - t[0]
        stop = float(rel[-1]) if rel[-1] > 0 else float(dt)
        signals = self._signals(params, segment, rel if len(t) > 1 else np.array([0.0, stop]))
        fed = set(signals.dtype.names)
        start = {k: v for k, v in params.items() if k not in fed}
        result = self._run(start, signals, stop, float(dt), (float(t[0]), float(t[-1])))
        out_t = np.asarray(result["time"], dtype=float)
        return {column: np.interp(rel, out_t, np.asarray(result[var], dtype=float))
                for column, var in self.config["outputs"].items()}

    # -- internals -------------------------------------------------------------------------
    def _signals(self, params: Mapping[str, Any], segment: Mapping[str, np.ndarray], rel: np.ndarray) -> np.ndarray:
        """Inputs as fmpy's structured time series: the mapped columns, other FMU inputs held constant."""
        inputs = dict(self.config["inputs"])
        held = {v.name: params.get(v.name, self.start_value(v.name) or 0.0)
                for v in self.fmu.description.modelVariables
                if v.causality == "input" and v.name not in inputs.values()}
        names = ["time", *inputs.values(), *held]
        sig = np.zeros(len(rel), dtype=[(n, np.float64) for n in names])
        sig["time"] = rel
        for column, var in inputs.items():
            values = np.asarray(segment[column], dtype=float)
            sig[var] = values if len(values) == len(rel) else np.full(len(rel), values[0])
        for var, value in held.items():
            sig[var] = value
        return sig

    def _run(self, start: Mapping[str, Any], signals: np.ndarray, stop: float, dt: float,
             span: tuple[float, float]) -> np.ndarray:
        fmpy = require_fmpy()
        fmu = self.fmu
        if self._runtime is None:
            self._runtime = _Runtime(fmu)
        rt = self._runtime
        tolerance = self.config.get("tolerance") or DEFAULT_TOLERANCE
        last = [0.0]

        def step_finished(time: float, recorder: Any) -> bool:
            last[0] = time
            return True

        callback_errors: list[str] = []
        with rt.lock, _quiet_callbacks(callback_errors), _messages_to(rt.messages):
            try:
                result = fmpy.simulate_fmu(
                    rt.unzipdir, model_description=fmu.description, fmu_instance=rt.ready(), fmi_type=fmu.fmi_type,
                    start_time=0.0, stop_time=stop, output_interval=dt, input=signals, start_values=dict(start),
                    output=list(self.config["outputs"].values()), relative_tolerance=tolerance, record_events=False,
                    step_finished=step_finished, validate=True)
            except Exception as exc:  # noqa: BLE001 - fmpy raises plain Exceptions; the FMU's log says more
                rt.discard()
                said = rt.messages or callback_errors  # the FMU's own log first
                reason = said[-1] if said else _one_line(exc)
                raise SimulationFailed(
                    f"{self.path}: the FMU failed after t = {span[0] + last[0]:g} s in the segment spanning "
                    f"t = {span[0]:g} .. {span[1]:g} s ({reason}); check the inputs there and the parameters"
                ) from exc
        end = float(result["time"][-1]) if len(result) else 0.0
        if end < stop - 1e-6 * max(1.0, stop) - dt:
            rt.discard()
            raise SimulationFailed(f"{self.path}: the FMU stopped at t = {span[0] + end:g} s in the segment spanning "
                                   f"t = {span[0]:g} .. {span[1]:g} s (it asked to terminate); check the inputs there")
        return result
