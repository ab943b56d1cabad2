"""Feature ranking by backward elimination (Guyon & Elisseeff 2003), per target and method.

Starting from all variables, each step drops the variable whose removal hurts the
validation error least; the ranking is the reverse order of removal (the last variable
standing is the most important). In window mode a variable's whole lagged series is one
feature, as in the egt-hybrid paper. For hybrid methods that feed the physical model's
prediction in as a feature, that prediction is a candidate variable named ``PM``.

Hyperparameters are selected once on all variables (the run's selection scheme), then
held fixed; every candidate removal is scored on the same training/validation pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from enginebench.errors import MethodError
from enginebench.experiments.selection import resample_pairs, select
from enginebench.experiments.spec import Selection
from enginebench.method import Method
from enginebench.results.metrics import grid_scores
from enginebench.samples import Samples

PM_VARIABLE = "PM"


@dataclass(frozen=True)
class Candidate:
    variables: tuple[str, ...]
    method: Method
    samples: Samples


def _variant(method: Method, train: Samples, keep: tuple[str, ...]) -> Candidate:
    groups = train.variables()
    cols = [j for v in keep if v in groups for j in groups[v]]
    if not cols and not (PM_VARIABLE in keep):
        raise MethodError("backward elimination left no feature")
    method_k = method
    if "pm_feature" in method.options and method.options["pm_feature"] != (PM_VARIABLE in keep):
        method_k = type(method)(**{**method.options, "pm_feature": PM_VARIABLE in keep})
    return Candidate(keep, method_k, train.select_features(cols))


def rank_features(
    method: Method, train: Samples, selection: Selection, rng: np.random.Generator,
    progress: Callable[[int, int], None] | None = None,
) -> pd.DataFrame:
    """Columns: rank (1 = most important), variable, error_after_removal, step."""
    variables = list(train.variables())
    if method.options.get("pm_feature"):
        variables.append(PM_VARIABLE)
    if len(variables) < 2:
        raise MethodError(f"feature ranking needs at least two variables; {method.name} has {variables}")
    params, _ = select(method, train, selection, rng)
    pairs = resample_pairs(len(train), selection, rng)
    remaining = tuple(variables)
    removed: list[tuple[str, float]] = []
    total = len(variables) * (len(variables) + 1) // 2 - 1
    done = 0
    while len(remaining) > 1:
        scores = []
        for v in remaining:
            cand = _variant(method, train, tuple(x for x in remaining if x != v))
            err = 0.0
            for fit_rows, val_rows in pairs:
                fit_part, val_part = cand.samples.take(fit_rows), cand.samples.take(val_rows)
                preds = cand.method.predict_grid(fit_part, val_part.without_targets(), [params], rng)
                err += float(grid_scores(preds, val_part, selection.criterion)[0])
            scores.append(err / len(pairs))
            done += 1
            if progress:
                progress(done, total)
        best = int(np.argmin(scores))
        removed.append((remaining[best], scores[best]))
        remaining = tuple(x for i, x in enumerate(remaining) if i != best)
    removed.append((remaining[0], float("nan")))
    order = list(reversed(removed))
    return pd.DataFrame({
        "rank": np.arange(1, len(order) + 1),
        "variable": [v for v, _ in order],
        "error_after_removal": [e for _, e in order],
        "step": [len(order) - i for i in range(len(order))],
        "params": [str({k: float(v) for k, v in params.items()})] * len(order),
    })
