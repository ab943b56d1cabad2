"""What every model of the input history shares: which inputs, their lags, and horizons from the data's memory.

``nfir`` (a kernel model) and ``boost-fir`` (gradient-boosted trees) both predict an output
from a window of past run-time inputs and never from outputs, so both are free-running and
BIBO-stable by construction. This mixin holds their common part: the input columns (option
``inputs``), the checks on them, the lagged feature rows of a segment, the horizon grid derived
from the input -> output memory (``nfir_memory.estimate_memory``, cached per training set) and
the parsing of ``horizon`` / ``stride`` hyperparameters. A class using it declares the options
``horizons``, ``strides``, ``max_lags`` and ``inputs`` (:data:`HISTORY_OPTIONS`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from enginebench.declare import listing, whole
from enginebench.errors import MethodError
from enginebench.method import Params, SearchSpace, TrainingShape
from enginebench.methods.nfir_memory import (MemoryEstimate, bounded_stride, estimate_memory, horizon_samples,
                                             lag_feature_names, lagged_inputs, nfir_lags)
from enginebench.samples import Samples

HISTORY_OPTIONS = (
    listing("horizons", None, "input windows searched; None = derived from the data's input->output memory "
            "(M/2, M, 2M samples)", items="float", low=0, nullable=True, unit="s", searches=("horizon",),
            message="{name} must be a non-empty list of seconds >= 0 or None (derive from the data), got {value}"),
    listing("strides", None, "lag strides searched (with every horizon); None = the stride keeping at most "
            "max_lags lags per input", items="int", low=1, nullable=True, unit="samples", searches=("stride",),
            message="{name} must be a non-empty list or None (derive from the data) of whole numbers of samples "
                    ">= 1, got {value}"),
    whole("max_lags", 16, "lags per input (lag 0 included) when the stride is derived", low=2),
    listing("inputs", None, "run-time input columns to lag; None = all", items="str", nullable=True,
            message="{name} must be a list of input column names or None, got {value}"),
)


MEMORY_CACHE_SIZE = 8
"""Memory estimates kept per method instance: the folds' training sets and the whole training set of a job."""


class InputHistory:
    """Lagged run-time inputs as features, with horizons derived from the training data's memory."""

    name: str
    options: dict[str, Any]
    _memory_cache: dict[tuple, MemoryEstimate] | None = None
    """Estimates per training set (key: its shape, rows and sum): the k-fold fits of a selection alternate
    between the folds' training sets, so one kept entry missed on every fit (a boosted-trees selection on a
    campaign estimated the memory 45 times, 110 of its 700 s)."""

    def memory(self, data: Samples) -> MemoryEstimate:
        """The input -> output memory of ``data`` (training samples with targets); cached for the same data."""
        names, cols = self._columns(data)
        self._check_inputs(data, names, cols)
        if not data.has_targets:
            raise MethodError(f"method {self.name!r}: deriving the horizons needs training samples with targets")
        for s in data.segments:
            if not np.isfinite(s.y).all():
                row, col = np.argwhere(~np.isfinite(s.y))[0]
                raise MethodError(f"method {self.name!r}: segment {s.id!r} has nan/inf in target "
                                  f"{data.target_names[col]!r} at row {int(s.rows[row])}; clean or drop it")
        key = (float(data.dt), tuple(cols), int(self.options["max_lags"]),
               tuple((s.id, len(s.U), len(s.rows), int(s.rows[0]) if len(s.rows) else -1) for s in data.segments),
               float(np.sum(data.y)))
        if self._memory_cache is None:
            self._memory_cache = {}
        cache = self._memory_cache
        if key in cache:
            return cache[key]
        est = estimate_memory([s.U[:, cols] for s in data.segments], [s.rows for s in data.segments],
                              [s.y for s in data.segments], int(self.options["max_lags"]))
        if len(cache) >= MEMORY_CACHE_SIZE:
            cache.pop(next(iter(cache)))  # the oldest
        cache[key] = est
        return est

    def check_columns(self, inputs: Sequence[str], internals: Sequence[str], targets: Sequence[str]) -> None:
        """Option ``inputs`` names run-time inputs of the data (checked before the first job)."""
        missing = [c for c in (self.options["inputs"] or []) if c not in inputs]
        if missing:
            raise MethodError(
                f"method {self.name!r}: option inputs names {', '.join(map(repr, missing))}: not "
                f"{'a run-time input' if len(missing) == 1 else 'run-time inputs'} of the data; its inputs are "
                f"{', '.join(inputs)}"
            )

    def check_data(self, shape: TrainingShape) -> None:
        """Given ``horizons`` longer than the longest training record are refused before the first job: every lag
        past a record's start reads its first sample (edge padding), so such a window models nothing."""
        horizons = self.options["horizons"]
        if not horizons or shape.dt <= 0 or not shape.records:
            return
        longest = shape.longest
        bad = [h for h in horizons if float(h) / shape.dt >= longest]
        if bad:
            raise MethodError(
                f"method {self.name!r}: option horizons = {list(horizons)!r} s includes {bad[-1]:g} s = "
                f"{float(bad[-1]) / shape.dt:.0f} samples at dt = {shape.dt:g} s, as long as or longer than the "
                f"longest of the {shape.describe()}; use horizons below {longest * shape.dt:g} s (or leave horizons "
                "out to derive them from the data)")

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """The declared bounds and the input window's, for model selection's extension past a grid's edge: from
        one sample (0 where the grid holds 0: no past at all) to the longest training record."""
        bounds = dict(super().search_bounds(data))  # type: ignore[misc]
        sizes = [len(s.U) for s in data.segments]
        if not sizes or data.dt <= 0:
            return bounds
        horizons = self.history_space(data)["horizon"]
        low = 0.0 if len(horizons) and float(np.min(horizons)) <= 0 else float(data.dt)
        bounds["horizon"] = (low, float(max(sizes) * data.dt))
        return bounds

    def history_space(self, data: Samples) -> SearchSpace:
        """Horizons (s) and strides as given, else the horizons derived from the memory of ``data``."""
        o = self.options
        if o["horizons"] is None:
            horizons = np.array([h * data.dt for h in self.memory(data).grid])
        else:
            horizons = np.array([float(h) for h in o["horizons"]])
        out: SearchSpace = {"horizon": horizons}
        if o["strides"] is not None:
            out["stride"] = np.array([int(s) for s in o["strides"]])
        return out

    def _columns(self, data: Samples) -> tuple[tuple[str, ...], list[int]]:
        names = tuple(data.input_names if self.options["inputs"] is None else self.options["inputs"])
        missing = [c for c in names if c not in data.input_names]
        if missing:
            raise MethodError(
                f"method {self.name!r}: option inputs names {', '.join(missing)}, which are not run-time inputs of "
                f"the data ({', '.join(data.input_names)})"
            )
        if not names:
            raise MethodError(f"method {self.name!r}: no input to lag; the data have no run-time input columns")
        return names, [data.input_names.index(c) for c in names]

    def _check_inputs(self, data: Samples, names: Sequence[str], cols: list[int]) -> None:
        for s in data.segments:
            if not np.isfinite(s.U[:, cols]).all():
                row, col = np.argwhere(~np.isfinite(s.U[:, cols]))[0]
                raise MethodError(f"method {self.name!r}: segment {s.id!r} has nan/inf in input {names[col]!r} at "
                                  f"row {row}; clean or drop it")

    def lagged(self, data: Samples, lags: np.ndarray, columns: list[int] | None = None) -> Samples:
        """``data`` with X replaced by the lagged inputs at each segment's evaluated rows."""
        names, cols = self._columns(data) if columns is None else (tuple(data.input_names[c] for c in columns), columns)
        self._check_inputs(data, names, cols)
        segs = tuple(replace(s, X=lagged_inputs(s.U[:, cols], lags, s.rows)) for s in data.segments)
        return replace(data, segments=segs, feature_names=lag_feature_names(names, lags))

    def history_params(self, params: Params, dt: float, others: Sequence[str]) -> tuple[np.ndarray, float, int]:
        """(lags in samples, horizon s, stride samples) of a grid point whose other hyperparameters are ``others``."""
        known = ("horizon", "stride", *others)
        missing = [k for k in ("horizon", *others) if k not in params]
        if missing:
            raise MethodError(
                f"method {self.name!r}: hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}; "
                f"give horizon (s){''.join(', ' + k for k in others)} (and optionally stride, samples)"
            )
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise MethodError(f"method {self.name!r}: unknown hyperparameter(s) {', '.join(unknown)}; it has "
                              f"{', '.join(known)}")
        horizon = float(params["horizon"])
        nfir_lags(horizon, 1, dt)  # checks the horizon
        stride = params["stride"] if "stride" in params else bounded_stride(horizon_samples(horizon, dt),
                                                                              self.options["max_lags"])
        return nfir_lags(horizon, stride, dt), horizon, int(stride)

    def history_description(self, memory: MemoryEstimate | None, dt: float) -> dict[str, Any]:
        """The derived horizons' story for ``describe`` (empty when the horizons were given)."""
        if memory is None:
            return {}
        out: dict[str, Any] = {"horizons_derived": memory.describe(dt)}
        if memory.warnings():
            out["warnings"] = memory.warnings()
        return out
