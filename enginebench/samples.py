"""What a method sees: per-segment feature matrices and targets, built for one evaluation mode.

The features are built here, not by the methods, so that the ``window`` mode can only
ever offer measured outputs strictly before t: a method cannot read y(t) because y(t)
is not in its inputs.

This module is that contract (``Samples``, ``SegmentSamples``, the window features'
names, the ``init_samples`` rule); it stands on nothing but numpy, the errors and the
declared fields. The raw arrays, the pools that draw rows from them and ``make_samples``,
which builds samples from a dataset, are ``datasets/pools.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Iterator, Sequence

import numpy as np

from enginebench.declare import Invalid, whole
from enginebench.errors import DataError


MODES = ("static", "window", "simulation")

INIT_SAMPLES = whole("init_samples", 0, "simulation mode: samples that set each evaluated segment's state", low=0,
                     unit="samples", message="'{name}' must be a whole number of samples >= 0, got {value}")
"""The ``init_samples`` key, declared once: the experiment spec lists it, :func:`init_samples_problem` checks it."""


def init_samples_problem(init_samples: Any, mode: str) -> str | None:
    """What is wrong with ``init_samples`` in evaluation ``mode``, or None: a whole number of samples >= 0, and
    above 0 only in simulation mode. The one check of the key: the experiment spec reports it after the spec's
    origin, a ``SamplePool`` built directly raises it as a DataError."""
    try:
        init_samples = INIT_SAMPLES.validate(init_samples)
    except Invalid as bad:
        return bad.render(INIT_SAMPLES.name, init_samples)
    if init_samples and mode != "simulation":
        return f"init_samples = {init_samples} needs mode = 'simulation' (mode is {mode!r})"
    return None


@dataclass(frozen=True)
class SegmentSamples:
    """One segment's samples.

    ``X`` holds one row per evaluated time step (``rows`` gives its position in the
    raw segment); ``U`` and ``t`` hold the raw run-time inputs and time over the whole
    segment, for physical models and simulators. ``y`` is absent when the method is
    asked to predict; ``y0`` (simulation mode) is the measured output at the segment's
    first raw row. ``y_init`` (simulation mode) holds the measured outputs of the state
    initialisation window, raw rows ``0 .. N-1``, shape (N, targets); the evaluated rows
    then start at N, so a simulating method may use them to set its state and never sees
    a measured output after them. N = 0 (the default) gives an empty window and y0 only.
    """

    id: str
    X: np.ndarray
    rows: np.ndarray
    U: np.ndarray
    t: np.ndarray
    y: np.ndarray | None = None
    y0: np.ndarray | None = None
    Z: np.ndarray | None = None
    y_init: np.ndarray | None = None

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
    init_samples: int = 0
    """Simulation mode: samples at the start of each evaluated segment that set the state (see ``y_init``)."""

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
        """The view handed to ``Method.predict``: targets removed (y0 and the init window ``y_init`` kept)."""
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

    def cut(self, pieces: Sequence[tuple[int, int, int]], init_samples: int = 0) -> "Samples":
        """Contiguous pieces of whole segments as segments of their own: ``(segment, start, stop)`` raw rows.

        For model selection inside records (simulation mode): a validation block is simulated
        from its own start, its first ``init_samples`` samples set the state (``y_init``) and
        are not evaluated; a fitting piece keeps every row. Needs whole segments with
        targets (training samples), never a row subsample.
        """
        out = []
        for k, a, b in pieces:
            s = self.segments[k]
            if s.y is None or len(s.rows) != len(s.t) or (len(s.rows) and s.rows[0] != 0):
                raise DataError(f"segment {s.id!r}: only whole training segments with targets can be cut into blocks")
            if not 0 <= a < b <= len(s.t) or b - a <= init_samples:
                raise DataError(f"segment {s.id!r}: block {a}:{b} of {len(s.t)} rows is not longer than "
                                f"init_samples = {init_samples}")
            lo = a + init_samples
            out.append(SegmentSamples(
                id=f"{s.id}[{a}:{b}]", X=s.X[lo:b], rows=np.arange(init_samples, b - a), U=s.U[a:b], t=s.t[a:b],
                y=s.y[lo:b], y0=s.y[a], Z=None if s.Z is None else s.Z[a:b], y_init=s.y[a:lo],
            ))
        return replace(self, segments=tuple(out), init_samples=init_samples)

    def joined(self, other: "Samples") -> "Samples":
        """These segments followed by ``other``'s (same targets, mode and features): e.g. training + validation."""
        if (other.target_names, other.feature_names, other.mode) != (self.target_names, self.feature_names, self.mode):
            raise DataError("cannot join samples of different targets, features or modes")
        return replace(self, segments=self.segments + other.segments)

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

    @property
    def segment_sizes(self) -> np.ndarray:
        """Rows per segment, in order."""
        return np.array([len(s) for s in self.segments], dtype=np.int64)

    def batches(self, max_rows: int, features: bool = True) -> Iterator["Samples"]:
        """Consecutive blocks of at most ``max_rows`` rows, in order (a segment may span blocks);
        ``features`` is a pool's (these samples' features are built already)."""
        return iter_batches(self, max_rows, features)

    def materialize(self) -> "Samples":
        """These samples (a ``SamplePool`` builds its rows here)."""
        return self


def lagged_feature_names(inputs: Sequence[str], outputs: Sequence[str], lags: int) -> list[str]:
    """Names of the window features: ``x[t]``, ``x[t-1]``... and ``y[t-1]``...``y[t-lags]``."""
    names = []
    for c in inputs:
        names += [f"{c}[t]"] + [f"{c}[t-{k}]" for k in range(1, lags + 1)]
    for c in outputs:
        names += [f"{c}[t-{k}]" for k in range(1, lags + 1)]
    return names


def iter_batches(data: Any, max_rows: int, features: bool = True) -> Iterator[Samples]:
    """``data`` (``Samples`` or a ``datasets.pools.SamplePool``) in consecutive row blocks of at most ``max_rows``
    rows (one block if it is small).

    ``features=False`` (a pool only): the blocks' ``X`` have no columns, built without the window's lags."""
    n = len(data)
    step = max(1, int(max_rows))
    if n <= step and isinstance(data, Samples):
        yield data
        return
    for start in range(0, n, step):
        rows = np.arange(start, min(n, start + step))
        yield data.take(rows) if isinstance(data, Samples) else data.take(rows, features=features)
