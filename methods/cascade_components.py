"""The parts a cascade is built from: its component methods, the samples each sees, their tuning and fitted state.

``component_class`` finds a component (upstream, downstream, surrogate NFIR) through the
registry; ``target_samples`` and ``with_inputs`` re-cut a cascade's samples for an
upstream (the intermediate as target) and for the downstream (the intermediates as
inputs); ``intermediate_values`` reads a measured intermediate and ``Initialiser``
estimates its unmeasured initial value; ``upstream_signals`` runs fitted upstreams over
every raw row; ``holdout_search`` tunes a component on held-out trajectories by
segment-averaged MAE (``segment_mae``). The Cascade method and its presets are
``cascade.py``; nothing here reads a cascade's options.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from enginebench.errors import MethodError
from enginebench.method import Method, Params
from enginebench.samples import Samples


def component_class(name: str) -> type[Method]:
    """A cascade component by method name, through the registry (built-ins, plugins, registered classes)."""
    from enginebench.registry import get

    return get(name)


# -- sample plumbing ----------------------------------------------------------------------
def with_inputs(data: Samples, names: Sequence[str], U: Sequence[np.ndarray]) -> Samples:
    """``data`` with new raw inputs per segment (simulation mode: the features are the inputs)."""
    segs = tuple(replace(s, U=u, X=np.ascontiguousarray(u[s.rows])) for s, u in zip(data.segments, U))
    return replace(data, segments=segs, input_names=tuple(names), feature_names=tuple(names))


def intermediate_values(data: Samples, name: str) -> list[np.ndarray]:
    """The measured intermediate over every raw row of each segment, from ``Z`` or from ``U``."""
    if name in data.internal_names:
        j = data.internal_names.index(name)
        missing = [s.id for s in data.segments if s.Z is None]
        if missing:
            raise MethodError(
                f"cascade: the measured {name!r} is needed here but segment {missing[0]!r} carries no internal columns "
                "(prediction samples never do)"
            )
        return [np.asarray(s.Z[:, j], dtype=np.float64) for s in data.segments]
    if name in data.input_names:
        j = data.input_names.index(name)
        return [np.asarray(s.U[:, j], dtype=np.float64) for s in data.segments]
    raise MethodError(
        f"cascade: the data have no column {name!r} (inputs: {', '.join(data.input_names)}; internals: "
        f"{', '.join(data.internal_names) or 'none'}); give {name} the role 'internal' in the experiment "
        f"(roles = {{ {name} = \"internal\" }})"
    )


def target_samples(data: Samples, name: str, inputs: Sequence[str], values: Sequence[np.ndarray] | None,
                   y0: Sequence[np.ndarray] | None) -> Samples:
    """Samples predicting the intermediate ``name`` from ``inputs`` (targets ``values`` when given).

    Their initialisation window is empty (the intermediate is not measured at run time), so a
    simulating upstream starts from ``y0``, the estimate of the intermediate at the first row.
    """
    cols = [data.input_names.index(c) for c in inputs]
    segs = []
    for k, s in enumerate(data.segments):
        u = np.ascontiguousarray(s.U[:, cols])
        segs.append(replace(
            s, U=u, X=np.ascontiguousarray(u[s.rows]), Z=None,
            y=None if values is None else values[k][s.rows][:, None],
            y0=None if y0 is None else np.atleast_1d(np.asarray(y0[k], dtype=np.float64)),
            # the init window measured the target, not the intermediate: the upstream starts from y0 (estimated)
            y_init=np.empty((0, 1)),
        ))
    return replace(data, segments=tuple(segs), input_names=tuple(inputs), feature_names=tuple(inputs),
                   target_names=(name,), internal_names=())


@dataclass(frozen=True)
class Initialiser:
    """Ridge estimate of an intermediate from [run-time inputs, target] at one instant (standardised)."""

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    offset: float

    @classmethod
    def fit(cls, features: np.ndarray, z: np.ndarray, ridge: float = 1e-6) -> "Initialiser":
        mean, scale = features.mean(0), features.std(0)
        scale = np.where(scale > 0, scale, 1.0)
        F = (features - mean) / scale
        zc = z - z.mean()
        coef = np.linalg.solve(F.T @ F + ridge * len(F) * np.eye(F.shape[1]), F.T @ zc)
        return cls(mean=mean, scale=scale, coef=coef, offset=float(z.mean()))

    def __call__(self, features: np.ndarray) -> np.ndarray:
        return ((np.atleast_2d(features) - self.mean) / self.scale) @ self.coef + self.offset


def initial_features(data: Samples, inputs: Sequence[str], y: Sequence[np.ndarray]) -> np.ndarray:
    """(n_segments, n_in + k) first-row features: run-time inputs at row 0 and the measured initial target."""
    cols = [data.input_names.index(c) for c in inputs]
    return np.array([np.r_[s.U[0, cols], np.ravel(yy)] for s, yy in zip(data.segments, y)])


@dataclass
class UpstreamFitted:
    """One fitted upstream model of one intermediate signal."""

    name: str
    method: Method
    fitted: Any
    inputs: tuple[str, ...]
    params: dict[str, Any]
    search: dict[str, Any]
    initialiser: Initialiser


@dataclass
class CascadeFitted:
    """The fitted cascade: upstream models (none when ideal) and the downstream model."""

    upstreams: list[UpstreamFitted]
    """The surrogates' NFIR models first (option ``surrogates``), then one upstream per intermediate."""
    downstream: Method
    fitted: Any
    down_inputs: tuple[str, ...]
    source: str
    intermediates: tuple[str, ...]
    shared: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    """Kept between the models of one grid, which share their upstreams: the last evaluated data and
    its downstream samples (``Cascade.predict``); never pickled."""

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "shared": {}}


def upstream_signals(ups: Sequence[UpstreamFitted], data: Samples, owner: str
                     ) -> tuple[list[list[np.ndarray]], np.ndarray]:
    """Each upstream's prediction of its intermediate over every raw row of every segment, and diverged flags.

    ``owner``: the cascade's name, for the errors when a segment lacks its initial target y0 or the samples
    lack an input an upstream was trained on.
    """
    full = replace(data, segments=tuple(replace(s, rows=np.arange(len(s.U)), y=None, Z=None) for s in data.segments))
    y0 = [s.y0 if s.y0 is not None else (s.y[0] if s.y is not None else None) for s in data.segments]
    if any(v is None for v in y0):
        raise MethodError(f"method {owner!r}: every segment needs its measured initial target y0 (simulation mode)")
    signals, diverged = [], np.zeros(len(data.segments), dtype=bool)
    for up in ups:
        absent = [c for c in up.inputs if c not in data.input_names]
        if absent:
            raise MethodError(f"method {owner!r}: the model of {up.name!r} was trained on the run-time input "
                              f"{absent[0]!r}, which these samples lack; predict with the inputs it was trained on "
                              f"({', '.join(up.inputs)})")
        z0 = up.initialiser(initial_features(full, up.inputs, y0))
        part = target_samples(full, up.name, up.inputs, None, list(z0))
        preds = up.method.predict(up.fitted, part)
        diverged |= np.asarray(getattr(preds, "diverged", np.zeros(len(preds), bool)))
        signals.append([np.asarray(p, dtype=np.float64).reshape(len(s.U), -1)[:, 0] for p, s in zip(preds, full.segments)])
    return signals, diverged


def holdout_search(method: Method, data: Samples, grid: Sequence[Params], holdout: float, rng: np.random.Generator
                   ) -> tuple[Params, dict[str, Any]]:
    """The grid point of ``method`` scoring best on the last ``holdout`` fraction of ``data``'s trajectories.

    Fitted on the other trajectories (``predict_grid``) and scored by ``segment_mae``;
    returns the point and what the search did. With one point, or one trajectory, that
    point (the first) is returned without a search.
    """
    params, search = (grid[0] if grid else {}), {"grid_size": len(grid)}
    n_seg = len(data.segments)
    if len(grid) > 1 and n_seg >= 2:
        n_hold = min(n_seg - 1, max(1, math.ceil(holdout * n_seg)))
        edges = np.r_[0, np.cumsum([len(s) for s in data.segments])]
        fit_part = data.take(np.arange(edges[n_seg - n_hold]))
        hold = data.take(np.arange(edges[n_seg - n_hold], edges[-1]))
        preds = method.predict_grid(fit_part, hold.without_targets(), grid, rng)
        score = segment_mae(preds, hold)
        best = int(np.argmin(score))
        params = grid[best]
        search.update(holdout_segments=n_hold, best_score=float(score[best]))
    return params, search


def segment_mae(predictions: np.ndarray, data: Samples) -> np.ndarray:
    """Segment-averaged MAE of every grid point, (n_grid, n_rows, k) -> (n_grid,); non-finite -> inf."""
    err = np.abs(predictions - data.y[None])
    edges = np.r_[0, np.cumsum([len(s) for s in data.segments])]
    per_seg = np.stack([err[:, a:b].mean(axis=(1, 2)) for a, b in zip(edges[:-1], edges[1:])], axis=1)
    score = per_seg.mean(axis=1)
    return np.where(np.isfinite(score), score, np.inf)
