"""Where the evaluated records' inputs leave the range the training records cover.

A model fitted on inputs in [low, high] extrapolates beyond it, and its error there (or its
divergence: a free run pushed past the amplitudes it was fitted on) says more about the data
than about the method. The F-16 ground vibration test is the case in point: its level-4
validation record drives the structure with a force well past the training levels', and a
nonlinear model that is fine on level 2 diverges there. The run states such records once,
under every view of it (``results/notes.py``), so a reader sees why before blaming a method.

An input counts as outside on a record when at least ``MIN_FRACTION`` of the record's rows lie
more than ``MARGIN`` of the training span past the training minimum or maximum: both relative
to the data, so a few spikes or a value grazing the edge say nothing.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.datasets.pools import RawSegments

MARGIN = 0.05
"""How far past the training range (a fraction of its span) a value must lie to count as outside."""
MIN_FRACTION = 0.01
"""The share of a record's rows that must lie outside for the record to be named."""


def _training_range(train: RawSegments) -> tuple[np.ndarray, np.ndarray]:
    lows = [np.nanmin(s.U, axis=0) for s in train.segments if len(s.U)]
    highs = [np.nanmax(s.U, axis=0) for s in train.segments if len(s.U)]
    return np.nanmin(np.vstack(lows), axis=0), np.nanmax(np.vstack(highs), axis=0)


def input_coverage(raws: Mapping[str, Mapping[str, RawSegments]]) -> dict[str, Any]:
    """``{"records": {part: count}, "outside": [...]}`` over every split's evaluated parts (all but "train").

    ``outside`` holds one entry per (split, part, record, input) outside the training range: the
    share of the record's rows outside (``fraction``), the farthest value's distance past the range
    in training spans (``reach``), and the training range (``low``, ``high``).
    """
    records: dict[str, int] = {}
    outside: list[dict[str, Any]] = []
    for split, parts in raws.items():
        train = parts["train"]
        if not train.inputs or not any(len(s.U) for s in train.segments):
            continue
        low, high = _training_range(train)
        span = high - low
        for part, raw in parts.items():
            if part == "train":
                continue
            for seg in raw.segments:
                records[part] = records.get(part, 0) + 1
                if not len(seg.U):
                    continue
                U = np.asarray(seg.U, dtype=np.float64)
                with np.errstate(invalid="ignore"):
                    past = np.maximum(low - MARGIN * span - U, U - high - MARGIN * span)
                    out = past > 0
                fraction = out.mean(axis=0)
                for j in np.flatnonzero(fraction >= MIN_FRACTION):
                    beyond = np.maximum(low[j] - U[:, j], U[:, j] - high[j])
                    reach = float(np.nanmax(beyond) / span[j]) if span[j] > 0 else None  # a constant in training
                    outside.append({"split": split, "part": part, "segment": str(seg.id), "input": raw.inputs[j],
                                    "fraction": float(fraction[j]), "reach": reach,
                                    "low": float(low[j]), "high": float(high[j])})
    return {"records": records, "outside": outside}
