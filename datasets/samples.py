"""What a method sees: per-segment feature matrices and targets, built for one evaluation mode.

The features are built here, not by the methods, so that the ``window`` mode can only
ever offer measured outputs strictly before t: a method cannot read y(t) because y(t)
is not in its inputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from enginebench.datasets.dataset import TIME, Dataset
from enginebench.errors import DataError

MODES = ("static", "window", "simulation")


@dataclass(frozen=True)
class SegmentSamples:
    """One segment's samples.

    ``X`` holds one row per evaluated time step (``rows`` gives its position in the
    raw segment); ``U`` and ``t`` hold the raw run-time inputs and time over the whole
    segment, for physical models and simulators. ``y`` is absent when the method is
    asked to predict; ``y0`` (simulation mode) is the measured output at the first row.
    """

    id: str
    X: np.ndarray
    rows: np.ndarray
    U: np.ndarray
    t: np.ndarray
    y: np.ndarray | None = None
    y0: np.ndarray | None = None
    Z: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rows)


@dataclass(frozen=True)
class Samples:
    """A batch of segments prepared for one (targets, mode, window) setting."""

    segments: tuple[SegmentSamples, ...]
    mode: str
    window: float
    dt: float
    feature_names: tuple[str, ...]
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    internal_names: tuple[str, ...] = ()
    units: dict[str, str] = field(default_factory=dict)
    physical_model: Any = None

    def __len__(self) -> int:
        return sum(len(s) for s in self.segments)

    @property
    def lags(self) -> int:
        return int(round(self.window / self.dt))

    @property
    def X(self) -> np.ndarray:
        """All feature rows, segments stacked in order."""
        return np.concatenate([s.X for s in self.segments]) if self.segments else np.empty((0, len(self.feature_names)))

    @property
    def y(self) -> np.ndarray:
        if any(s.y is None for s in self.segments):
            raise DataError("these samples carry no targets (prediction-only view)")
        return np.concatenate([s.y for s in self.segments]) if self.segments else np.empty((0, len(self.target_names)))

    @property
    def has_targets(self) -> bool:
        return all(s.y is not None for s in self.segments)

    def feature_index(self, name: str) -> int:
        try:
            return self.feature_names.index(name)
        except ValueError:
            raise DataError(f"no feature {name!r}; features are {', '.join(self.feature_names)}") from None

    def without_targets(self) -> "Samples":
        """The view handed to ``Method.predict``: targets removed (initial outputs kept for simulation)."""
        return replace(self, segments=tuple(replace(s, y=None, Z=None) for s in self.segments))

    def take(self, index: np.ndarray) -> "Samples":
        """Rows at global positions ``index`` (repeats allowed), grouped by segment in segment order."""
        index = np.asarray(index, dtype=np.int64)
        sizes = np.array([len(s) for s in self.segments], dtype=np.int64)
        offsets = np.r_[0, np.cumsum(sizes)]
        if index.size and (index.min() < 0 or index.max() >= offsets[-1]):
            raise IndexError(f"row index out of range 0..{offsets[-1] - 1}")
        seg_of = np.searchsorted(offsets, index, side="right") - 1
        order = np.argsort(seg_of, kind="stable")
        index, seg_of = index[order], seg_of[order]
        out = []
        for k in np.unique(seg_of):
            s = self.segments[k]
            local = index[seg_of == k] - offsets[k]
            out.append(replace(s, X=s.X[local], rows=s.rows[local], y=None if s.y is None else s.y[local]))
        return replace(self, segments=tuple(out))

    def variables(self) -> dict[str, list[int]]:
        """Feature columns grouped by signal: a lagged series ``x[t]``, ``x[t-1]``... is one variable."""
        groups: dict[str, list[int]] = {}
        for j, name in enumerate(self.feature_names):
            groups.setdefault(name.split("[", 1)[0], []).append(j)
        return groups

    def select_features(self, columns: Sequence[int]) -> "Samples":
        """The same rows with only the given feature columns (raw inputs ``U`` are kept)."""
        cols = list(columns)
        return replace(
            self,
            segments=tuple(replace(s, X=np.ascontiguousarray(s.X[:, cols])) for s in self.segments),
            feature_names=tuple(self.feature_names[j] for j in cols),
        )

    def segment_ids(self) -> list[str]:
        return [s.id for s in self.segments]


def lagged_feature_names(inputs: Sequence[str], outputs: Sequence[str], lags: int) -> list[str]:
    """Names of the window features: ``x[t]``, ``x[t-1]``... and ``y[t-1]``...``y[t-lags]``."""
    names = []
    for c in inputs:
        names += [f"{c}[t]"] + [f"{c}[t-{k}]" for k in range(1, lags + 1)]
    for c in outputs:
        names += [f"{c}[t-{k}]" for k in range(1, lags + 1)]
    return names


def _lag_block(values: np.ndarray, lags: int) -> np.ndarray:
    """(N, c) -> (N - lags, c * (lags + 1)) with, per column, lag 0, 1, ..., lags."""
    win = sliding_window_view(values, lags + 1, axis=0)  # (N - lags, c, lags + 1), oldest first
    return win[:, :, ::-1].reshape(win.shape[0], -1)


def make_samples(
    ds: Dataset,
    targets: Sequence[str],
    mode: str = "static",
    window: float = 0.0,
    *,
    inputs: Sequence[str] | None = None,
    physical_model: Any = None,
) -> Samples:
    """Build the samples of ``ds`` for predicting ``targets`` in ``mode``.

    ``window`` (seconds) is the past horizon Delta of the ``window`` mode: inputs over
    [t - Delta, t] and measured outputs over [t - Delta, t - dt]. The first Delta/dt rows
    of each segment, whose window is incomplete, are not evaluated.
    """
    if mode not in MODES:
        raise DataError(f"unknown evaluation mode {mode!r}; use one of {', '.join(MODES)}")
    targets = list(targets)
    if not targets:
        raise DataError("no target given")
    for name in targets:
        col = ds.schema[name]
        if col.role != "output":
            raise DataError(f"column {name!r} has role {col.role!r}; only 'output' columns can be targets")
    inputs = list(ds.schema.inputs if inputs is None else inputs)
    for name in inputs:
        if ds.schema[name].role != "input":
            raise DataError(f"column {name!r} has role {ds.schema[name].role!r}; only 'input' columns are run-time inputs")
    if window < 0:
        raise DataError(f"window must be >= 0 seconds, got {window}")
    lags = int(round(window / ds.dt))
    if abs(lags * ds.dt - window) > 1e-9 * max(1.0, window):
        raise DataError(f"window {window} s is not a multiple of the sample period {ds.dt} s")
    if mode != "window" and lags:
        raise DataError(f"a window of {window} s needs mode 'window' (mode is {mode!r})")
    internals = ds.schema.internals

    if mode == "window":
        feature_names = lagged_feature_names(inputs, targets, lags)
    else:
        feature_names = list(inputs)

    segs = []
    for sid, part in ds.segments():
        U = part[inputs].to_numpy(dtype=np.float64)
        Y = part[targets].to_numpy(dtype=np.float64)
        t = part[TIME].to_numpy(dtype=np.float64)
        Z = part[internals].to_numpy(dtype=np.float64) if internals else None
        n = len(part)
        if n <= lags:
            raise DataError(
                f"dataset {ds.name!r}, segment {sid!r}: {n} rows, shorter than the window of "
                f"{lags + 1} samples ({window} s); drop short segments or use a shorter window"
            )
        if mode == "window" and lags:
            X = _lag_block(U, lags)
            X = np.hstack([X, _lag_block(Y[:-1], lags - 1)]) if lags else X
            rows = np.arange(lags, n)
        else:
            X = U
            rows = np.arange(n)
        segs.append(
            SegmentSamples(
                id=sid, X=np.ascontiguousarray(X), rows=rows, U=U, t=t, y=Y[rows],
                y0=Y[0] if mode == "simulation" else None, Z=Z,
            )
        )
    units = {c.name: c.unit for c in ds.schema.columns}
    return Samples(
        segments=tuple(segs), mode=mode, window=float(window), dt=ds.dt,
        feature_names=tuple(feature_names), input_names=tuple(inputs), target_names=tuple(targets),
        internal_names=tuple(internals), units=units, physical_model=physical_model,
    )
