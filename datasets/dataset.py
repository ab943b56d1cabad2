"""The dataset container: segments of fixed-period recordings with typed columns."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from typing import Any, Iterator

import numpy as np
import pandas as pd

from enginebench.datasets.schema import Schema
from enginebench.errors import DataError

TIME = "time"
"""Time column, in seconds, monotonic within a segment."""
SEGMENT = "segment"
"""Segment id column: one continuous recording (a voyage, a flight, a logging period)."""


@dataclass(frozen=True)
class Dataset:
    """A set of segments sampled every ``dt`` seconds, stored as one long frame.

    ``frame`` has the columns ``segment`` (str), ``time`` (float seconds) and every
    column of ``schema``; rows are ordered by segment (in order of first appearance)
    and by time within a segment. ``meta`` carries provenance, licence, the published
    split and the name of the dataset's physical model, if any.
    """

    name: str
    frame: pd.DataFrame
    schema: Schema
    dt: float
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        missing = [c for c in (SEGMENT, TIME, *self.schema.names()) if c not in self.frame.columns]
        if missing:
            raise DataError(f"dataset {self.name!r}: frame lacks column(s) {', '.join(missing)}")
        if not self.dt > 0:
            raise DataError(f"dataset {self.name!r}: sample period dt must be positive, got {self.dt}")

    # -- segments -------------------------------------------------------------------
    @property
    def segment_ids(self) -> list[str]:
        return list(pd.unique(self.frame[SEGMENT]))

    def segment_bounds(self) -> list[tuple[str, int, int]]:
        """(id, start, stop) row positions of each segment in ``frame``."""
        seg = self.frame[SEGMENT].to_numpy()
        if len(seg) == 0:
            return []
        change = np.flatnonzero(seg[1:] != seg[:-1]) + 1
        starts = np.r_[0, change]
        stops = np.r_[change, len(seg)]
        return [(str(seg[a]), int(a), int(b)) for a, b in zip(starts, stops)]

    def segments(self) -> Iterator[tuple[str, pd.DataFrame]]:
        for sid, a, b in self.segment_bounds():
            yield sid, self.frame.iloc[a:b]

    def __len__(self) -> int:
        return len(self.frame)

    # -- derived datasets -----------------------------------------------------------
    def with_frame(self, frame: pd.DataFrame, **meta: Any) -> "Dataset":
        return replace(self, frame=frame.reset_index(drop=True), meta={**self.meta, **meta})

    def rows(self, mask: np.ndarray) -> "Dataset":
        """The rows where ``mask`` is true (segments keep their ids)."""
        return self.with_frame(self.frame.loc[np.asarray(mask, dtype=bool)])

    def select_segments(self, ids: list[str]) -> "Dataset":
        wanted = set(ids)
        unknown = wanted - set(self.segment_ids)
        if unknown:
            raise DataError(f"dataset {self.name!r}: unknown segment(s) {', '.join(sorted(unknown))}")
        return self.rows(self.frame[SEGMENT].isin(wanted).to_numpy())

    def with_roles(self, changes: dict[str, str]) -> "Dataset":
        """A copy with some columns given new roles; a text column (a group id) cannot become a signal."""
        schema = self.schema.with_roles(changes)
        frame = self.frame
        for name, role in changes.items():
            if role == "group" or name not in frame or pd.api.types.is_numeric_dtype(frame[name].dtype):
                continue
            values = pd.to_numeric(frame[name], errors="coerce")
            bad = values.isna() & frame[name].notna()
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                raise DataError(f"dataset {self.name!r}, column {name!r}: holds text ({str(frame[name].iloc[i])!r} at "
                                f"row {i}), so it cannot have role {role!r} (roles = {{ {name} = \"{role}\" }}); "
                                "only numeric columns can be inputs, outputs or internals")
            frame = frame.assign(**{name: values.astype(float)})
        return replace(self, schema=schema, frame=frame)

    # -- identity -------------------------------------------------------------------
    def content_hash(self) -> str:
        """sha256 of the values, schema and dt: equal data give equal hashes on any machine."""
        h = hashlib.sha256()
        h.update(json.dumps({"schema": self.schema.to_dict(), "dt": self.dt}, sort_keys=True).encode())
        cols = [SEGMENT, TIME, *self.schema.names()]
        h.update(pd.util.hash_pandas_object(self.frame[cols], index=False).to_numpy().tobytes())
        return h.hexdigest()

    def summary(self) -> dict[str, Any]:
        bounds = self.segment_bounds()
        lengths = [b - a for _, a, b in bounds]
        return {
            "name": self.name,
            "rows": len(self.frame),
            "segments": len(bounds),
            "dt_s": self.dt,
            "duration_h": float(sum(lengths) * self.dt / 3600.0),
            "shortest_segment": min(lengths) if lengths else 0,
            "longest_segment": max(lengths) if lengths else 0,
            "inputs": self.schema.inputs,
            "outputs": self.schema.outputs,
            "internal": self.schema.internals,
            "groups": self.schema.groups,
        }
