"""Searching past a grid's edge: a selected value at an edge is tried further out until it is inside or at its bound.

A fixed grid whose best point sits at an edge says only that the optimum may lie beyond it;
leaving the user to widen it is leaving them the search. Where a method declares hard bounds
for a hyperparameter (``Field.bound`` next to the option that sets its grid, or
``Method.search_bounds`` from the data, e.g. the most lags a record carries), a selected value
at an extendable edge is moved one step past it and scored on the same resamples or folds,
together with the selected point's neighbours in the other numeric hyperparameters (the
values either side of the selected ones), since their optimum moves with it (a kernel's
width and its ridge penalty trade off along a diagonal). This repeats while the best point
sits at an edge.

The step is the grid's own spacing at that edge: a ratio where the grid is log-spaced
(every value positive and evenly spaced in log10, or spanning two decades or more), a
difference otherwise, whole numbers where the grid holds whole numbers. It doubles each
time the same edge is pushed again, so ten decades past a grid take a handful of rounds,
and the last step stops at the bound. Once the best value is inside, a gap the doubled
steps left next to it is halved until it is no wider than the grid's median spacing, or on a
linear axis of values >= 0 than a fifth of the best value (:data:`RELATIVE_RESOLUTION`: a bracket
closed in on, as in a line search, to the precision such a value needs). The search ends when no selected value sits at an
extendable edge or next to a wide gap, when a value has reached its bound (the warning then
names the bound, not "widen the grid") or after ``MAX_ROUNDS`` rounds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from enginebench.declare import is_number
from enginebench.experiments.search import infer_range

MAX_ROUNDS = 16
"""Most rounds of extension in one selection (each scores a handful of points on every resample)."""

RELATIVE_RESOLUTION = 0.2
"""On a linear axis of values >= 0 (a horizon in seconds, a count), gaps next to the best value are not refined
below this fraction of it: nfir's and boost-fir's data-derived horizon grids may be spaced 0.1 s near zero, and
refining down to that spacing around a best horizon of 2.1 s took a boosted-trees selection through six more
rounds (2.5, 1.9, 2.3, 2.2, 2.0 s ...) whose fold-mean scores differed by at most 0.2 %."""

Bounds = Mapping[str, tuple[float | None, float | None]]
Evaluate = Callable[[list[dict[str, Any]]], np.ndarray]


@dataclass
class Axis:
    """One extendable hyperparameter: its values so far (sorted), scale, bounds and pushes per edge."""

    name: str
    values: list[float]
    log: bool
    whole: bool
    low: float | None
    high: float | None
    pushes: dict[str, int] = field(default_factory=lambda: {"lower": 0, "upper": 0})
    added: list[float] = field(default_factory=list)
    step: float = 0.0
    """The grid's typical (median) spacing, in log10 on a log axis: gaps left by doubled steps are refined down to
    it. The median, not the finest: a data-derived grid may hold two close values (nfir's and boost-fir's horizons:
    M/2, M, 2M and the ladder's best, which may lie next to M), and refining every gap down to theirs scored a
    dozen near-equal horizons on every fold."""

    def __post_init__(self) -> None:
        if not self.step:
            self.step = float(np.median(np.diff(self._coordinates(self.values))))

    def _coordinates(self, values: list[float]) -> np.ndarray:
        return np.log10(values) if self.log else np.asarray(values, dtype=float)

    def refinement(self, value: float) -> float | None:
        """A value halving the wider gap next to ``value`` left by a doubled step (None: both gaps at most the
        grid's spacing): the search brackets an optimum with doubling steps, then closes in on it."""
        i = self.values.index(value)
        x = self._coordinates(self.values)
        gaps = [(x[i] - x[i - 1], i - 1) if i > 0 else (0.0, -1), (x[i + 1] - x[i], i + 1) if i + 1 < len(x) else (0.0, -1)]
        gap, j = max(gaps)
        fine = self.step
        if not self.log and self.values[0] >= 0:  # a length or count: known to a fraction of itself is enough
            fine = max(fine, RELATIVE_RESOLUTION * abs(value))
        if gap <= fine * (1 + 1e-9) or j < 0:
            return None
        mid = (x[i] + x[j]) / 2
        new = 10.0 ** mid if self.log else mid
        if self.whole:
            new = float(np.round(new))
            if new in self.values:
                return None
        return float(new)

    def edge(self, value: float) -> str | None:
        return "lower" if value <= self.values[0] else "upper" if value >= self.values[-1] else None

    def bound(self, edge: str) -> float | None:
        return self.low if edge == "lower" else self.high

    def at_bound(self, edge: str) -> bool:
        b = self.bound(edge)
        end = self.values[0] if edge == "lower" else self.values[-1]
        return b is not None and (end <= b if edge == "lower" else end >= b)

    def next_value(self, edge: str) -> float | None:
        """The value one (doubling) step past ``edge``, cut at the bound; None at the bound or without one."""
        b = self.bound(edge)
        if b is None or self.at_bound(edge):
            return None
        times = 2 ** self.pushes[edge]
        if edge == "lower":
            end, inner = self.values[0], self.values[1]
            new = end / (inner / end) ** times if self.log else end - (inner - end) * times
            new = max(new, b)
            if self.whole:
                new = float(min(np.floor(new + 1e-9), end - 1))
                new = max(new, float(np.ceil(b - 1e-9)))
        else:
            end, inner = self.values[-1], self.values[-2]
            new = end * (end / inner) ** times if self.log else end + (end - inner) * times
            new = min(new, b)
            if self.whole:
                new = float(max(np.ceil(new - 1e-9), end + 1))
                new = min(new, float(np.floor(b + 1e-9)))
        if (edge == "lower" and new >= self.values[0]) or (edge == "upper" and new <= self.values[-1]):
            return None
        return new

    def neighbours(self, value: float) -> list[float]:
        i = int(np.searchsorted(self.values, value))
        return self.values[max(i - 1, 0): i + 2]

    def insert(self, value: float) -> None:
        self.values = sorted(set(self.values) | {value})
        self.added.append(value)


def _numeric_values(values: Any) -> list[float] | None:
    items = list(np.asarray(values).reshape(-1))
    if not items or not all(is_number(v) and np.isfinite(v) for v in items):
        return None
    return sorted({float(v) for v in items})


def axes(space: Mapping[str, np.ndarray], bounds: Bounds) -> dict[str, Axis]:
    """The hyperparameters that may be extended: numeric grids of 3 or more values with a declared bound."""
    out = {}
    for name, (low, high) in bounds.items():
        if name not in space:
            continue
        values = _numeric_values(space[name])
        if values is None or len(values) < 3:
            continue
        positive = values[0] > 0
        log = positive and (infer_range(name, np.asarray(values)).log or values[-1] / values[0] >= 100)
        whole = np.asarray(space[name]).dtype.kind in "iu"  # whole numbers by type, not by value (100.0 is a float)
        out[name] = Axis(name, values, bool(log), bool(whole), low, high)
    return out


def _as_type(template: Any, value: float) -> Any:
    return int(round(value)) if isinstance(template, (int, np.integer)) else float(value)


@dataclass
class Extension:
    """What the extension did: the points and scores (grid first), the values added and the edges left at a bound."""

    points: list[dict[str, Any]]
    scores: np.ndarray
    added: dict[str, list[float]]
    at_bound: dict[str, tuple[str, float]]
    """Hyperparameter -> (edge, bound) where the selected value stopped at its bound."""
    stopped: dict[str, str]
    """Hyperparameter -> edge still selected when ``MAX_ROUNDS`` ran out."""
    extended_space: dict[str, np.ndarray]


def _mean(scores: np.ndarray) -> np.ndarray:
    """The mean over resamples, summed column by column as ``selection.select`` does (the same ties)."""
    total = np.zeros(len(scores))
    for j in range(scores.shape[1]):
        total += scores[:, j]
    return total / max(scores.shape[1], 1)


def extend(space: Mapping[str, np.ndarray], points: list[dict[str, Any]], scores: np.ndarray, evaluate: Evaluate,
           bounds: Bounds, rules: Mapping[str, str], warned: Mapping[str, tuple[str, ...]],
           max_rounds: int = MAX_ROUNDS) -> Extension:
    """Extend the search past the edges the selected point sits at (module docstring).

    ``rules``/``warned``: a hyperparameter's edge rule and the edges it makes worth searching past (the edges
    worth a warning: an integer degree's lower edge 1 is neither). ``evaluate`` scores new points on every
    resample, as for the grid.
    """
    found = axes(space, bounds)
    points = list(points)
    scores = np.asarray(scores, dtype=float)
    seen = {tuple(map(repr, p.values())) for p in points}

    def best_point() -> dict[str, Any] | None:
        mean = _mean(scores)
        finite = np.where(np.isfinite(mean), mean, np.inf)
        return points[int(np.argmin(finite))] if np.isfinite(finite).any() else None

    def extendable(name: str, best: dict[str, Any]) -> str | None:
        edge = found[name].edge(float(best[name]))
        return edge if edge in warned.get(rules.get(name, "both"), ("lower", "upper")) else None

    for _ in range(max_rounds):
        best = best_point()
        if best is None:
            break
        new: list[dict[str, Any]] = []
        for name, axis in found.items():
            edge = extendable(name, best)
            value = axis.next_value(edge) if edge else None
            if value is not None:
                axis.pushes[edge] += 1  # type: ignore[index]
            elif edge is None and axis.added:
                value = axis.refinement(float(best[name]))
            if value is None:
                continue
            combos: list[dict[str, Any]] = [dict(best, **{name: _as_type(best[name], value)})]
            for other in found:
                if other != name:
                    near = found[other].neighbours(float(best[other]))
                    combos = [dict(c, **{other: _as_type(best[other], v)}) for c in combos for v in near]
            axis.insert(value)
            for c in combos:
                key = tuple(map(repr, c.values()))
                if key not in seen:
                    seen.add(key)
                    new.append(c)
        if not new:
            break
        points.extend(new)
        scores = np.vstack([scores, np.asarray(evaluate(new), dtype=float)])
    at_bound: dict[str, tuple[str, float]] = {}
    stopped: dict[str, str] = {}
    best = best_point()
    for name, axis in found.items():
        edge = extendable(name, best) if best is not None else None
        if edge is None:
            continue
        if axis.at_bound(edge):
            at_bound[name] = (edge, float(axis.bound(edge)))  # type: ignore[arg-type]
        elif axis.bound(edge) is not None:
            stopped[name] = edge
    extended = {name: (np.asarray(found[name].values) if name in found and found[name].added else np.asarray(v))
                for name, v in space.items()}
    return Extension(points, scores, {n: a.added for n, a in found.items() if a.added}, at_bound, stopped, extended)
