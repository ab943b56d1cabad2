"""Model selection inside one repetition, on training data only.

Bootstrap (iid resamples, scored on the out-of-bag rows, as the diesel seed) or blocked
k-fold (contiguous blocks in time order). Every method is asked for predictions of a whole
grid at once, so methods that share work across the grid (one eigendecomposition for
all regularisation values) do it once per resample.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from enginebench.datasets.splits import blocked_folds
from enginebench.errors import MethodError, SpecError
from enginebench.experiments.extension import MAX_ROUNDS, Extension, extend
from enginebench.experiments.search import plain, range_positions, range_warnings, search_points
from enginebench.experiments.spec import Selection
from enginebench.method import Method, grid_points
from enginebench.results.metrics import grid_scores
from enginebench.samples import Samples


def _segment_rows(sizes: np.ndarray) -> list[np.ndarray]:
    edges = np.r_[0, np.cumsum(sizes)]
    return [np.arange(a, b) for a, b in zip(edges[:-1], edges[1:])]


def resample_pairs(n: int, selection: Selection, rng: np.random.Generator,
                   segment_sizes: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(fit rows, validation rows) pairs for the selection scheme.

    With ``segment_sizes`` (simulation mode: a trajectory is only usable whole) the
    resampling units are segments: a bootstrap draws whole segments with replacement
    and validates on the segments left out; k-fold takes contiguous blocks of segments.
    """
    if segment_sizes is not None:
        rows = _segment_rows(np.asarray(segment_sizes))
        m = len(rows)
        if selection.kind == "kfold":
            return [(np.concatenate([rows[i] for i in fit]), np.concatenate([rows[i] for i in val]))
                    for fit, val in blocked_folds(m, min(selection.folds, m))]
        pairs = []
        for _ in range(selection.resamples):
            fit = np.sort(rng.integers(0, m, m))
            oob = np.setdiff1d(np.arange(m), fit)
            if oob.size:
                pairs.append((np.concatenate([rows[i] for i in fit]), np.concatenate([rows[i] for i in oob])))
        return pairs
    if selection.kind == "kfold":
        return blocked_folds(n, selection.folds)
    pairs = []
    for _ in range(selection.resamples):
        fit = rng.integers(0, n, n)
        oob = np.setdiff1d(np.arange(n), fit)
        if oob.size:
            pairs.append((np.sort(fit), oob))
    return pairs


def record_blocks(sizes: np.ndarray, folds: int, init_samples: int = 0
                  ) -> list[tuple[list[tuple[int, int, int]], list[tuple[int, int, int]]]]:
    """K-fold inside records: ``folds`` contiguous time blocks over the training rows, cut at record ends.

    Returns, per fold, (fitting pieces, validation pieces) as ``(segment, start, stop)`` raw
    rows: the validation block and everything else, each record's remainder kept as
    contiguous pieces (a piece before and a piece after the block). A validation piece
    must be longer than ``init_samples`` + 1 (its own init window plus something to score),
    a fitting piece at least 2 rows; shorter ones are left out. SpecError when a fold is
    left with nothing to score (more folds than the records can hold).
    """
    sizes = np.asarray(sizes, dtype=np.int64)
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    edges = np.linspace(0, int(sizes.sum()), folds + 1).round().astype(np.int64)
    out = []
    for j in range(folds):
        lo, hi = edges[j], edges[j + 1]
        fit, val = [], []
        for k, (s0, n) in enumerate(zip(starts, sizes)):
            a, b = max(lo - s0, 0), min(hi - s0, n)
            if a < b and b - a > init_samples + 1:
                val.append((k, int(a), int(b)))
            for c, d in ((0, min(max(a, 0), n)), (max(min(b, n), 0), n)) if a < b else ((0, n),):
                if d - c >= 2:
                    fit.append((k, int(c), int(d)))
        if not val:
            shortest = int(np.diff(edges).min())
            raise SpecError(
                f"selection kfold: fold {j + 1} of {folds} has no block longer than init_samples + 1 = "
                f"{init_samples + 1} samples (blocks of ~{shortest} samples over {len(sizes)} training record(s)); "
                f"use fewer folds or a smaller init_samples")
        out.append((fit, val))
    return out


LONG_BLOCK = 2 ** 16
"""A validation block of at most this many samples is scored whole (every block of the built-in experiments)."""


def scored_pieces(pieces: list[tuple[int, int, int]], init_samples: int = 0) -> list[tuple[int, int, int]]:
    """The parts of k-fold validation blocks that are simulated and scored: a block of at most ``LONG_BLOCK``
    samples whole; a longer one of n samples as m = ceil(log2 n) sub-blocks of ``LONG_BLOCK // m`` scored
    samples each, every one after its own ``init_samples`` window, spread evenly from the block's start to its
    end (the first starts where the block starts, the last ends where it ends).

    A free run costs time in proportion to the samples it simulates, once per candidate: scoring at most
    ``LONG_BLOCK`` samples per block keeps a selection's cost from growing with the record's length, while
    sub-blocks from all over the block still see every part of it (a 28-hour record's night and day), and more
    of them, shorter, the longer it is. Deterministic: no random draw, so nothing else in a job changes.
    """
    out: list[tuple[int, int, int]] = []
    for k, a, b in pieces:
        n = b - a
        if n <= LONG_BLOCK:
            out.append((k, a, b))
            continue
        m = int(np.ceil(np.log2(n)))
        span = init_samples + LONG_BLOCK // m
        starts = a + np.linspace(0, n - span, m).round().astype(np.int64)
        out.extend((k, int(s), int(s) + span) for s in starts)
    return out


WARNED_EDGES = {"both": ("lower", "upper"), "low": ("lower",), "high": ("upper",), "none": ()}
"""A method's edge rule (``Method.grid_edges``: "both", "low", "high", "none") -> the grid edges worth a warning."""


def grid_positions(space: dict[str, np.ndarray], chosen: dict[str, Any],
                   rules: dict[str, str] | None = None) -> dict[str, dict[str, Any]]:
    """Where each selected value sits in its grid, for every numeric grid of 3 or more distinct finite values.

    ``{name: {"edge": "lower" | "upper" | None, "value": selected, "lower": grid min, "upper": grid max,
    "warn": bool}}``; ``warn`` is True at an edge that ``rules`` (hyperparameter -> "both", "low",
    "high" or "none"; "both" for one not listed) says is worth a warning. Other parameters (short,
    non-numeric or non-finite grids) are left out: an edge of theirs says nothing.
    """
    rules = rules or {}
    out: dict[str, dict[str, Any]] = {}
    for name, values in space.items():
        try:
            grid = np.unique(np.asarray(values, dtype=float))
            value = float(chosen[name])
        except (TypeError, ValueError, KeyError):
            continue
        if len(grid) < 3 or not np.isfinite(grid).all():
            continue
        edge = "lower" if value == grid[0] else "upper" if value == grid[-1] else None
        out[name] = {"edge": edge, "value": value, "lower": float(grid[0]), "upper": float(grid[-1]),
                     "warn": edge in WARNED_EDGES.get(rules.get(name, "both"), ("lower", "upper"))}
    return out


def edge_warnings(method: str, space: dict[str, np.ndarray], chosen: dict[str, Any],
                  rules: dict[str, str] | None = None, extension: Extension | None = None) -> list[str]:
    """A warning for each selected value at an edge of a numeric grid of 3 or more values that ``rules`` warns about.

    After an ``extension``: a value at its declared hard bound is said to be there (the search does not go
    past a bound), one still at an edge when the extension's rounds ran out says so; a hyperparameter without a
    declared bound keeps the advice to widen its grid."""
    out = []
    at_bound = extension.at_bound if extension is not None else {}
    stopped = extension.stopped if extension is not None else {}
    for name, e in grid_positions(space, chosen, rules).items():
        if not e["warn"]:
            continue
        if name in at_bound:
            out.append(f"{method}: {name} = {e['value']:g} selected at its declared hard bound {at_bound[name][1]:g} "
                       f"(searched [{e['lower']:g} .. {e['upper']:g}]); the search does not go past the bound")
        elif name in stopped:
            out.append(f"{method}: {name} = {e['value']:g} still at the {e['edge']} edge after {MAX_ROUNDS} rounds of "
                       f"extending its grid (searched [{e['lower']:g} .. {e['upper']:g}]); the optimum may lie beyond it")
        else:
            out.append(f"{method}: {name} = {e['value']:g} selected at the {e['edge']} edge of its grid "
                       f"[{e['lower']:g} .. {e['upper']:g}]; the optimum may lie beyond it: widen the grid")
    return out


def edge_rules(method: Method) -> tuple[dict[str, str], dict[str, str]]:
    """(hyperparameter -> edge rule, hyperparameter -> the option that sets its grid) from the method's declared options."""
    declaration = method.option_declaration()
    rules = method.grid_edges()
    setting: dict[str, list[str]] = {}
    for f in declaration.fields:
        for param in f.searches:
            setting.setdefault(param, []).append(f.name)
    return rules, {param: " and ".join(names) for param, names in setting.items()}  # lags: "na and nb"


@dataclass(frozen=True)
class SelectionTable:
    """Every grid point's score on every resample or fold of one selection (the validation curve as data)."""

    grid: list[dict[str, Any]]
    """The grid points, in the order methods were asked to predict them."""
    scores: np.ndarray
    """(n_grid, n_resamples) float64 criterion values; +inf where a point's predictions were non-finite."""
    criterion: str
    chosen: int
    """Index in ``grid`` of the selected point (lowest mean score over the resamples)."""

    def frame(self) -> pd.DataFrame:
        """One row per (grid point, resample): ``point``, ``param:<name>`` per hyperparameter (float, or text
        for a non-numeric value), ``resample``, ``score``, ``criterion`` and ``chosen`` (True on every row
        of the selected point)."""
        n_grid, n_res = self.scores.shape
        point = np.repeat(np.arange(n_grid, dtype=np.int64), n_res)
        out: dict[str, Any] = {"point": point}
        for name in self.grid[0] if self.grid else []:
            values = [p[name] for p in self.grid]
            numeric = all(isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_)) for v in values)
            column = (np.asarray(values, dtype=float) if numeric
                      else np.array([v if isinstance(v, str) else str(v) for v in values], dtype=object))
            out[f"param:{name}"] = column[point]
        out["resample"] = np.tile(np.arange(n_res, dtype=np.int64), n_grid)
        out["score"] = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        out["criterion"] = self.criterion
        out["chosen"] = point == self.chosen
        return pd.DataFrame(out)


class BestModel:
    """Scores each model of ``fit_grid`` as it comes and keeps the best so far (lowest score, first on ties)."""

    def __init__(self) -> None:
        self.index: int | None = None
        self.score = np.inf
        self.fitted: Any = None

    def scores(self, method: Method, fit_part: Samples, val_part: Samples, points: list[dict[str, Any]],
               rng: np.random.Generator, criterion: str, offset: int) -> np.ndarray:
        """The criterion of every point (``offset``: the points' first index in the whole search)."""
        view = val_part.without_targets()
        out = np.full(len(points), np.nan)
        for i, fitted in method.fit_grid(fit_part, points, rng):
            out[i] = grid_scores(np.concatenate(method.predict(fitted, view))[None], val_part, criterion)[0]
            if out[i] < self.score or (self.index is not None and out[i] == self.score and offset + i < self.index):
                self.index, self.score, self.fitted = offset + i, out[i], fitted
        method.check_grid_covered(~np.isnan(out))
        return out


NEAR_MEAN = 0.98
"""A selected point scoring at least this share of the training mean's score has no skill worth the name (the
tables' flag uses the same 2 %)."""


def mean_baseline_score(parts: list[tuple[Samples, Samples]], criterion: str) -> float:
    """The criterion of the fitting part's mean as the prediction of each validation part, averaged like the grid's:
    the score a candidate must beat to have learnt anything."""
    total = 0.0
    for fit_part, val_part in parts:
        if not len(fit_part) or not len(val_part):
            return float("nan")
        guess = np.broadcast_to(fit_part.y.mean(axis=0), val_part.y.shape)[None]
        total += float(grid_scores(guess, val_part, criterion)[0])
    return total / len(parts)


class CandidateFailures:
    """Scores grid points on one resample, a point that raises scored as failed (+inf) for that point alone.

    A method predicts a whole grid at once; when that raises, each point is predicted alone, so one
    candidate the data cannot carry (an order too high for a fold, a factorisation that breaks) fails itself
    and not the job. Each failure is kept as a note (point, resample, reason) and summed up in one warning.
    """

    def __init__(self, method: str) -> None:
        self.method = method
        self.notes: list[dict[str, Any]] = []

    def scores(self, method: Method, fit_part: Samples, val_part: Samples, points: list[dict[str, Any]],
               rng: np.random.Generator, criterion: str, resample: int) -> np.ndarray:
        view = val_part.without_targets()
        try:
            return grid_scores(method.predict_grid(fit_part, view, points, rng), val_part, criterion)
        except Exception as whole_grid:  # noqa: BLE001 - any failure of a candidate is its own
            if len(points) == 1:
                self._note(points[0], resample, whole_grid)
                return np.array([np.inf])
        out = np.empty(len(points))
        for i, point in enumerate(points):
            try:
                out[i] = grid_scores(method.predict_grid(fit_part, view, [point], rng), val_part, criterion)[0]
            except Exception as bad:  # noqa: BLE001
                self._note(point, resample, bad)
                out[i] = np.inf
        return out

    def _note(self, point: dict[str, Any], resample: int, error: Exception) -> None:
        reason = " ".join(str(error).split()) or type(error).__name__
        self.notes.append({"point": {k: plain(v) for k, v in point.items()}, "resample": resample + 1,
                           "reason": f"{type(error).__name__}: {reason}"})

    def warnings(self) -> list[str]:
        """One line for all failed candidates: how many, on how many resamples, and the first reason."""
        if not self.notes:
            return []
        points = {repr(n["point"]) for n in self.notes}
        first = self.notes[0]
        shown = ", ".join(f"{k}={_shown(v)}" for k, v in first["point"].items())
        return [f"{self.method}: {len(points)} candidate(s) failed on {len(self.notes)} resample fit(s) and were "
                f"scored as failed there (e.g. {shown} on resample {first['resample']}: {first['reason']})"]

    def first_reason(self) -> str:
        return f" (first failure: {self.notes[0]['reason']})" if self.notes else ""


def _shown(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def select(method: Method, train: Samples, selection: Selection, rng: np.random.Generator,
           validation: Samples | None = None, init_samples: int = 0,
           keep_fitted: bool = False) -> tuple[dict[str, Any], dict[str, Any]]:
    """The best grid point for ``method`` on ``train`` and a record of the search.

    ``selection.kind == "validation"`` fits on all of ``train`` and scores on the split's
    own validation part (the turboshaft seed's protocol). ``init_samples`` is the
    experiment's state initialisation window, given to validation blocks cut from
    training records (simulation-mode k-fold). The record lists the selected values at
    the edge of their grid under ``warnings`` (as the method's ``grid_edges`` rules
    allow), where each searched numeric parameter sits in its grid under ``grid_edges``
    (``grid_positions``, plus ``option``: the declared option that sets that grid, or
    None), and holds the scores of every grid point on
    every resample or fold under ``table`` (a :class:`SelectionTable`; absent when
    nothing was scored: an empty or one-point grid, ``kind = "none"``).

    ``keep_fitted`` (a validation selection whose model is not refitted): the selected
    point's model, fitted on ``train`` and scored on the validation part, is returned under
    ``fitted``, so the model tested is the model selected (for methods that predict
    through ``fit_grid``; the record has no ``fitted`` otherwise, and the caller fits).

    ``selection.search`` "random" or "bayes" tries ``selection.trials`` points over the ranges
    the grid spans instead (``experiments/search.py``), on the same resamples or folds (drawn
    first); the table then lists the trials in order, and ``grid_edges`` and the warnings
    flag a selected value within 2 % of its range's ends (``range_positions``).
    """
    space = method.search_space(train)
    grid = grid_points(space)
    if not grid:
        return {}, {"grid_size": 0}
    if len(grid) == 1 or selection.kind == "none":
        return grid[0], {"grid_size": len(grid)}
    if selection.kind == "validation":
        if validation is None:
            raise MethodError("selection kind 'validation' needs a split with a validation part")
        parts = [(train, validation)]
    elif train.mode == "simulation" and selection.kind == "kfold":
        blocks = record_blocks(train.segment_sizes, selection.folds, init_samples)
        parts = [(train.cut(fit), train.cut(scored_pieces(val, init_samples), init_samples))
                 for fit, val in blocks]
    else:
        sizes = np.array([len(s) for s in train.segments]) if train.mode == "simulation" else None
        parts = [(train.take(f), train.take(v)) for f, v in resample_pairs(len(train), selection, rng, sizes)]
    if not parts:
        raise MethodError(f"model selection for {method.name!r}: no usable resample (training set of {len(train)} rows)")

    keeper = BestModel() if keep_fitted and selection.kind == "validation" and method.keeps_grid_models() else None
    evaluated = [0]
    failures = CandidateFailures(method.name)

    def evaluate(points: list[dict[str, Any]]) -> np.ndarray:
        scores = np.empty((len(points), len(parts)))
        for j, (fit_part, val_part) in enumerate(parts):
            if keeper is not None:
                scores[:, j] = keeper.scores(method, fit_part, val_part, points, rng, selection.criterion, evaluated[0])
            else:
                scores[:, j] = failures.scores(method, fit_part, val_part, points, rng, selection.criterion, j)
        evaluated[0] += len(points)
        return scores

    if selection.search == "grid":
        scores = evaluate(grid)
    else:  # random or bayes: points drawn or proposed over the ranges the grid spans (experiments/search.py)
        grid, scores = search_points(space, selection.search, selection.trials, rng, evaluate)
    rules, options = edge_rules(method)
    bounds = method.search_bounds(train)
    extension = None
    searched = len(grid)
    if selection.search == "grid" and selection.extend and bounds:
        extension = extend(space, grid, scores, evaluate, bounds, rules, WARNED_EDGES)
        grid, scores, space = extension.points, extension.scores, extension.extended_space
    total = np.zeros(len(grid))
    for j in range(len(parts)):
        total += scores[:, j]
    mean = total / len(parts)
    if not np.isfinite(mean).any():
        raise MethodError(f"model selection for {method.name!r}: every grid point gave non-finite predictions"
                          + failures.first_reason())
    best = int(np.argmin(np.where(np.isfinite(mean), mean, np.inf)))
    if selection.search == "grid":
        edges = grid_positions(space, grid[best], rules)
        warnings = edge_warnings(method.name, space, grid[best], rules, extension)
    else:
        edges = range_positions(space, grid[best], rules, WARNED_EDGES)
        warnings = range_warnings(method.name, edges)
    for name, found in edges.items():
        found["option"] = options.get(name)
        if extension is not None and name in extension.added:
            found["extended"] = [float(v) for v in extension.added[name]]
        if extension is not None and name in extension.at_bound:
            found["bound"] = extension.at_bound[name][1]
    record = {"grid_size": searched, "best_score": float(mean[best]), "resamples": len(parts),
              "grid_edges": edges, "table": SelectionTable(grid, scores, selection.criterion, best)}
    if selection.search != "grid":
        record["search"] = selection.search
    if extension is not None and extension.added:
        record["extended"] = {name: [float(v) for v in added] for name, added in extension.added.items()}
        record["extension_points"] = len(grid) - searched
    if keeper is not None and keeper.index == best:
        record["fitted"] = keeper.fitted
    baseline = mean_baseline_score(parts, selection.criterion)
    record["mean_score"] = baseline
    if np.isfinite(baseline) and mean[best] >= NEAR_MEAN * baseline:
        warnings.append(f"{method.name}: no candidate scored better than the training mean on the selection's "
                        f"resamples (best {selection.criterion} {mean[best]:.4g} vs the mean's {baseline:.4g}): "
                        f"its model class or grid does not fit these data; expect no skill over the mean")
    warnings += failures.warnings()
    if failures.notes:
        record["failed_candidates"] = failures.notes
    if warnings:
        record["warnings"] = warnings
    return grid[best], record
