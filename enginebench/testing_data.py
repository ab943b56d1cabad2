"""The tiny synthetic data the conformance suite runs on (``testing.check_method``), also for plugin tests.

Two datasets drawn from one seed: three training segments of 30 samples and two
evaluated segments of 25 (dt = 1 s), run-time inputs ``u1`` (V) and ``u2`` (bar), target
``y`` (degC) with a little memory of its own, and a linear physical model
(``TinyLinearPM``) so that hybrid methods can run too. Extra columns can be asked for
with their role (``roles``, e.g. ``{"w": "internal"}`` for a method that models an
intermediate signal measured in training only, or ``{"w": "input"}``): each is a smooth,
lagged map of ``u1`` and ``u2`` plus a little noise, drawn from a generator of its own so
the other columns do not change. ``tiny_samples`` gives the
(training, evaluated) samples of one mode, as the checks see them: window mode with two
past samples, simulation mode with a ``TINY_INIT``-sample initialisation window at the
start of every evaluated segment. Kept apart from the suite (``testing.py``, which
re-exports ``TinyLinearPM``, ``TINY_INIT`` and ``tiny_samples``, and ``testing_checks.py``)
so that what is checked and on what are read separately.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import RawSegments, SamplePool, make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import DataError
from enginebench.samples import Samples

CHECKED_MODES = ("static", "window", "simulation")
TINY_WINDOW = 2.0
"""Window (seconds, dt = 1 s) used for window mode: two past samples."""
TINY_INIT = 3
"""Simulation mode: the state initialisation window (samples) of every evaluated segment."""


class TinyLinearPM:
    """A physical model for the tiny dataset: y = c0 + c1 * u2, calibrated by least squares."""

    name = "tiny-linear"
    inputs = ("u1", "u2")
    outputs = ("y",)

    def calibrate(self, segments: Sequence[Mapping[str, np.ndarray]]) -> dict[str, Any]:
        u2 = np.concatenate([s["u2"] for s in segments])
        y = np.concatenate([s["y"] for s in segments])
        c1, c0 = np.polyfit(u2, y, 1)
        return {"c0": float(c0), "c1": float(c1)}

    def simulate(self, params: Mapping[str, Any], segment: Mapping[str, np.ndarray], dt: float) -> dict[str, np.ndarray]:
        return {"y": params["c0"] + params["c1"] * np.asarray(segment["u2"], dtype=float)}


def _extra_column(u1: np.ndarray, u2: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """An extra signal of the tiny data: a lagged map of the inputs with its own gains and a little noise."""
    a, b = rng.uniform(0.5, 1.5, 2)
    lagged = np.r_[u2[0], u2[:-1]]
    return 2.0 + a * np.tanh(u1) + b * lagged + rng.normal(0.0, 0.01, len(u1))


def _tiny_frame(n_segments: int, n: int, first: int, seed: int, extra: Sequence[str] = ()) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(first, first + n_segments):
        u1 = rng.uniform(-2.0, 2.0, n)
        u2 = np.cumsum(rng.normal(0.0, 0.3, n))
        y = np.empty(n)
        for i in range(n):
            y[i] = 10.0 + np.sin(u1[i]) + 0.5 * u2[i] + (0.2 * (y[i - 1] - 10.0) if i else 0.0) + rng.normal(0, 0.01)
        columns = {SEGMENT: f"s{k}", TIME: k * (n + 10.0) + np.arange(n, dtype=float), "u1": u1, "u2": u2, "y": y}
        for j, name in enumerate(extra):
            columns[name] = _extra_column(u1, u2, np.random.default_rng((seed, k, j)))
        parts.append(pd.DataFrame(columns))
    return pd.concat(parts, ignore_index=True)


_COLUMNS = (Column("u1", "input", "V"), Column("u2", "input", "bar"), Column("y", "output", "degC"))
EXTRA_ROLES = ("input", "internal")
"""The roles an extra column of the tiny data may take."""


def _schema(roles: Mapping[str, str]) -> Schema:
    """The tiny data's columns, then the extra ones (checked: a new name, role input or internal)."""
    for name, role in roles.items():
        if name in {c.name for c in _COLUMNS} or name in (SEGMENT, TIME):
            raise DataError(f"tiny data: extra column {name!r} is already a column; name another one")
        if role not in EXTRA_ROLES:
            raise DataError(f"tiny data: extra column {name!r} has role {role!r}; use one of {', '.join(EXTRA_ROLES)}")
    return Schema(_COLUMNS + tuple(Column(name, role, "") for name, role in roles.items()))


def tiny_datasets(seed: int, roles: Mapping[str, str] | None = None) -> tuple[Dataset, Dataset]:
    """The (training, evaluated) datasets of ``seed``: 3 x 30 and 2 x 25 samples, with the extra ``roles`` columns."""
    roles = dict(roles or {})
    schema = _schema(roles)
    meta = {"provenance": "enginebench.testing (synthetic)", "licence": "CC0"}
    train = Dataset("check-method-train", _tiny_frame(3, 30, 0, seed, tuple(roles)), schema, 1.0, meta)
    test = Dataset("check-method-test", _tiny_frame(2, 25, 3, seed + 1, tuple(roles)), schema, 1.0, meta)
    return train, test


def samples_of(ds: Dataset, mode: str, evaluated: bool = False) -> Samples:
    """Samples of ``ds``; evaluated simulation samples carry the ``TINY_INIT``-sample initialisation window."""
    if mode == "simulation":
        init = TINY_INIT if evaluated else 0
        return SamplePool(RawSegments.from_dataset(ds, outputs=["y"]), ["y"], "simulation",
                          physical_model=TinyLinearPM(), init_samples=init).materialize()
    return make_samples(ds, ["y"], mode, TINY_WINDOW if mode == "window" else 0.0, physical_model=TinyLinearPM())


def tiny_samples(mode: str = "static", seed: int = 0,
                 roles: Mapping[str, str] | None = None) -> tuple[Samples, Samples]:
    """The (training, evaluated) samples ``check_method`` uses, with targets, for ``mode``.

    In simulation mode the evaluated segments start with a ``TINY_INIT``-sample
    initialisation window (``y_init``); training segments are whole. ``roles`` adds
    extra columns (name -> ``input`` or ``internal``), as ``check_method`` does.
    """
    if mode not in CHECKED_MODES:
        raise DataError(f"tiny_samples: mode {mode!r} is not checked; use one of {', '.join(CHECKED_MODES)}")
    train, test = tiny_datasets(seed, roles)
    return samples_of(train, mode), samples_of(test, mode, evaluated=True)
