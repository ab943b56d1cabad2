"""The conformance checks one by one, and how they call a method and read what it returns.

Each ``check_*`` function tests one property the runner relies on (attributes, options,
determinism, shapes, no target leakage, a pickle round trip, bad input) and raises
``CheckFailed`` with a message saying why, without the check's and method's names;
``testing.check_method`` runs them per mode, names them and collects the failures into a
``ConformanceError``. The helpers guard every call of the method (``_call``) and check
the per-segment shape contract of its predictions (``_stacked``). Kept apart from the
suite's entry point so that each check can be read on its own.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass, replace
from typing import Any, Callable, Mapping

import numpy as np

from enginebench.datasets.dataset import SEGMENT, Dataset
from enginebench.errors import DataError, EngineBenchError
from enginebench.method import FAMILIES, Method, SegmentPredictions, grid_points
from enginebench.samples import MODES, Samples
from enginebench.testing_data import TINY_INIT, samples_of

UNKNOWN_OPTION = "no_such_option_for_check_method"


class CheckFailed(Exception):
    """A check failed; the message says why (without the check and method names)."""


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".splitlines()[0]


def _call(what: str, fn: Callable[[], Any]) -> Any:
    """Run one step of a check; a method that reads the targets it must predict is reported as such."""
    try:
        return fn()
    except DataError as exc:
        if "carry no targets" in str(exc):
            raise CheckFailed(f"{what} read the targets of the samples it must predict (data.y), which are "
                              f"removed before predict; use only data.X, data.U and data.t") from exc
        raise CheckFailed(f"{what} raised {_describe(exc)}") from exc
    except Exception as exc:
        raise CheckFailed(f"{what} raised {_describe(exc)}") from exc


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
        raise CheckFailed(f"{what} returned {type(preds).__name__}, not a list of one array per segment") from None
    if len(arrays) != len(data.segments):
        raise CheckFailed(f"{what} returned {len(arrays)} arrays for {len(data.segments)} segments; "
                          f"return one (n_rows, n_targets) array per segment")
    for seg, arr in zip(data.segments, arrays):
        shape = np.shape(arr)
        if shape != (len(seg), k):
            raise CheckFailed(f"{what} returned shape {shape} for segment {seg.id!r}; expected ({len(seg)}, {k}) "
                              f"= (rows of the segment, targets)")
    return np.concatenate([np.asarray(a, dtype=float) for a in arrays]) if arrays else np.empty((0, k))


def _check_flags(preds: Any, data: Samples, what: str) -> np.ndarray:
    """The ``diverged`` flags of a simulating method's predictions: one bool per segment."""
    if not isinstance(preds, SegmentPredictions):
        raise CheckFailed(f"{what} returned {type(preds).__name__}, not SegmentPredictions; a simulating method returns "
                          f"SegmentPredictions(arrays, diverged=flags) (enginebench.method), one flag per segment")
    flags = np.asarray(preds.diverged)
    if flags.dtype != bool or flags.shape != (len(data.segments),):
        raise CheckFailed(f"{what} returned diverged flags of dtype {flags.dtype} and shape {flags.shape}; expected one "
                          f"bool per segment, shape ({len(data.segments)},)")
    return flags


def _flags(preds: Any) -> np.ndarray | None:
    return np.asarray(preds.diverged) if isinstance(preds, SegmentPredictions) else None


@dataclass(frozen=True)
class CheckRun:
    """What every check of one ``check_method`` call shares: the method, the data, the seed, fixed params."""

    method: Method
    train_ds: Dataset
    test_ds: Dataset
    mode: str
    seed: int
    fixed: Mapping[str, Any]

    @property
    def train(self) -> Samples:
        return samples_of(self.train_ds, self.mode)

    @property
    def test(self) -> Samples:
        return samples_of(self.test_ds, self.mode, evaluated=True)


def _params(run: CheckRun, train: Samples) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A fit point (the middle of the search grid) and up to three grid points for predict_grid.

    Hyperparameters fixed by ``check_method(..., params=...)`` replace their grid.
    """
    space = _call("search_space", lambda: run.method.search_space(train))
    if not isinstance(space, Mapping):
        raise CheckFailed(f"search_space returned {type(space).__name__}; return a dict of name -> candidate values")
    values = {name: list(np.asarray(v).reshape(-1)) for name, v in space.items()}
    values.update({name: [value] for name, value in run.fixed.items()})
    grid = grid_points(values)
    if not grid:
        return {}, [{}]
    picks = sorted({0, len(grid) // 2, len(grid) - 1})
    return grid[len(grid) // 2], [grid[i] for i in picks]


def _fit_predict(run: CheckRun, train: Samples, test: Samples, params: Mapping[str, Any],
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
        raise CheckFailed(f"{what} raised {_describe(exc)}, a bare traceback for the user; check the input and raise "
                          f"enginebench.errors.MethodError saying what is wrong") from exc
    if data is not None:
        values = _stacked(preds, data, what)
        if not np.all(np.isfinite(values)):
            raise CheckFailed(f"{what} returned non-finite predictions instead of raising MethodError")


def _with_segment(data: Samples, k: int, **changes: Any) -> Samples:
    segs = list(data.segments)
    segs[k] = replace(segs[k], **changes)
    return replace(data, segments=tuple(segs))


# -- the checks -----------------------------------------------------------------------------

def check_attributes(cls: type) -> None:
    if not (isinstance(cls, type) and issubclass(cls, Method)):
        raise CheckFailed(f"{cls!r} is not a subclass of enginebench.method.Method")
    if not isinstance(cls.name, str) or not cls.name:
        raise CheckFailed("class attribute 'name' is empty; set name = \"my-method\" (the name used in experiments)")
    if cls.family not in FAMILIES:
        raise CheckFailed(f"family {cls.family!r} is not one of {', '.join(FAMILIES)}")
    modes = cls.modes
    if not isinstance(modes, (set, frozenset)) or not modes or not set(modes) <= set(MODES):
        raise CheckFailed(f"modes {modes!r} must be a non-empty frozenset of {', '.join(MODES)}")


def check_options(cls: type[Method], options: Mapping[str, Any]) -> Method:
    defaults = _call("default_options()", cls.default_options)
    if not isinstance(defaults, dict):
        raise CheckFailed(f"default_options() returned {type(defaults).__name__}; return a dict of option -> default")
    unknown = set(options) - set(defaults)
    if unknown:
        raise CheckFailed(f"the options given to check_method ({', '.join(sorted(unknown))}) are not in default_options()")
    _call(f"{cls.__name__}() with the default options", lambda: cls())
    method = _call(f"{cls.__name__}(**{dict(options)!r})", lambda: cls(**options))
    missing = set(defaults) - set(getattr(method, "options", {}))
    if missing:
        raise CheckFailed(f"instance .options lacks {', '.join(sorted(missing))}; call super().__init__(**options)")
    try:
        cls(**{**options, UNKNOWN_OPTION: 1})
    except EngineBenchError as exc:
        if UNKNOWN_OPTION not in str(exc):
            raise CheckFailed(f"an unknown option raised an error that does not name it: {exc}") from None
    except Exception as exc:
        raise CheckFailed(f"an unknown option raised {_describe(exc)}; raise MethodError naming it "
                          f"(the base __init__ does)") from None
    else:
        raise CheckFailed(f"the unknown option {UNKNOWN_OPTION!r} was accepted silently; raise MethodError naming it "
                          f"(call super().__init__(**options))")
    return method


def check_determinism(run: CheckRun, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    _, first, flags1 = _fit_predict(run, train, test, params)
    _, second, flags2 = _fit_predict(run, train, test, params, " (second time)")
    if not np.array_equal(first, second, equal_nan=True):
        worst = float(np.nanmax(np.abs(first - second)))
        raise CheckFailed(f"fit + predict twice with the same seed gave different predictions (largest difference "
                          f"{worst:.3g}); draw random numbers only from the rng argument of fit, never from "
                          f"np.random or an unseeded generator")
    if flags1 is not None and flags2 is not None and not np.array_equal(flags1, flags2):
        raise CheckFailed("fit + predict twice with the same seed flagged different segments as diverged")


def check_shapes(run: CheckRun, train: Samples, test: Samples) -> None:
    params, grid = _params(run, train)
    view = test.without_targets()
    if run.mode == "simulation":
        late = [s.id for s in view.segments if not (len(s.rows) and s.rows[0] == TINY_INIT)]
        if late:  # pragma: no cover - guards the check itself
            raise CheckFailed(f"internal: evaluated segment {late[0]!r} does not start after the initialisation window")
    fitted, preds, _ = _fit_predict(run, train, test, params)  # one (len(s.rows), n_targets) array per segment
    if not getattr(run.method, "uses_features", True):  # the toolkit then builds no features: X has no columns
        bare = replace(view, segments=tuple(replace(s, X=np.empty((len(s.rows), 0))) for s in view.segments))
        got = _stacked(_call("predict with no feature columns (uses_features = False)",
                             lambda: run.method.predict(fitted, bare)), bare, "predict")
        if not np.array_equal(got, preds, equal_nan=True):
            raise CheckFailed("uses_features = False, but predict gives other predictions when data.X has no columns: "
                              "a method that reads data.X must keep uses_features = True")
    out = _call("predict_grid", lambda: run.method.predict_grid(train, view, grid, np.random.default_rng(run.seed)))
    expected = (len(grid), len(view), len(view.target_names))
    if np.shape(out) != expected:
        raise CheckFailed(f"predict_grid over {len(grid)} grid points returned shape {np.shape(out)}; expected "
                          f"{expected} = (grid points, rows, targets)")


def check_leakage(run: CheckRun, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    fitted, before, _ = _fit_predict(run, train, test, params)
    changed = samples_of(_perturbed(run.test_ds, run.mode, run.seed), run.mode, evaluated=True)
    if np.array_equal(changed.y, test.y):  # pragma: no cover - guards the check itself
        raise CheckFailed("internal: the perturbed targets equal the original ones")
    view = changed.without_targets()
    after = _stacked(_call("predict on samples with changed targets", lambda: run.method.predict(fitted, view)),
                     view, "predict")
    if not np.array_equal(before, after, equal_nan=True):
        if run.mode == "simulation":
            raise CheckFailed(f"changing the measured outputs after the initialisation window (the first {TINY_INIT} "
                              f"samples, y_init) changed the predictions: a simulation may use y0 and y_init only, then "
                              f"runs free on the inputs")
        raise CheckFailed("changing the targets of the evaluated rows (never features) changed the predictions: "
                          "the method reads what it must predict")


def check_pickle(run: CheckRun, train: Samples, test: Samples) -> None:
    params, _ = _params(run, train)
    fitted, before, _ = _fit_predict(run, train, test, params)
    try:
        fitted2 = pickle.loads(pickle.dumps(fitted, protocol=pickle.HIGHEST_PROTOCOL))
        method2 = pickle.loads(pickle.dumps(run.method, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception as exc:
        raise CheckFailed(f"pickling the method or its fitted model failed ({_describe(exc)}); runs ship both to "
                          f"worker processes, so keep them picklable (no lambdas, open files or locks)") from exc
    view = test.without_targets()
    after = _stacked(_call("predict after a pickle round trip", lambda: method2.predict(fitted2, view)), view,
                     "predict after a pickle round trip")
    if not np.array_equal(before, after, equal_nan=True):
        raise CheckFailed("predictions after pickling and unpickling the fitted model differ from before")


def check_bad_input(run: CheckRun, train: Samples, test: Samples) -> None:
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
