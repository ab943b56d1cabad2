"""The Method interface: one small contract that every model, built-in or plugin, fulfils."""

from __future__ import annotations

import itertools
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from enginebench.datasets.samples import Samples
from enginebench.errors import MethodError

FAMILIES = ("physical", "data-driven", "hybrid", "baseline")

EXPLAIN_WEIGHTS = "weights"
"""``Method.explain`` key: mixing weights per row (sum 1), drawn as stacked bands (a mixture's gate)."""
EXPLAIN_COMPONENTS = "components"
"""``Method.explain`` key: additive parts of the prediction per row."""

Params = Mapping[str, Any]
SearchSpace = dict[str, np.ndarray]
"""Hyperparameter name -> candidate values; model selection searches their product."""


def log_grid(low_exp: float, high_exp: float, num: int) -> np.ndarray:
    """``num`` values from 10**low_exp to 10**high_exp, evenly spaced in the exponent."""
    return np.logspace(low_exp, high_exp, num)


def check_log_grid_option(method: str, key: str, spec: Any) -> tuple[float, float, int]:
    """Validate a (low exponent, high exponent, count) grid option; MethodError naming it otherwise."""
    try:
        low, high, num = spec
        ok = (not any(isinstance(v, (bool, np.bool_)) for v in (low, high, num))  # true is not a number
              and bool(np.isfinite([low, high]).all()) and float(num) == int(num) and int(num) >= 1)
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise MethodError(
            f"method {method!r}: option {key}={spec!r} must be (low exponent, high exponent, count) "
            f"with a count >= 1, e.g. (-4, 4, 41) for 10^-4 ... 10^4"
        )
    return float(low), float(high), int(num)


def check_whole_option(method: str, key: str, value: Any, low: int = 1) -> int:
    """A whole-number option >= ``low`` (a boolean is not a number); MethodError naming it otherwise."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value < low:
        raise MethodError(f"method {method!r}: option {key} must be a whole number >= {low}, got {value!r}")
    return int(value)


def check_positive_option(method: str, key: str, value: Any) -> float:
    """A finite positive number option (a boolean is not a number); MethodError naming it otherwise."""
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating))
            or not np.isfinite(value) or value <= 0):
        raise MethodError(f"method {method!r}: option {key} must be a positive number, got {value!r}")
    return float(value)


def grid_points(space: SearchSpace) -> list[dict[str, Any]]:
    """Every point of the product grid, in a fixed order (last name varies fastest)."""
    names = list(space)
    return [dict(zip(names, values)) for values in itertools.product(*(space[n] for n in names))]


class Method:
    """Base class of every method.

    Subclasses set ``name``, ``family`` and ``modes`` and implement ``fit`` and
    ``predict``. ``fit`` sees training samples with targets; ``predict`` sees samples
    whose targets were removed, so a method cannot peek at what it must predict.
    Options that are not searched (switches, fixed settings) are constructor keywords.
    """

    name: ClassVar[str] = ""
    family: ClassVar[str] = "data-driven"
    modes: ClassVar[frozenset[str]] = frozenset({"static", "window"})
    summary: ClassVar[str] = ""
    reference_baseline: ClassVar[bool] = False
    """True for the method results tables measure skill against (``results.tables.BASELINE``
    names it: the training mean, family "baseline"); exactly one registered method declares it."""

    def __init__(self, **options: Any) -> None:
        unknown = set(options) - set(self.default_options())
        if unknown:
            raise MethodError(
                f"method {self.name!r}: unknown option(s) {', '.join(sorted(unknown))}; "
                f"known: {', '.join(sorted(self.default_options())) or 'none'}"
            )
        self.options = {**self.default_options(), **options}

    @classmethod
    def default_options(cls) -> dict[str, Any]:
        return {}

    def search_space(self, data: Samples) -> SearchSpace:
        """Candidate hyperparameters; an empty space means nothing to select."""
        return {}

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> Any:
        raise NotImplementedError

    def predict(self, fitted: Any, data: Samples) -> list[np.ndarray]:
        """One (n_rows, n_targets) array per segment of ``data``, aligned with its rows."""
        raise NotImplementedError

    def describe(self, fitted: Any) -> dict[str, Any]:
        """Interpretable artefacts of a fitted model (selected parameters, equations...)."""
        return {}

    def explain(self, fitted: Any, data: Samples) -> dict[str, list[np.ndarray]]:
        """Optional hook: named internal series of the predictions of ``data``, for figures.

        Each value holds one (len(s.rows), k) array per segment of ``data``, aligned with
        the arrays ``predict`` returns (in simulation mode evaluated along the simulated
        trajectory, never the measured one). Reserved names that figures draw:
        ``EXPLAIN_WEIGHTS`` ("weights": k mixing weights summing to 1 per row, e.g. a
        mixture of experts' gate, drawn as stacked bands under the trajectory) and
        ``EXPLAIN_COMPONENTS`` ("components": k additive parts of the prediction). Other
        names are free. The default explains nothing ({}), and figures then draw the
        prediction alone: the toolkit never recognises a method by its name or class.
        """
        return {}

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Predictions of ``data`` for every grid point, shape (n_grid, n_rows, n_targets).

        The default fits each point in turn; methods that share work across the grid
        (one eigendecomposition for all regularisation values) override it.
        """
        out = []
        for params in grid:
            fitted = self.fit(train, params, rng)
            out.append(np.concatenate(self.predict(fitted, data)))
        return np.stack(out)

    def check_mode(self, mode: str) -> None:
        if mode not in self.modes:
            raise MethodError(
                f"method {self.name!r} does not support mode {mode!r}; it supports {', '.join(sorted(self.modes))}"
            )


def split_rows(values: np.ndarray, data: Samples) -> list[np.ndarray]:
    """Cut stacked predictions back into one array per segment of ``data``."""
    sizes = np.cumsum([len(s) for s in data.segments])[:-1]
    return np.split(values, sizes)


class SegmentPredictions(list):
    """Per-segment predictions plus a per-segment ``diverged`` flag.

    Simulating methods return this from ``predict`` so that a trajectory that left its
    bounded envelope or went non-finite is counted and reported, never silently dropped.
    A diverged segment's array still holds what was simulated (held at the envelope
    where it left it), so raw means stay computable.
    """

    def __init__(self, arrays: Sequence[np.ndarray], diverged: Sequence[bool] | None = None) -> None:
        super().__init__(arrays)
        self.diverged = np.zeros(len(self), dtype=bool) if diverged is None else np.asarray(diverged, dtype=bool)
        if self.diverged.shape != (len(self),):
            raise ValueError("one diverged flag per segment is required")
