"""The Method interface: one small contract that every model, built-in or plugin, fulfils."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Iterator, Mapping, Sequence

import numpy as np

from enginebench.declare import Declaration, anything, log_grid as declared_log_grid
from enginebench.errors import MethodError
from enginebench.samples import Samples

FAMILIES = ("physical", "data-driven", "hybrid", "baseline")

EXPLAIN_WEIGHTS = "weights"
"""``Method.explain`` key: mixing weights per row (sum 1), drawn as stacked bands (a mixture's gate)."""

Params = Mapping[str, Any]
SearchSpace = dict[str, np.ndarray]
"""Hyperparameter name -> candidate values; model selection searches their product."""


def log_grid(low_exp: float, high_exp: float, num: int) -> np.ndarray:
    """``num`` values from 10**low_exp to 10**high_exp, evenly spaced in the exponent."""
    return np.logspace(low_exp, high_exp, num)


def check_log_grid_option(method: str, key: str, spec: Any) -> tuple[float, float, int]:
    """Validate a (low exponent, high exponent, count) grid option; MethodError naming it otherwise.

    A thin wrapper over the declaration's ``log_grid`` kind, kept for plugins that check by hand.
    """
    Declaration(declared_log_grid(key, spec, "")).validate({key: spec}, f"method {method!r}", MethodError, fill=False)
    low, high, num = spec
    return float(low), float(high), int(num)


def grid_points(space: SearchSpace) -> list[dict[str, Any]]:
    """Every point of the product grid, in a fixed order (last name varies fastest)."""
    names = list(space)
    return [dict(zip(names, values)) for values in itertools.product(*(space[n] for n in names))]


@dataclass(frozen=True)
class TrainingShape:
    """What ``Method.check_data`` is told of one split's training part, before the first job."""

    records: tuple[int, ...]
    """Samples of each training record (the raw records: a method's lags run inside each of them)."""
    inputs: tuple[str, ...]
    targets: tuple[str, ...]
    dt: float
    """The sample period (s)."""
    mode: str

    @property
    def longest(self) -> int:
        return max(self.records, default=0)

    def rows_after(self, lags: int) -> int:
        """Samples of the records that have ``lags`` earlier samples inside their own record."""
        return sum(max(0, n - lags) for n in self.records)

    def describe(self) -> str:
        """The records in words, for a message: "3 training records of at most 120 samples (360 in all)"."""
        n = len(self.records)
        return (f"{n} training record{'s' if n != 1 else ''} of at most {self.longest} samples "
                f"({sum(self.records)} in all)")


class Method:
    """Base class of every method.

    Subclasses set ``name``, ``family`` and ``modes`` and implement ``fit`` and
    ``predict``. ``fit`` sees training samples with targets; ``predict`` sees samples
    whose targets were removed, so a method cannot peek at what it must predict.
    Options that are not searched (switches, fixed settings) are constructor keywords,
    declared once in ``declared_options`` (kind, default, unit, one-line meaning: see
    ``enginebench/declare.py``); ``default_options`` and the constructor's checks come from
    it. A plugin may instead override ``default_options`` alone: its options are then
    undeclared (any value, no meaning).
    """

    name: ClassVar[str] = ""
    family: ClassVar[str] = "data-driven"
    modes: ClassVar[frozenset[str]] = frozenset({"static", "window"})
    summary: ClassVar[str] = ""
    reference_baseline: ClassVar[bool] = False
    """True for the method results tables measure skill against (``results.tables.BASELINE``
    names it: the training mean, family "baseline"); exactly one registered method declares it."""

    uses_features: ClassVar[bool] = True
    """False for a method that never reads ``data.X`` when it predicts (the training mean; a physical
    model simulated from the raw inputs ``U``): the toolkit then builds no feature rows for the parts it
    evaluates and hands it ``X`` with no columns. ``check_method`` checks the claim."""

    joint_targets: ClassVar[bool] = False
    """True for a method that models several targets at once (``fit`` and ``predict`` take samples
    with k targets and share the work between them): with the experiment's ``joint_targets = true``
    it runs one job for all targets, its hyperparameters selected on the summed, scale-free error."""

    declared_options: ClassVar[Declaration] = Declaration()
    """Every constructor option: default, kind, accepted values, unit and meaning."""

    def __init__(self, **options: Any) -> None:
        self.options = self.option_declaration().validate(options, f"method {self.name!r}", MethodError)

    @classmethod
    def default_options(cls) -> dict[str, Any]:
        """Every option with its default (from ``declared_options``)."""
        return cls.declared_options.defaults()

    @classmethod
    def option_declaration(cls) -> Declaration:
        """The options as checked and shown: ``declared_options`` with the keys and defaults of
        ``default_options()`` (a key only ``default_options`` names is undeclared: any value, no meaning)."""
        declared = cls.declared_options
        defaults = cls.default_options()
        fields = []
        for key, value in defaults.items():
            if key not in declared:
                fields.append(anything(key, value))
            elif declared[key].default is value:
                fields.append(declared[key])
            else:
                fields.append(replace(declared[key], default=value))
        return Declaration(*fields)

    @classmethod
    def grid_edges(cls) -> dict[str, str]:
        """Searched hyperparameter -> at which edges of its grid a selected value deserves a warning:
        "both", "low", "high" or "none" (from the options that set each grid; a hyperparameter not
        listed has no declaring option, e.g. a fixed search space)."""
        return cls.option_declaration().edges()

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """Searched hyperparameter -> hard bounds (low, high) that model selection may extend its grid to when the
        selected value sits at an edge (``experiments/extension.py``). The default reads the declared options'
        ``bound``; a method whose bounds depend on the data (the most lags a record carries) overrides it."""
        return self.option_declaration().bounds()

    def check_columns(self, inputs: Sequence[str], internals: Sequence[str], targets: Sequence[str]) -> None:
        """Optional hook, called before the first job: MethodError when an option names a column the experiment's
        data do not have in that role (so the mistake is one line up front, not a failed job per repetition)."""

    def check_data(self, shape: TrainingShape) -> None:
        """Optional hook, called before the first job with the shape of each split's training part: MethodError
        when an option asks for more than those data can carry (lags longer than the records), so the mistake is
        one line up front, not a failed job per repetition."""

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
        trajectory, never the measured one). The reserved name that figures draw:
        ``EXPLAIN_WEIGHTS`` ("weights": k mixing weights summing to 1 per row, e.g. a
        mixture of experts' gate, drawn as stacked bands under the trajectory). Other
        names are free. The default explains nothing ({}), and figures then draw the
        prediction alone: the toolkit never recognises a method by its name or class.
        """
        return {}

    def model_state(self, fitted: Any) -> Any:
        """Optional hook: ``fitted`` as data a stored model holds (``results/model_store.py``): arrays, numbers,
        text, lists, tuples, str-keyed dicts and dataclasses of them, nothing that runs code when read. The default
        hands over ``fitted`` itself; a method holding other objects returns their arrays here and rebuilds them
        in ``model_from_state``, or raises MethodError saying why its models cannot be stored."""
        return fitted

    def model_from_state(self, state: Any) -> Any:
        """The fitted model from what ``model_state`` returned (the default: it is the model)."""
        return state

    def c_model(self, fitted: Any) -> Any:
        """Optional hook: the fitted model's step as C code (a ``methods.export.CModel``) for an FMU and the
        real-time figures; None (the default) when the method cannot be exported."""
        return None

    def step_times(self, fitted: Any, data: Samples) -> tuple[str, np.ndarray] | None:
        """Optional hook: the fitted model run step by step on the method's own step code over every segment of
        ``data`` (the test part, simulation mode), for the real-time figures: ``(what was timed, e.g. "c-step";
        the seconds of each step)``. None (the default): the method times no step of its own, and the job's
        prediction time over the steps stands in. MethodError when the step cannot be timed on this machine (no
        C compiler): its message says why. The built-in exportable methods time their ``c_model`` step with
        ``methods.export.harness.c_step_times``."""
        return None

    def onnx_model(self, fitted: Any) -> Any:
        """Optional hook: the fitted model's initial state and step as a torch network (a
        ``methods.export.onnx.OnnxModel``) for ``export --onnx``; None (the default) when it has none."""
        return None

    def fit_grid(
        self, train: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> Iterator[tuple[int, Any]]:
        """Fitted models of the grid points as ``(index in grid, fitted)``, each point once, in any order.

        The default fits each point in turn. A method whose points share a fit overrides it
        (one training run checkpointed at several epoch counts yields a model per count);
        the fitted models must equal what ``fit`` would return for each point given the
        same draws. Model selection predicts and scores each model as it comes and keeps
        the best, so that with ``refit = false`` the model selected is the model tested.
        """
        for i, params in enumerate(grid):
            yield i, self.fit(train, params, rng)

    def keeps_grid_models(self) -> bool:
        """Whether ``predict_grid`` predicts the models of ``fit_grid``, so that model selection may
        score them one by one and keep the one it selects: true unless ``predict_grid`` is overridden."""
        return type(self).predict_grid is Method.predict_grid

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Predictions of ``data`` for every grid point, shape (n_grid, n_rows, n_targets).

        The default predicts each model of ``fit_grid``; methods that share work across the
        grid's predictions (one eigendecomposition for all regularisation values) override it.
        """
        out: list[np.ndarray | None] = [None] * len(grid)
        for i, fitted in self.fit_grid(train, grid, rng):
            out[i] = np.concatenate(self.predict(fitted, data))
        self.check_grid_covered([o is not None for o in out])
        return np.stack(out)

    def check_grid_covered(self, covered: Sequence[bool]) -> None:
        """MethodError naming the grid points that ``fit_grid`` yielded no model for."""
        missing = [i for i, c in enumerate(covered) if not c]
        if missing:
            raise MethodError(f"method {self.name!r}: fit_grid yielded no model for grid point(s) {missing}")

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
