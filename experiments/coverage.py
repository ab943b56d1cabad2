"""Where the evaluated records' inputs (and outputs) leave the range the training records cover.

A model fitted on inputs in [low, high] extrapolates beyond it, and its error there (or its
divergence: a free run pushed past the amplitudes it was fitted on) says more about the data
than about the method. The F-16 ground vibration test is the case in point: its level-4
validation record drives the structure with a force well past the training levels', and a
nonlinear model that is fine on level 2 diverges there. The run states such records once,
under every view of it (``results/notes.py``), so a reader sees why before blaming a method.

The outputs are checked the same way: Silverbox's test part opens with an input whose amplitude
grows past the estimation data's, and it is the output's amplitude that a free run must
extrapolate to. A column counts as outside on a record when at least ``MIN_FRACTION`` of the
record's rows lie more than ``MARGIN`` of the training span past the training minimum or
maximum: both relative to the data, so a few spikes or a value grazing the edge say nothing.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.datasets.pools import RawSegments

MARGIN = 0.05
"""How far past the training range (a fraction of its span) a value must lie to count as outside."""
MIN_FRACTION = 0.01
"""The share of a record's rows that must lie outside for the record to be named."""


def _training_range(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    lows = [np.nanmin(a, axis=0) for a in arrays if len(a)]
    highs = [np.nanmax(a, axis=0) for a in arrays if len(a)]
    return np.nanmin(np.vstack(lows), axis=0), np.nanmax(np.vstack(highs), axis=0)


def _outside(X: np.ndarray, low: np.ndarray, high: np.ndarray, names: tuple[str, ...], where: dict[str, Any]
             ) -> list[dict[str, Any]]:
    """The entries of one record's columns ``X`` outside [low, high] (``MARGIN``, ``MIN_FRACTION``)."""
    span = high - low
    beyond = np.maximum(low - X, X - high)  # > 0 outside the range, in the column's unit
    with np.errstate(invalid="ignore"):
        fraction = (beyond > MARGIN * span).mean(axis=0)
    entries = []
    for j in np.flatnonzero(fraction >= MIN_FRACTION):
        reach = float(np.nanmax(beyond[:, j]) / span[j]) if span[j] > 0 else None  # a constant in training
        entries.append({**where, "column": names[j], "fraction": float(fraction[j]), "reach": reach,
                        "low": float(low[j]), "high": float(high[j])})
    return entries


def range_coverage(raws: Mapping[str, Mapping[str, RawSegments]]) -> dict[str, Any]:
    """``{"records": {part: count}, "outside": [...]}`` over every split's evaluated parts (all but "train").

    ``outside`` holds one entry per (split, part, record, column) outside the training range, for the
    inputs (what drives the model) and the targets (what a free run must reach: an output past its
    training amplitudes is an extrapolation even when the inputs are not): the role, the share of the
    record's rows outside (``fraction``), the farthest value's distance past the range in training
    spans (``reach``), and the training range (``low``, ``high``).
    """
    records: dict[str, int] = {}
    outside: list[dict[str, Any]] = []
    for split, parts in raws.items():
        train = parts["train"]
        if not any(len(s.t) for s in train.segments):
            continue
        roles = [(role, names, attr, _training_range([getattr(s, attr) for s in train.segments]))
                 for role, names, attr in (("input", train.inputs, "U"), ("output", train.outputs, "Y")) if names]
        for part, raw in parts.items():
            if part == "train":
                continue
            for seg in raw.segments:
                records[part] = records.get(part, 0) + 1
                if not len(seg.t):
                    continue
                where = {"split": split, "part": part, "segment": str(seg.id)}
                for role, names, attr, (low, high) in roles:
                    X = np.asarray(getattr(seg, attr), dtype=np.float64)
                    outside += [{**e, "role": role} for e in _outside(X, low, high, tuple(names), where)]
    return {"records": records, "outside": outside}
