"""Search beyond grids: a method's search space read as ranges, and the points random or Bayesian search tries.

A method declares candidate values per hyperparameter (``Method.search_space``); grid search
tries their product. Random and Bayesian search read each candidate array as a range
instead (:func:`infer_range`), so every method, plugins included, gets them for free:

* numbers (3 or more distinct, all finite) evenly spaced in log10 -> a log-uniform range on
  [min, max]; evenly spaced floats -> a uniform range; integers -> an integer range on
  [min, max] (log scale when log-spaced, e.g. 1, 10, 100);
* anything else (strings, booleans, fewer than 3 values, irregular floats) -> a choice among
  the given values (one value: fixed).

``random`` draws ``trials`` points from the ranges with the job's generator (duplicates of a
discrete space dropped); ``bayes`` asks optuna's TPE sampler, seeded from the job's generator,
for ``BAYES_BATCH`` points at a time and tells it each point's mean score (a point proposed
again is told its first score, not scored twice). Both evaluate a batch of points together,
so a method's ``predict_grid`` still shares what it can.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from enginebench.errors import SpecError

SEARCHES = ("grid", "random", "bayes")
BAYES_BATCH = 8
"""Points optuna proposes before it is told their scores (one ``predict_grid`` call per resample)."""
EDGE_SHARE = 0.02
"""Random/bayes: a selected value within this share of its range's ends (log scale for log ranges) is at an edge."""
INSTALL = "pip install enginebench[search]"


@dataclass(frozen=True)
class Range:
    """Where one hyperparameter may lie: ``kind`` "float" or "int" on [low, high] (``log``: log-uniform), or
    "choice" among ``choices``."""

    name: str
    kind: str
    low: float = 0.0
    high: float = 0.0
    log: bool = False
    choices: tuple[Any, ...] = ()

    def position(self, value: Any) -> float | None:
        """Where ``value`` lies on the range, 0 at ``low`` and 1 at ``high`` (log scale for log ranges); None
        for a choice or a range of one value."""
        if self.kind == "choice" or self.high <= self.low:
            return None
        lo, hi, v = (np.log10([self.low, self.high, float(value)]) if self.log
                     else (self.low, self.high, float(value)))
        return float((v - lo) / (hi - lo))


def plain(value: Any) -> Any:
    """A numpy scalar as the Python number it holds; anything else as it is."""
    return value.item() if isinstance(value, np.generic) else value


def _evenly_spaced(x: np.ndarray) -> bool:
    step = np.diff(x)
    return bool(np.allclose(step, step.mean(), rtol=1e-6, atol=1e-12 * max(1.0, abs(float(x[-1] - x[0])))))


def infer_range(name: str, values: Sequence[Any] | np.ndarray) -> Range:
    """The range a candidate array stands for (see the module docstring); ``name`` labels it."""
    arr = np.asarray(values)
    distinct = tuple(dict.fromkeys(plain(v) for v in arr.reshape(-1)))
    numeric = arr.dtype.kind in "iuf" and arr.size > 0
    if not numeric or len(distinct) < 3 or not np.isfinite(arr.astype(float)).all():
        return Range(name, "choice", choices=distinct)
    x = np.unique(arr.astype(float))
    log = bool(x[0] > 0 and _evenly_spaced(np.log10(x)) and not _evenly_spaced(x))
    if arr.dtype.kind in "iu":
        return Range(name, "int", int(x[0]), int(x[-1]), log=log)
    if log or _evenly_spaced(x):
        return Range(name, "float", float(x[0]), float(x[-1]), log=log)
    return Range(name, "choice", choices=distinct)


def ranges(space: Mapping[str, np.ndarray]) -> dict[str, Range]:
    """Every searched hyperparameter's range, in the search space's order."""
    return {name: infer_range(name, values) for name, values in space.items()}


def _draw(r: Range, n: int, rng: np.random.Generator) -> list[Any]:
    if r.kind == "choice":
        return [r.choices[i] for i in rng.integers(0, len(r.choices), n)]
    if r.kind == "float":
        u = rng.uniform(np.log10(r.low), np.log10(r.high), n) if r.log else rng.uniform(r.low, r.high, n)
        return [float(v) for v in (10.0 ** u if r.log else u)]
    if r.log:  # log-uniform over the integers: each integer owns [i - 1/2, i + 1/2) on the log scale
        u = 10.0 ** rng.uniform(np.log10(r.low - 0.5), np.log10(r.high + 0.5), n)
        return [int(v) for v in np.clip(np.round(u), r.low, r.high)]
    return [int(v) for v in rng.integers(int(r.low), int(r.high) + 1, n)]


def random_points(space: Mapping[str, Range], trials: int, rng: np.random.Generator) -> list[dict[str, Any]]:
    """``trials`` points drawn from ``space`` (one vector of draws per hyperparameter, in order), each distinct
    point kept once in the order first drawn."""
    columns = {name: _draw(r, trials, rng) for name, r in space.items()}
    points = [{name: columns[name][i] for name in space} for i in range(trials)]
    seen: set[tuple[Any, ...]] = set()
    out = []
    for p in points:
        key = tuple(p.values())
        if key not in seen:
            seen.add(key)
            out.append(p)
    return out


def optuna_module() -> Any:
    """optuna, imported with its logging at warning level; SpecError saying how to install it otherwise."""
    try:
        import optuna
    except ImportError:
        raise SpecError(f"[selection] search = 'bayes' needs optuna, which is not installed; {INSTALL}") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna


def check_search(search: str) -> None:
    """Refuse, before any job runs, a search whose library is missing (bayes without optuna: one SpecError)."""
    if search == "bayes":
        optuna_module()


def _suggest(trial: Any, r: Range) -> Any:
    if r.kind == "choice":
        return r.choices[0] if len(r.choices) == 1 else trial.suggest_categorical(r.name, list(r.choices))
    if r.kind == "int":
        return int(trial.suggest_int(r.name, int(r.low), int(r.high), log=r.log))
    return float(trial.suggest_float(r.name, r.low, r.high, log=r.log))


Evaluate = Callable[[list[dict[str, Any]]], np.ndarray]
"""Points -> (n_points, n_parts) scores (+inf for a failed point)."""


def bayes_points(space: Mapping[str, Range], trials: int, rng: np.random.Generator, evaluate: Evaluate,
                 batch: int = BAYES_BATCH) -> tuple[list[dict[str, Any]], np.ndarray]:
    """``trials`` points proposed by optuna's TPE sampler (seeded by one draw of ``rng``) in batches of ``batch``,
    each batch's new points scored by ``evaluate`` and every proposal told back its mean score; (distinct points,
    their scores) in trial order: a point proposed again (a discrete space) is told its first score, not re-scored."""
    optuna = optuna_module()
    seed = int(rng.integers(0, 2**31 - 1))
    points: list[dict[str, Any]] = []
    rows: dict[tuple[Any, ...], np.ndarray] = {}
    asked_so_far = 0
    with warnings.catch_warnings():  # constant_liar and multivariate are experimental: no job warning for that
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        sampler = optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)
        study = optuna.create_study(sampler=sampler, direction="minimize")
        while asked_so_far < trials:
            asked = [study.ask() for _ in range(min(batch, trials - asked_so_far))]
            asked_so_far += len(asked)
            proposed = [{name: _suggest(t, r) for name, r in space.items()} for t in asked]
            keys = [tuple(p.values()) for p in proposed]
            new = [i for i, k in enumerate(keys) if k not in rows and k not in keys[:i]]
            if new:
                got = np.asarray(evaluate([proposed[i] for i in new]), dtype=float)
                for i, row in zip(new, got):
                    rows[keys[i]] = row
                    points.append(proposed[i])
            for t, key in zip(asked, keys):
                mean = float(rows[key].mean())
                study.tell(t, mean if np.isfinite(mean) else float("inf"))
    return points, np.stack([rows[tuple(p.values())] for p in points])


def search_points(space: Mapping[str, np.ndarray], search: str, trials: int, rng: np.random.Generator,
                  evaluate: Evaluate) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Random or Bayesian search over a method's search space: (points tried, (n_points, n_parts) scores)."""
    found = ranges(space)
    if search == "random":
        points = random_points(found, trials, rng)
        return points, np.asarray(evaluate(points), dtype=float)
    if search == "bayes":
        return bayes_points(found, trials, rng, evaluate)
    raise ValueError(f"search {search!r} is not one of random, bayes")


def range_positions(space: Mapping[str, np.ndarray], chosen: Mapping[str, Any], rules: Mapping[str, str],
                    warned: Mapping[str, tuple[str, ...]]) -> dict[str, dict[str, Any]]:
    """Random/bayes counterpart of ``selection.grid_positions``: for every numeric range, the selected value's
    edge ("lower"/"upper" within ``EDGE_SHARE`` of an end, else None), value, bounds and ``warn`` (the edge is
    one that ``warned[rules[name]]`` lists; rule "both" for a hyperparameter not in ``rules``)."""
    out: dict[str, dict[str, Any]] = {}
    for name, r in ranges(space).items():
        where = r.position(chosen[name]) if name in chosen else None
        if where is None:
            continue
        edge = "lower" if where <= EDGE_SHARE else "upper" if where >= 1 - EDGE_SHARE else None
        out[name] = {"edge": edge, "value": float(chosen[name]), "lower": float(r.low), "upper": float(r.high),
                     "warn": edge in warned.get(rules.get(name, "both"), ("lower", "upper"))}
    return out


def range_warnings(method: str, positions: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """A warning per selected value near a range end worth a warning (``range_positions``)."""
    return [f"{method}: {name} = {e['value']:g} selected within {EDGE_SHARE:.0%} of the {e['edge']} end of its "
            f"range [{e['lower']:g} .. {e['upper']:g}]; the optimum may lie beyond it: widen the range"
            for name, e in positions.items() if e["warn"]]
