"""Conformance checks for Method classes: ``check_method(cls)`` for plugin authors.

A method that passes can be dropped into any experiment: the runner relies on exactly
these properties (a deterministic fit under the job's seed, one array per segment,
predictions that never see the targets, a fitted model and a method that survive
pickling to a worker, and bad input reported as a MethodError line rather than a
traceback). Use it in your plugin's tests::

    from enginebench.testing import check_method
    from my_plugin import MyMethod

    def test_conformance():
        check_method(MyMethod, {"alpha_grid": (-2, 2, 3)})

The checks run on a tiny synthetic dataset (three training and two evaluated segments,
inputs ``u1``, ``u2``, target ``y``) with a linear physical model attached, so hybrid
methods that need one can run too; static, window (two past samples) and simulation
modes are checked, whichever the method supports.

Simulation mode follows the identification protocol: ``fit`` gets whole training
segments; ``predict`` gets evaluated segments whose first ``TINY_INIT`` samples are the
state initialisation window (``y_init``, ``init_samples``; evaluated rows start after it)
and must return ``SegmentPredictions`` (one array of len(s.rows) rows per segment and one
``diverged`` flag per segment). The leakage check perturbs every measured output after
the window: the predictions must not change (the window itself may change them). Bad
input there is a NaN run-time input, a NaN in the initialisation window and a missing
input column. Slow methods can fix hyperparameters with ``params``, e.g.
``check_method(MyODE, params={"epochs": 3})``.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.samples import MODES, Samples, make_samples
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import DataError, EngineBenchError
from enginebench.methods.base import FAMILIES, Method, SegmentPredictions, grid_points

__all__ = ["CHECKS", "ConformanceError", "ConformanceReport", "TinyLinearPM", "check_method", "tiny_samples"]

CHECKS = ("attributes", "options", "determinism", "shapes", "no-target-leakage", "pickle-round-trip", "bad-input")
"""The checks, in the order they run."""

CHECKED_MODES = ("static", "window", "simulation")
TINY_WINDOW = 2.0
"""Window (seconds, dt = 1 s) used for window mode: two past samples."""
TINY_INIT = 3
"""Simulation mode: the state initialisation window (samples) of every evaluated segment."""
_UNKNOWN_OPTION = "no_such_option_for_check_method"


class ConformanceError(AssertionError):
    """One or more checks failed; ``failures`` holds (check, message) pairs."""

    def __init__(self, method: str, failures: Sequence[tuple[str, str]], n_checks: int) -> None:
        self.method = method
        self.failures = list(failures)
        lines = "\n".join(f"  - {msg}" for _, msg in self.failures)
        super().__init__(f"method {method!r} failed {len({c for c, _ in self.failures})} of {n_checks} "
                         f"conformance checks:\n{lines}")


@dataclass
class ConformanceReport:
    """What ``check_method`` verified: checks passed, per mode, and anything skipped with why."""

    method: str
    modes: tuple[str, ...]
    passed: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)


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


def _tiny_frame(n_segments: int, n: int, first: int, seed: int) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(first, first + n_segments):
        u1 = rng.uniform(-2.0, 2.0, n)
        u2 = np.cumsum(rng.normal(0.0, 0.3, n))
        y = np.empty(n)
        for i in range(n):
            y[i] = 10.0 + np.sin(u1[i]) + 0.5 * u2[i] + (0.2 * (y[i - 1] - 10.0) if i else 0.0) + rng.normal(0, 0.01)
        parts.append(pd.DataFrame({SEGMENT: f"s{k}", TIME: k * (n + 10.0) + np.arange(n, dtype=float),
                                   "u1": u1, "u2": u2, "y": y}))
    return pd.concat(parts, ignore_index=True)


_SCHEMA = Schema((Column("u1", "input", "V"), Column("u2", "input", "bar"), Column("y", "output", "degC")))


def _tiny_datasets(seed: int) -> tuple[Dataset, Dataset]:
    meta = {"provenance": "enginebench.testing (synthetic)", "licence": "CC0"}
    train = Dataset("check-method-train", _tiny_frame(3, 30, 0, seed), _SCHEMA, 1.0, meta)
    test = Dataset("check-method-test", _tiny_frame(2, 25, 3, seed + 1), _SCHEMA, 1.0, meta)
    return train, test


def _samples(ds: Dataset, mode: str, evaluated: bool = False) -> Samples:
    """Samples of ``ds``; evaluated simulation samples carry the ``TINY_INIT``-sample initialisation window."""
    if mode == "simulation":
        init = TINY_INIT if evaluated else 0
        return SamplePool(RawSegments.from_dataset(ds, outputs=["y"]), ["y"], "simulation",
                          physical_model=TinyLinearPM(), init_samples=init).materialize()
    return make_samples(ds, ["y"], mode, TINY_WINDOW if mode == "window" else 0.0, physical_model=TinyLinearPM())


def tiny_samples(mode: str = "static", seed: int = 0) -> tuple[Samples, Samples]:
    """The (training, evaluated) samples ``check_method`` uses, with targets, for ``mode``.

    In simulation mode the evaluated segments start with a ``TINY_INIT``-sample
    initialisation window (``y_init``); training segments are whole.
    """
    if mode not in CHECKED_MODES:
        raise DataError(f"tiny_samples: mode {mode!r} is not checked; use one of {', '.join(CHECKED_MODES)}")
    train, test = _tiny_datasets(seed)
    return _samples(train, mode), _samples(test, mode, evaluated=True)


# -- helpers ------------------------------------------------------------------------------

class _Failed(Exception):
    """A check failed; the message says why (without the check and method names)."""


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".splitlines()[0]


def _call(what: str, fn: Callable[[], Any]) -> Any:
    """Run one step of a check; a method that reads the targets it must predict is reported as such."""
    try:
        return fn()
    except DataError as exc:
        if "carry no targets" in str(exc):
            raise _Failed(f"{what} read the targets of the samples it must predict (data.y), which are "
                          f"removed before predict; use only data.X, data.U and data.t") from exc
        raise _Failed(f"{what} raised {_describe(exc)}") from exc
    except Exception as exc:
        raise _Failed(f"{what} raised {_describe(exc)}") from exc


def _stacked(preds: Any, data: Samples, what: str) -> np.ndarray:
    """Check the per-segment shape contract and return the predictions stacked, (n_rows, n_targets).

    In simulation mode the result must be a ``SegmentPredictions`` with one bool flag per segment.
    """
    k = len(data.target_names)
    if data.mode == "simulation":
        _check_flags(preds, data, what)
    try:
        arrays = list(preds)
    except TypeError:
        raise _Failed(f"{what} returned {type(preds).__name__}, not a list of one array per segment") from None
    if len(arrays) != len(data.segments):
        raise _Failed(f"{what} returned {len(arrays)} arrays for {len(data.segments)} segments; "
                      f"return one (n_rows, n_targets) array per segment")
    for seg, arr in zip(data.segments, arrays):
        shape = np.shape(arr)
        if shape != (len(seg), k):
            raise _Failed(f"{what} returned shape {shape} for segment {seg.id!r}; expected ({len(seg)}, {k}) "
                          f"= (rows of the segment, targets)")
    return np.concatenate([np.asarray(a, dtype=float) for a in arrays]) if arrays else np.empty((0, k))


def _check_flags(preds: Any, data: Samples, what: str) -> np.ndarray:
    """The ``diverged`` flags of a simulating method's predictions: one bool per segment."""
    if not isinstance(preds, SegmentPredictions):
        raise _Failed(f"{what} returned {type(preds).__name__}, not SegmentPredictions; a simulating method returns "
                      f"SegmentPredictions(arrays, diverged=flags) (enginebench.methods.base), one flag per segment")
    flags = np.asarray(preds.diverged)
    if flags.dtype != bool or flags.shape != (len(data.segments),):
        raise _Failed(f"{what} returned diverged flags of dtype {flags.dtype} and shape {flags.shape}; expected one "
                      f"bool per segment, shape ({len(data.segments)},)")
    return flags


def _flags(preds: Any) -> np.ndarray | None:
    return np.asarray(preds.diverged) if isinstance(preds, SegmentPredictions) else None


@dataclass(frozen=True)
class _Run:
    """What every check of one ``check_method`` call shares: the method, the data, the seed, fixed params."""

    method: Method
    train_ds: Dataset
    test_ds: Dataset
    mode: str
    seed: int
    fixed: Mapping[str, Any]

    @property
    def train(self) -> Samples:
        return _samples(self.train_ds, self.mode)

    @property
    def test(self) -> Samples:
        return _samples(self.test_ds, self.mode, evaluated=True)


def _params(run: _Run, train: Samples) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A fit point (the middle of the search grid) and up to three grid points for predict_grid.

    Hyperparameters fixed by ``check_method(..., params=...)`` replace their grid.
    """
    space = _call("search_space", lambda: run.method.search_space(train))
    if not isinstance(space, Mapping):
        raise _Failed(f"search_space returned {type(space).__name__}; return a dict of name -> candidate values")
    values = {name: list(np.asarray(v).reshape(-1)) for name, v in space.items()}
    values.update({name: [value] for name, value in run.fixed.items()})
    grid = grid_points(values)
    if not grid:
        return {}, [{}]
    picks = sorted({0, len(grid) // 2, len(grid) - 1})
    return grid[len(grid) // 2], [grid[i] for i in picks]


def _fit_predict(run: _Run, train: Samples, test: Samples, params: Mapping[str, Any],
                 what: str = "") -> tuple[Any, np.ndarray, np.ndarray | None]:
    """(fitted model, stacked predictions, diverged flags or None) of one fit and predict."""
    fitted = _call(f"fit{what}", lambda: run.method.fit(train, params, np.random.default_rng(run.seed)))
    view = test.without_targets()
    preds = _call(f"predict{what}", lambda: run.method.predict(fitted, view))
    return fitted, _stacked(preds, view, f"predict{what}"), _flags(preds)


def _perturbed(ds: Dataset, mode: str, seed: int) -> Dataset:
    """``ds`` with measured outputs changed where no evaluated row may see them.

    In static mode that is every row; in window mode y(t) is a lagged feature of the
    following rows, so only each segment's last row is changed; in simulation mode every
    row after the initialisation window (the window is what the method may use).
    """
    frame = ds.frame.copy()
    rng = np.random.default_rng(seed + 99)
    if mode == "static":
        rows = np.arange(len(frame))
    elif mode == "window":
        rows = np.flatnonzero(frame[SEGMENT].ne(frame[SEGMENT].shift(-1)).to_numpy())
    else:
        position = frame.groupby(SEGMENT, sort=False).cumcount().to_numpy()
        rows = np.flatnonzero(position >= TINY_INIT)
    frame.loc[rows, "y"] = frame.loc[rows, "y"].to_numpy() + rng.normal(50.0, 10.0, len(rows))
    return replace(ds, frame=frame)


def _bad_outcome(what: str, fn: Callable[[], Any], data: Samples | None) -> None:
    """Bad input must raise an EngineBenchError (e.g. MethodError) or give finite, well-shaped predictions."""
    try:
        preds = fn()
    except EngineBenchError:
        return
    except Exception as exc:
        raise _Failed(f"{what} raised {_describe(exc)}, a bare traceback for the user; check the input and raise "
                      f"enginebench.errors.MethodError saying what is wrong") from exc
    if data is not None:
        values = _stacked(preds, data, what)
        if not np.all(np.isfinite(values)):
            raise _Failed(f"{what} returned non-finite predictions instead of raising MethodError")


def _with_segment(data: Samples, k: int, **changes: Any) -> Samples:
    segs = list(data.segments)
    segs[k] = replace(segs[k], **changes)
    return replace(data, segments=tuple(segs))


# -- the checks -----------------------------------------------------------------------------

def _check_attributes(cls: type) -> None:
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise _Failed(f"{cls!r} is not a subclass of enginebench.methods.base.Method")
    if not isinstance(cls.name, str) or not cls.name:
        raise _Failed("class attribute 'name' is empty; set name = \"my-method\" (the name used in experiments)")
    if cls.family not in FAMILIES:
        raise _Failed(f"family {cls.family!r} is not one of {', '.join(FAMILIES)}")
    modes = cls.modes
    if not isinstance(modes, (set, frozenset)) or not modes or not set(modes) <= set(MODES):
        raise _Failed(f"modes {modes!r} must be a non-empty frozenset of {', '.join(MODES)}")


def _check_options(cls: type[Method], options: Mapping[str, Any]) -> Method:
    defaults = _call("default_options()", cls.default_options)
    if not isinstance(defaults, dict):
        raise _Failed(f"default_options() returned {type(defaults).__name__}; return a dict of option -> default")
    unknown = set(options) - set(defaults)
    if unknown:
        raise _Failed(f"the options given to check_method ({', '.join(sorted(unknown))}) are not in default_options()")
    _call(f"{cls.__name__}() with the default options", lambda: cls())
    method = _call(f"{cls.__name__}(**{dict(options)!r})", lambda: cls(**options))
    missing = set(defaults) - set(getattr(method, "options", {}))
    if missing:
        raise _Failed(f"instance .options lacks {', '.join(sorted(missing))}; call super().__init__(**options)")
    try:
        cls(**{**options, _UNKNOWN_OPTION: 1})
    except EngineBenchError as exc:
        if _UNKNOWN_OPTION not in str(exc):
            raise _Failed(f"an unknown option raised an error that does not name it: {exc}") from None
    except Exception as exc:
        raise _Failed(f"an unknown option raised {_describe(exc)}; raise MethodError naming it "
                      f"(the base __init__ does)") from None
    else:
        raise _Failed(f"the unknown option {_UNKNOWN_OPTION!r} was accepted silently; raise MethodError naming it "
                      f"(call super().__init__(**options))")
    return method


def _check_determinism(run: _Run, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    _, first, flags1 = _fit_predict(run, train, test, params)
    _, second, flags2 = _fit_predict(run, train, test, params, " (second time)")
    if not np.array_equal(first, second, equal_nan=True):
        worst = float(np.nanmax(np.abs(first - second)))
        raise _Failed(f"fit + predict twice with the same seed gave different predictions (largest difference "
                      f"{worst:.3g}); draw random numbers only from the rng argument of fit, never from "
                      f"np.random or an unseeded generator")
    if flags1 is not None and flags2 is not None and not np.array_equal(flags1, flags2):
        raise _Failed("fit + predict twice with the same seed flagged different segments as diverged")


def _check_shapes(run: _Run, train: Samples, test: Samples) -> None:
    params, grid = _params(run, train)
    view = test.without_targets()
    if run.mode == "simulation":
        late = [s.id for s in view.segments if not (len(s.rows) and s.rows[0] == TINY_INIT)]
        if late:  # pragma: no cover - guards the check itself
            raise _Failed(f"internal: evaluated segment {late[0]!r} does not start after the initialisation window")
    _fit_predict(run, train, test, params)  # checks one (len(s.rows), n_targets) array per segment (and flags)
    out = _call("predict_grid", lambda: run.method.predict_grid(train, view, grid, np.random.default_rng(run.seed)))
    expected = (len(grid), len(view), len(view.target_names))
    if np.shape(out) != expected:
        raise _Failed(f"predict_grid over {len(grid)} grid points returned shape {np.shape(out)}; expected "
                      f"{expected} = (grid points, rows, targets)")


def _check_leakage(run: _Run, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    fitted, before, _ = _fit_predict(run, train, test, params)
    changed = _samples(_perturbed(run.test_ds, run.mode, run.seed), run.mode, evaluated=True)
    if np.array_equal(changed.y, test.y):  # pragma: no cover - guards the check itself
        raise _Failed("internal: the perturbed targets equal the original ones")
    view = changed.without_targets()
    after = _stacked(_call("predict on samples with changed targets", lambda: run.method.predict(fitted, view)),
                     view, "predict")
    if not np.array_equal(before, after, equal_nan=True):
        if run.mode == "simulation":
            raise _Failed(f"changing the measured outputs after the initialisation window (the first {TINY_INIT} "
                          f"samples, y_init) changed the predictions: a simulation may use y0 and y_init only, then "
                          f"runs free on the inputs")
        raise _Failed("changing the targets of the evaluated rows (never features) changed the predictions: "
                      "the method reads what it must predict")


def _check_pickle(run: _Run, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    fitted, before, _ = _fit_predict(run, train, test, params)
    try:
        fitted2 = pickle.loads(pickle.dumps(fitted, protocol=pickle.HIGHEST_PROTOCOL))
        method2 = pickle.loads(pickle.dumps(run.method, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception as exc:
        raise _Failed(f"pickling the method or its fitted model failed ({_describe(exc)}); runs ship both to "
                      f"worker processes, so keep them picklable (no lambdas, open files or locks)") from exc
    view = test.without_targets()
    after = _stacked(_call("predict after a pickle round trip", lambda: method2.predict(fitted2, view)), view,
                     "predict after a pickle round trip")
    if not np.array_equal(before, after, equal_nan=True):
        raise _Failed("predictions after pickling and unpickling the fitted model differ from before")


def _check_bad_input(run: _Run, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    method = run.method
    fitted, _, _ = _fit_predict(run, train, test, params)
    view = test.without_targets()
    first = view.segments[0]
    if run.mode == "simulation":
        U = first.U.copy()
        U[first.rows[0], 0] = np.nan  # the first evaluated row's first input
        bad = _with_segment(view, 0, U=U, X=U[first.rows])
        _bad_outcome("predict with a NaN run-time input", lambda: method.predict(fitted, bad), bad)
        y_init = np.array(first.y_init, dtype=float)
        y_init[-1] = np.nan
        bad_init = _with_segment(view, 0, y_init=y_init)
        _bad_outcome("predict with a NaN in the initialisation window (y_init)",
                     lambda: method.predict(fitted, bad_init), bad_init)
        Ut = train.segments[0].U.copy()
        Ut[0, 0] = np.nan
        nan_train = _with_segment(train, 0, U=Ut, X=Ut[train.segments[0].rows])
        _bad_outcome("fit with a NaN run-time input", lambda: method.fit(nan_train, params, np.random.default_rng(run.seed)),
                     None)
        keep = list(range(len(view.input_names) - 1))
        narrow = replace(view, input_names=view.input_names[:-1], feature_names=view.feature_names[:-1],
                         segments=tuple(replace(s, U=s.U[:, keep], X=s.X[:, keep]) for s in view.segments))
        _bad_outcome(f"predict without input {view.input_names[-1]!r} (trained with it)",
                     lambda: method.predict(fitted, narrow), narrow)
        return
    X = first.X.copy()
    X[0, 0] = np.nan
    nan_view = _with_segment(view, 0, X=X)
    _bad_outcome("predict with a NaN feature", lambda: method.predict(fitted, nan_view), nan_view)
    Xt = train.segments[0].X.copy()
    Xt[0, 0] = np.nan
    nan_train = _with_segment(train, 0, X=Xt)
    _bad_outcome("fit with a NaN feature", lambda: method.fit(nan_train, params, np.random.default_rng(run.seed)), None)
    narrow = view.select_features(range(view.X.shape[1] - 1))
    _bad_outcome(f"predict with {narrow.X.shape[1]} feature columns (trained on {view.X.shape[1]})",
                 lambda: method.predict(fitted, narrow), narrow)


def check_method(cls: type[Method], options: Mapping[str, Any] | None = None, *, seed: int = 0,
                 params: Mapping[str, Any] | None = None) -> ConformanceReport:
    """Run every conformance check on ``cls`` (built with ``options``); raise ConformanceError listing failures.

    Each failure message names the check, the method and, where it matters, the mode.
    ``params`` fixes hyperparameters (replacing their search grid) to keep a slow method's
    checks quick, e.g. ``{"epochs": 3}``. Returns a report of what passed, per mode.
    """
    options = dict(options or {})
    label = getattr(cls, "name", None) or getattr(cls, "__name__", repr(cls))
    failures: list[tuple[str, str]] = []
    modes = tuple(m for m in CHECKED_MODES if m in getattr(cls, "modes", ()))
    report = ConformanceReport(method=label, modes=modes)

    def fail(check: str, message: str, mode: str | None = None) -> None:
        where = f" ({mode} mode)" if mode else ""
        failures.append((check, f"[{check}] method {label!r}{where}: {message}"))

    try:
        _check_attributes(cls)
        report.passed.append("attributes")
    except _Failed as exc:
        fail("attributes", str(exc))
        raise ConformanceError(label, failures, len(CHECKS)) from None
    try:
        method = _check_options(cls, options)
        report.passed.append("options")
    except _Failed as exc:
        fail("options", str(exc))
        raise ConformanceError(label, failures, len(CHECKS)) from None
    train_ds, test_ds = _tiny_datasets(seed)
    for mode in modes:
        run = _Run(method, train_ds, test_ds, mode, seed, dict(params or {}))
        train, test = run.train, run.test
        steps: list[tuple[str, Callable[[], None]]] = [
            ("no-target-leakage", lambda: _check_leakage(run, train, test)),
            ("determinism", lambda: _check_determinism(run, train, test)),
            ("shapes", lambda: _check_shapes(run, train, test)),
            ("pickle-round-trip", lambda: _check_pickle(run, train, test)),
            ("bad-input", lambda: _check_bad_input(run, train, test)),
        ]
        for check, step in steps:
            try:
                step()
                report.passed.append(f"{check}[{mode}]")
            except _Failed as exc:
                fail(check, str(exc), mode)
    if failures:
        raise ConformanceError(label, failures, len(CHECKS))
    return report
