"""The raw arrays of a dataset part and the pools that draw samples from them, features built on demand.

``RawSegments`` reads each segment's inputs, outputs, internals and time from the frame
once (and can ``spill`` them to one memory-mapped file shared by worker processes);
a ``SamplePool`` stands for the ``Samples`` of one (targets, mode, window) setting and
builds the feature rows of only the rows a job draws (``take``, ``batches``). What the
samples look like to a method (``Samples``, ``SegmentSamples``, the window features'
names) is ``enginebench/samples.py``; this module is how the rows are stored and drawn, so
that sharing and memory use stay apart from the contract, and ``make_samples`` builds a
dataset's samples through a pool.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from enginebench.datasets.dataset import TIME, Dataset
from enginebench.datasets.schema import Schema
from enginebench.errors import DataError
from enginebench.samples import (MODES, Samples, SegmentSamples, init_samples_problem, iter_batches,
                                 lagged_feature_names)


@dataclass(frozen=True, eq=False)
class SegmentArrays:
    """The raw arrays of one segment, read from the frame once and shared by every pool."""

    id: str
    U: np.ndarray
    """Run-time inputs over the whole segment, (n, c)."""
    Y: np.ndarray
    """Measured outputs over the whole segment, (n, k_all), columns in ``RawSegments.outputs`` order."""
    t: np.ndarray
    Z: np.ndarray | None


@dataclass(frozen=True, eq=False)
class RawSegments:
    """Per-segment arrays of one dataset part, built once and shared by all (target, window) pools.

    Sharing matters at full size: one copy of the inputs serves every target and window,
    and window features are only ever built for the rows a job asks for.
    """

    segments: tuple[SegmentArrays, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    internals: tuple[str, ...]
    dt: float
    units: dict[str, str]
    dataset: str
    spill_file: str | None = field(default=None, compare=False)
    """The file the arrays are memory-mapped from (see ``spill``); None while they live in memory."""
    layout: tuple = field(default=(), compare=False, repr=False)

    @classmethod
    def from_dataset(cls, ds: Dataset, *, inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                     internals: Sequence[str] | None = None) -> "RawSegments":
        """Read ``inputs``, ``outputs`` and ``internals`` (default: the schema's) of every segment of ``ds``."""
        inputs = list(ds.schema.inputs if inputs is None else inputs)
        outputs = list(ds.schema.outputs if outputs is None else outputs)
        internals = list(ds.schema.internals if internals is None else internals)
        for name in inputs:
            if ds.schema[name].role != "input":
                raise DataError(f"column {name!r} has role {ds.schema[name].role!r}; only 'input' columns are run-time inputs")
        segs = []
        for sid, part in ds.segments():
            segs.append(SegmentArrays(
                id=sid,
                U=part[inputs].to_numpy(dtype=np.float64),
                Y=part[outputs].to_numpy(dtype=np.float64),
                t=part[TIME].to_numpy(dtype=np.float64),
                Z=part[internals].to_numpy(dtype=np.float64) if internals else None,
            ))
        return cls(segments=tuple(segs), inputs=tuple(inputs), outputs=tuple(outputs), internals=tuple(internals),
                   dt=ds.dt, units={c.name: c.unit for c in ds.schema.columns}, dataset=ds.name)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for seg in self.segments for a in (seg.U, seg.Y, seg.t, seg.Z) if a is not None)

    def spill(self, path: str | os.PathLike[str]) -> "RawSegments":
        """Write every array to one file and return a copy that reads them memory-mapped from it.

        The copy pickles as the file name and layout, not the data: worker processes on
        the same machine map the same file, so the operating system keeps one shared,
        read-only copy of the raw data in its page cache instead of one per worker.
        The file must outlive every process that uses the copy.
        """
        layout, offset = [], 0
        with open(path, "wb") as fh:
            for seg in self.segments:
                entry = []
                for arr in (seg.U, seg.Y, seg.t, seg.Z):
                    if arr is None:
                        entry.append(None)
                        continue
                    arr = np.ascontiguousarray(arr, dtype=np.float64)
                    arr.tofile(fh)
                    entry.append((offset // 8, arr.shape))
                    offset += arr.nbytes
                layout.append((seg.id, tuple(entry)))
        return RawSegments._mapped(str(path), tuple(layout), self.inputs, self.outputs, self.internals, self.dt,
                                   self.units, self.dataset)

    @classmethod
    def _mapped(cls, path: str, layout: tuple, inputs: tuple[str, ...], outputs: tuple[str, ...],
                internals: tuple[str, ...], dt: float, units: dict[str, str], dataset: str) -> "RawSegments":
        """The arrays of a spilled file as read-only views of one memory map."""
        total = sum(int(np.prod(shape)) for _, entry in layout for item in entry if item is not None
                    for shape in [item[1]])
        flat = np.memmap(path, dtype=np.float64, mode="r", shape=(total,)) if total else np.empty(0)

        def view(item: tuple | None) -> np.ndarray | None:
            if item is None:
                return None
            start, shape = item
            return flat[start:start + int(np.prod(shape))].reshape(shape)

        segments = tuple(SegmentArrays(sid, *(view(item) for item in entry)) for sid, entry in layout)
        return cls(segments=segments, inputs=inputs, outputs=outputs, internals=internals, dt=dt, units=units,
                   dataset=dataset, spill_file=path, layout=layout)

    def __reduce__(self):
        if self.spill_file is None:
            return super().__reduce__()
        return (RawSegments._mapped, (self.spill_file, self.layout, self.inputs, self.outputs, self.internals,
                                      self.dt, self.units, self.dataset))


class SamplePool:
    """The samples of one (targets, mode, window) setting, with features built only on demand.

    Behaves like the ``Samples`` it stands for (``len``, ``segment_sizes``, ``take``,
    ``batches``) but holds only the raw segment arrays: ``take`` builds the feature rows
    of just the rows asked for, so a 1,000-row training subsample of a 4-million-row
    pool never materialises the pool's lagged features.
    """

    def __init__(self, raw: RawSegments, targets: Sequence[str], mode: str = "static", window: float = 0.0, *,
                 physical_model: Any = None, init_samples: int = 0) -> None:
        if mode not in MODES:
            raise DataError(f"unknown evaluation mode {mode!r}; use one of {', '.join(MODES)}")
        targets = list(targets)
        if not targets:
            raise DataError("no target given")
        for name in targets:
            if name not in raw.outputs:
                raise DataError(f"column {name!r} is not an 'output' column; only 'output' columns can be targets "
                                f"(outputs: {', '.join(raw.outputs) or 'none'})")
        if window < 0:
            raise DataError(f"window must be >= 0 seconds, got {window}")
        lags = int(round(window / raw.dt))
        if abs(lags * raw.dt - window) > 1e-9 * max(1.0, window):
            raise DataError(f"window {window} s is not a multiple of the sample period {raw.dt} s")
        if mode != "window" and lags:
            raise DataError(f"a window of {window} s needs mode 'window' (mode is {mode!r})")
        problem = init_samples_problem(init_samples, mode)  # the spec's check (an experiment has passed it)
        if problem:
            raise DataError(problem)
        init_samples = int(init_samples)
        for seg in raw.segments:
            if len(seg.t) <= lags:
                raise DataError(
                    f"dataset {raw.dataset!r}, segment {seg.id!r}: {len(seg.t)} rows, shorter than the window of "
                    f"{lags + 1} samples ({window} s); drop short segments or use a shorter window"
                )
            if len(seg.t) <= init_samples:
                raise DataError(
                    f"dataset {raw.dataset!r}, segment {seg.id!r}: {len(seg.t)} rows, not longer than the state "
                    f"initialisation window init_samples = {init_samples}; lower init_samples or drop the segment"
                )
        self.raw = raw
        self.target_names = tuple(targets)
        self.mode = mode
        self.window = float(window)
        self.lags = lags
        self.init_samples = init_samples
        self.physical_model = physical_model
        self._target_cols = [raw.outputs.index(t) for t in targets]
        self._skip = lags + init_samples  # raw rows before the first evaluated one (only one of the two is > 0)
        self.segment_sizes = np.array([len(s.t) - self._skip for s in raw.segments], dtype=np.int64)
        self._offsets = np.r_[0, np.cumsum(self.segment_sizes)]
        names = lagged_feature_names(raw.inputs, targets, lags) if mode == "window" else list(raw.inputs)
        self.feature_names = tuple(names)

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def segment_ids(self) -> list[str]:
        return [s.id for s in self.raw.segments]

    def _features(self, seg: SegmentArrays, Y: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Feature rows at raw positions ``rows``: inputs at lags 0..L, outputs at lags 1..L (window mode)."""
        L = self.lags
        if L == 0:
            return seg.U[rows]
        m, p, q = len(rows), seg.U.shape[1], Y.shape[1]
        past = rows[:, None] - np.arange(L + 1)[None, :]                     # (m, L + 1): t, t-1, ..., t-L
        out = np.empty((m, p * (L + 1) + q * L))                            # written once, no hstack copy
        X_in = out[:, : p * (L + 1)].view()
        X_in.shape = (m, p, L + 1)                                          # a view (raises rather than copy)
        X_in[...] = seg.U[past].transpose(0, 2, 1)                          # per input: lag 0..L
        X_out = out[:, p * (L + 1):].view()
        X_out.shape = (m, q, L)
        X_out[...] = Y[past[:, 1:]].transpose(0, 2, 1)                      # per target: lag 1..L, never lag 0
        return out

    def _segment(self, k: int, local: np.ndarray | None, features: bool = True) -> SegmentSamples:
        seg = self.raw.segments[k]
        Y = seg.Y[:, self._target_cols]
        n = len(seg.t)
        rows = np.arange(self._skip, n) if local is None else np.asarray(local, dtype=np.int64) + self._skip
        whole = local is None and self._skip == 0
        if not features:
            X = np.empty((len(rows), 0))
        else:
            X = seg.U if whole else np.ascontiguousarray(self._features(seg, Y, rows))
        sim = self.mode == "simulation"
        return SegmentSamples(id=seg.id, X=X, rows=rows, U=seg.U, t=seg.t, y=Y[rows],
                              y0=Y[0] if sim else None, Z=seg.Z,
                              y_init=Y[:self.init_samples] if sim else None)

    def _samples(self, segments: Sequence[SegmentSamples]) -> Samples:
        raw = self.raw
        return Samples(
            segments=tuple(segments), mode=self.mode, window=self.window, dt=raw.dt,
            feature_names=self.feature_names, input_names=raw.inputs, target_names=self.target_names,
            internal_names=raw.internals, units=dict(raw.units), physical_model=self.physical_model,
            init_samples=self.init_samples,
        )

    def materialize(self) -> Samples:
        """Every row's samples (what ``make_samples`` returns)."""
        return self._samples([self._segment(k, None) for k in range(len(self.raw.segments))])

    def take(self, index: np.ndarray, features: bool = True) -> Samples:
        """Rows at global positions ``index`` (repeats allowed), grouped by segment in segment order
        (``features=False``: ``X`` with no columns, for a method that declares ``uses_features = False``)."""
        index = np.asarray(index, dtype=np.int64)
        if index.size and (index.min() < 0 or index.max() >= len(self)):
            raise IndexError(f"row index out of range 0..{len(self) - 1}")
        seg_of = np.searchsorted(self._offsets, index, side="right") - 1
        order = np.argsort(seg_of, kind="stable")
        index, seg_of = index[order], seg_of[order]
        return self._samples([self._segment(int(k), index[seg_of == k] - self._offsets[k], features)
                              for k in np.unique(seg_of)])

    def batches(self, max_rows: int, features: bool = True) -> Iterator[Samples]:
        """Consecutive blocks of at most ``max_rows`` rows, in order (a segment may span blocks);
        ``features=False`` builds no feature rows (``take``)."""
        return iter_batches(self, max_rows, features)


def check_targets(schema: Schema, targets: Sequence[str]) -> list[str]:
    """``targets`` as a list, each checked to be an 'output' column of ``schema`` (unknown names list all columns)."""
    targets = list(targets)
    if not targets:
        raise DataError("no target given")
    for name in targets:
        col = schema[name]
        if col.role != "output":
            raise DataError(f"column {name!r} has role {col.role!r}; only 'output' columns can be targets")
    return targets


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
    targets = check_targets(ds.schema, targets)
    raw = RawSegments.from_dataset(ds, inputs=inputs, outputs=targets)
    return SamplePool(raw, targets, mode, window, physical_model=physical_model).materialize()
