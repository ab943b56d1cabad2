"""SINDy with control inputs: sparse polynomial ODEs fitted by pysindy, simulated open loop.

The state is the target(s) and the control is the run-time inputs, both standardised
with training statistics. Derivatives come from a regularised differentiator of the
``derivative`` package (through pysindy's ``SINDyDerivative`` wrapper), computed once
per training set and shared by every grid point. Prediction never calls pysindy's
``simulate`` (one scipy ``solve_ivp`` per segment); it steps every segment at once with
a fixed-step integrator (RK4 or Euler at the data's sample period, inputs held between
samples). A trajectory that goes non-finite or leaves a bounded envelope around the
training range is stopped, held at its last in-envelope value and flagged diverged
(seed 003 reports SINDy blow-ups; they must be counted, never silently dropped).

Thresholds relative to the data (the default, ``threshold_scale = "relative"``). The STLSQ
threshold removes a term of the equation for d(x_k)/dt when its coefficient is smaller
than ``threshold x unit_k`` with ``unit_k = min(rms(dx_k/dt), c_k)``: the root mean square
of that state's fitted derivative over the training data, capped by c_k, the largest
coefficient magnitude of STLSQ's first pass (the ridge fit on the whole library). The
library terms are built from standardised signals (unit standard deviation), so a
relative threshold of 0.1 drops a term when a one-standard-deviation change of it moves
the derivative by less than a tenth of its typical size, whatever the signal's units,
the sample period (1 ms or 10 s) or ``time_scale``; the cap keeps the first pass's largest
term at every threshold below 1, so the default grid does not empty an equation whose
library explains little of its derivative. An absolute threshold instead means "per
``time_scale`` second" and empties the model of a slow system (every coefficient of a
system with time constants of minutes is below 0.01/s). Implemented exactly by dividing
each state's derivative by its unit before STLSQ and multiplying the coefficients back
(every ridge step is linear in the target). The default grid is 0.01 .. 0.5 relative;
``threshold_scale = "absolute"`` restores the seed's absolute thresholds (default grid
1e-2 .. 1e3, per ``time_scale`` second), which the turboshaft experiments pin. With
relative thresholds ``time_scale`` is only the unit of the reported equations. A state
whose every term is still removed (STLSQ's later passes may drop the first pass's
largest term) is named in describe's ``constant_states`` and ``warnings`` (the job's
warnings).

State initialisation: a segment with an initialisation window (``y_init``, N measured
outputs) is simulated from its last sample, row N - 1, so the model starts from the most
recent measured state; without one, from y0 at row 0.
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from dataclasses import dataclass, field, fields
from typing import Any, Iterator, Sequence

import numpy as np
import pysindy as ps
from sklearn.linear_model import ridge_regression

from enginebench.datasets.samples import Samples
from enginebench.declare import Declaration, Field, Invalid, choice, listing, positive, whole
from enginebench.errors import MethodError
from enginebench.methods.base import Method, Params, SearchSpace, SegmentPredictions, log_grid
from enginebench.methods.numerics.derivatives import digest
from enginebench.methods.sindy_library import (  # noqa: F401 (tests and callers import them from here too)
    DERIVATIVE_KINDS, DERIVATIVE_SOLVERS, INTEGRATORS, differentiate, library_features, raw_coefficients, simulate_batch,
)

DEFAULT_DERIVATIVE_ALPHA = {"trend_filtered": 1e-3, "kalman": 1.0}
DEFAULT_PARAMS = {"degree": 2, "threshold": 0.1, "alpha": 0.05}
THRESHOLD_SCALES = ("relative", "absolute")
DEFAULT_THRESHOLD_RANGE = {"relative": (1e-2, 0.5), "absolute": (1e-2, 1e3)}
"""Default STLSQ threshold grids: relative to each derivative's rms, or seed 003's absolute range."""
MIN_ROWS = 4
_PREPARE_OPTIONS = ("derivative", "derivative_solver", "derivative_chunk", "derivative_margin", "derivative_max_iter",
                    "time_scale", "envelope")
"""The options ``SINDy._prepare``'s result depends on (with ``derivative_alpha``): its cache key."""
PREPARED_CACHE_SIZE = 2
"""Prepared training sets ``SINDy._prepare`` keeps per process (least recently used dropped first)."""
_prepared: "OrderedDict[bytes, _Prepared]" = OrderedDict()


def _ordered(value: Any) -> Any:
    if len(value) != 2 or not value[0] <= value[1]:
        raise Invalid("{name} must be (low, high) with 0 < low <= high, got {value}")
    return value


def _degrees(value: Any) -> Any:
    for d in value:
        if not (float(d).is_integer() and 1 <= d <= 5):
            raise Invalid("{name}: polynomial degree must be an integer from 1 to 5, got " + repr(d))
    return value


def span(name: str, default: Any, meaning: str, **kw: Any) -> Field:
    """A (low, high) pair with 0 < low <= high."""
    return listing(name, default, meaning, items="float", low=0, low_open=True, check=_ordered,
                   message="{name} must be (low, high) with 0 < low <= high, got {value}", type_label="(low, high)"
                   + (" | None" if kw.get("nullable") else ""), **kw)
"""A training segment needs at least this many rows to be differentiated."""


@dataclass(kw_only=True)
class Scaling:
    """The training standardisation of states and controls, and the envelope of the standardised state.

    Shared by the grid-independent preparation (``_Prepared``) and the fit it becomes
    (``SINDyFit``); keyword-only, so the subclasses keep their own fields' positions.
    """

    state_mean: np.ndarray
    state_std: np.ndarray
    control_mean: np.ndarray
    control_std: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def scaling(self) -> dict[str, np.ndarray]:
        """These fields by name (to hand them on to another ``Scaling``)."""
        return {f.name: getattr(self, f.name) for f in fields(Scaling)}


@dataclass
class SINDyFit(Scaling):
    """A fitted SINDy model and everything needed to simulate and explain it.

    All coefficients act on standardised signals, ``(v - mean) / std``, with time in
    units of ``time_scale`` seconds. ``powers`` (n_terms, n_states + n_controls) gives
    the exponent of each signal in each library term (states first, then controls).
    ``lower``/``upper`` bound the standardised state: leaving them is divergence.
    """

    model: Any
    coef: np.ndarray
    powers: np.ndarray
    time_scale: float
    params: dict[str, Any]
    state_names: tuple[str, ...]
    control_names: tuple[str, ...]
    derivative: str
    derivative_alpha: float
    notes: list[str] = field(default_factory=list)
    threshold_scale: str = "absolute"
    derivative_rms: np.ndarray | None = None
    """Root mean square of each state's standardised derivative."""
    threshold_unit: np.ndarray | None = None
    """What the threshold multiplied, per equation: 1 (absolute) or ``threshold_unit(...)`` (relative)."""

    @property
    def n_states(self) -> int:
        return self.coef.shape[0]


@dataclass
class _Prepared(Scaling):
    """Standardised training trajectories and their derivatives (grid-independent)."""

    x: list[np.ndarray]
    u: list[np.ndarray] | None
    t: list[np.ndarray]
    x_dot: list[np.ndarray]
    notes: list[str]
    derivative_rms: np.ndarray


def threshold_unit(prep: "_Prepared", degree: int, alpha: float) -> np.ndarray:
    """Per equation, what a relative threshold multiplies: min(rms of dx_k/dt, largest first-pass coefficient).

    The first pass is STLSQ's own first step, the ridge fit (``alpha``) of dx_k/dt on the
    whole degree-``degree`` library. Capping the unit there keeps that pass's largest term
    for every threshold below 1, so a relative grid below 1 does not empty an equation
    whose library explains little of its derivative (the rms alone would).
    """
    z = [x if u is None else np.hstack([x, u]) for x, u in zip(prep.x, prep.u or [None] * len(prep.x))]
    z = np.vstack(z)
    powers = ps.PolynomialLibrary(degree=int(degree)).fit(z[:1]).powers_
    theta = library_features(z, np.asarray(powers, dtype=np.int64))
    first = ridge_regression(theta, np.concatenate(prep.x_dot), float(alpha))
    largest = np.abs(np.atleast_2d(first)).max(axis=1)
    rms = prep.derivative_rms
    return np.where(np.isfinite(largest) & (largest > 0), np.minimum(rms, largest), rms)


def initial_state(segment: Any) -> tuple[int, np.ndarray | None]:
    """(row, measured output) a simulation of ``segment`` starts from: the init window's last sample, else y0.

    A window whose last row is not before the segment's first evaluated row (an
    inconsistent view) is ignored in favour of y0 at row 0.
    """
    y_init = getattr(segment, "y_init", None)
    rows = np.asarray(segment.rows)
    if y_init is not None and len(y_init) and (not rows.size or rows.min() >= len(y_init) - 1):
        return len(y_init) - 1, np.asarray(y_init[-1], dtype=np.float64)
    return 0, None if segment.y0 is None else np.asarray(segment.y0, dtype=np.float64)


def constant_state_warnings(fitted: "SINDyFit") -> list[str]:
    """One line per state whose every term was thresholded away (the job's warnings)."""
    return [
        f"every term of d({n})/dt was thresholded away (threshold {fitted.params['threshold']:g}, "
        f"{fitted.threshold_scale}): {n} is simulated as its initial value held, a flat line; lower the threshold"
        for n, row in zip(fitted.state_names, fitted.coef) if not np.any(row)
    ]


def _format_terms(coef_row: np.ndarray, names: Sequence[str], digits: int = 4) -> str:
    terms = [f"{c:+.{digits}g} {n}" if n != "1" else f"{c:+.{digits}g}" for c, n in zip(coef_row, names) if c != 0]
    return " ".join(terms) if terms else "0"


# --------------------------------------------------------------------------- method
class SINDy(Method):
    """Sparse identification of nonlinear dynamics with control (seed 003's benchmark)."""

    name = "sindy"
    family = "data-driven"
    modes = frozenset({"simulation"})
    summary = "pysindy polynomial ODE with control inputs, STLSQ, batched open-loop simulation"

    declared_options = Declaration(
        listing("degrees", (1, 2, 3), "polynomial degrees of the library searched", items="float", searches=("degree",),
                edges="high", check=_degrees),
        choice("threshold_scale", "relative", "STLSQ thresholds relative to the rms of each state's derivative, or "
               "absolute (per time_scale second, the seed's)", THRESHOLD_SCALES),
        span("threshold_range", None, "STLSQ thresholds searched (log grid); None = (0.01, 0.5) relative or "
             "(1e-2, 1e3) absolute", nullable=True, searches=("threshold",)),
        whole("n_thresholds", 4, "thresholds on the grid", low=1),
        span("alpha_range", (1e-4, 1e-1), "ridge alphas of STLSQ searched (log grid)", searches=("alpha",)),
        whole("n_alphas", 3, "alphas on the grid", low=1),
        choice("derivative", "trend_filtered", "how state derivatives are estimated from the samples",
               DERIVATIVE_KINDS),
        positive("derivative_alpha", None, "smoothing weight of the derivative estimate; None = 1e-3 "
                 "(trend_filtered) or 1.0 (kalman)", nullable=True),
        whole("derivative_chunk", 256, "samples per chunk of the trend-filtered derivative", low=1, unit="samples"),
        whole("derivative_margin", 32, "overlap between derivative chunks", low=0, unit="samples"),
        choice("derivative_solver", "admm", "trend_filtered's solver: batched ADMM checked for optimality, or the "
               "derivative package's Lasso (stops at derivative_max_iter short of the optimum; earlier results)",
               DERIVATIVE_SOLVERS),
        whole("derivative_max_iter", 20000, "iteration cap of the trend-filtered derivative's solver", low=1),
        positive("time_scale", 1.0, "time unit of the identified ODE (the derivative is per time_scale seconds)",
                 unit="s"),
        choice("integrator", "rk4", "open-loop simulation's integration scheme", INTEGRATORS),
        whole("substeps", 1, "integration steps per sample period", low=1),
        positive("envelope", 10.0, "divergence: a state leaving [min - e span, max + e span] of the training "
                 "outputs"),
    )

    @staticmethod
    def _check_degree(d: Any, where: str) -> int:
        numeric = isinstance(d, (int, np.integer, float, np.floating)) and not isinstance(d, (bool, np.bool_))
        if not (numeric and float(d).is_integer() and 1 <= d <= 5):
            raise MethodError(f"sindy: {where}: polynomial degree must be an integer from 1 to 5, got {d!r}")
        return int(d)

    @property
    def threshold_range(self) -> tuple[float, float]:
        """The threshold grid's (low, high): the option, or the default of the threshold scale."""
        r = self.options["threshold_range"]
        return DEFAULT_THRESHOLD_RANGE[self.options["threshold_scale"]] if r is None else (float(r[0]), float(r[1]))

    @property
    def derivative_alpha(self) -> float:
        a = self.options["derivative_alpha"]
        return float(DEFAULT_DERIVATIVE_ALPHA[self.options["derivative"]] if a is None else a)

    # -- protocol ----------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        """Degree x STLSQ threshold (log grid, relative by default) x ridge alpha (log grid)."""
        o = self.options
        return {
            "degree": np.array([int(d) for d in o["degrees"]]),
            "threshold": log_grid(*np.log10(self.threshold_range), o["n_thresholds"]),
            "alpha": log_grid(*np.log10(o["alpha_range"]), o["n_alphas"]),
        }

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> SINDyFit:
        """Fit on all training segments at once. Deterministic: ``rng`` is not drawn from."""
        return self._fit_prepared(self._prepare(train), train, params)

    def predict(self, fitted: SINDyFit, data: Samples) -> SegmentPredictions:
        """Open-loop trajectories from each segment's last measured initial output, all segments batched.

        The start is the last row of the initialisation window (``y_init[-1]`` at row N - 1)
        when the segment has one, else y0 at row 0; no measured output after it is read.
        """
        self.check_mode(data.mode)
        self._check_signals(fitted, data)
        if not data.segments:
            return SegmentPredictions([], [])
        x0, controls, times, starts = [], [], [], []
        for s in data.segments:
            start, y_start = initial_state(s)
            if y_start is None or not np.all(np.isfinite(y_start)):
                where = "y0" if start == 0 else f"y_init (row {start})"
                raise MethodError(
                    f"sindy: segment {s.id!r} has no finite initial output {where}; simulation starts from the "
                    "measured outputs of the segment's first row or initialisation window"
                )
            starts.append(start)
            x0.append((np.asarray(y_start, dtype=np.float64).reshape(-1) - fitted.state_mean) / fitted.state_std)
            controls.append((s.U[start:] - fitted.control_mean) / fitted.control_std)
            times.append(s.t[start:] / fitted.time_scale)
        trajs, diverged = simulate_batch(
            fitted.coef, fitted.powers, np.vstack(x0), controls, times, fitted.lower, fitted.upper,
            integrator=self.options["integrator"], substeps=int(self.options["substeps"]),
        )
        arrays = [(tr * fitted.state_std + fitted.state_mean)[np.asarray(s.rows) - a]
                  for tr, s, a in zip(trajs, data.segments, starts)]
        return SegmentPredictions(arrays, diverged)

    def fit_grid(
        self, train: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> Iterator[tuple[int, SINDyFit]]:
        """Every grid point shares one standardisation and one differentiation of the training data."""
        prepared = self._prepare(train)
        for i, params in enumerate(grid):
            yield i, self._fit_prepared(prepared, train, params)

    def describe(self, fitted: SINDyFit) -> dict[str, Any]:
        """Equations (standardised and in raw units), term count and the selected parameters."""
        names = fitted.model.get_feature_names()
        raw = raw_coefficients(fitted)
        raw_names = ps.PolynomialLibrary(degree=fitted.params["degree"]).fit(
            np.zeros((1, fitted.powers.shape[1]))
        ).get_feature_names(list(fitted.state_names) + list(fitted.control_names))
        lhs = [f"d({n})/dt" for n in fitted.state_names]
        return {
            "equations": [f"{l} = {eq}" for l, eq in zip(lhs, fitted.model.equations(precision=4))],
            "equations_units": "standardised signals (z-scores with training mean/std); time in units of "
            f"{fitted.time_scale:g} s",
            "equations_raw": [f"{l} = {_format_terms(row, raw_names)}" for l, row in zip(lhs, raw)],
            "term_count": int(np.count_nonzero(fitted.coef)),
            "terms_per_equation": [int(c) for c in np.count_nonzero(fitted.coef, axis=1)],
            # states whose equation lost every term: dx/dt = 0, simulated as their initial value held
            "constant_states": [n for n, row in zip(fitted.state_names, fitted.coef) if not np.any(row)],
            "library_size": int(fitted.powers.shape[0]),
            "degree": int(fitted.params["degree"]),
            "threshold": float(fitted.params["threshold"]),
            "threshold_scale": fitted.threshold_scale,
            # the threshold each equation was cut at, in standardised units per time_scale second
            "threshold_per_equation": (float(fitted.params["threshold"]) * (
                np.ones(fitted.n_states) if fitted.threshold_unit is None else fitted.threshold_unit)).tolist(),
            "derivative_rms": None if fitted.derivative_rms is None else fitted.derivative_rms.tolist(),
            "alpha": float(fitted.params["alpha"]),
            "feature_names": list(names),
            "coefficients": fitted.coef.tolist(),
            "state": list(fitted.state_names),
            "controls": list(fitted.control_names),
            "standardisation": {
                "state_mean": fitted.state_mean.tolist(), "state_std": fitted.state_std.tolist(),
                "control_mean": fitted.control_mean.tolist(), "control_std": fitted.control_std.tolist(),
            },
            "envelope": {"lower": (fitted.lower * fitted.state_std + fitted.state_mean).tolist(),
                         "upper": (fitted.upper * fitted.state_std + fitted.state_mean).tolist()},
            "derivative": fitted.derivative,
            "derivative_alpha": fitted.derivative_alpha,
            "notes": list(fitted.notes),
            "warnings": constant_state_warnings(fitted),
        }

    # -- internals ---------------------------------------------------------------
    def _check_signals(self, fitted: SINDyFit, data: Samples) -> None:
        if tuple(data.target_names) != fitted.state_names or tuple(data.input_names) != fitted.control_names:
            raise MethodError(
                f"sindy: model was fitted for targets {list(fitted.state_names)} with inputs "
                f"{list(fitted.control_names)}, but the data has targets {list(data.target_names)} with inputs "
                f"{list(data.input_names)}; predict with samples built for the same columns"
            )

    def _params(self, params: Params) -> dict[str, Any]:
        unknown = set(params) - set(DEFAULT_PARAMS)
        if unknown:
            raise MethodError(
                f"sindy: unknown parameter(s) {', '.join(sorted(unknown))}; known: {', '.join(DEFAULT_PARAMS)}"
            )
        p = {**DEFAULT_PARAMS, **params}
        p["degree"] = self._check_degree(p["degree"], "parameter degree")
        for key in ("threshold", "alpha"):
            if not (np.isfinite(p[key]) and p[key] >= 0):
                raise MethodError(f"sindy: parameter {key} must be a finite number >= 0, got {p[key]!r}")
            p[key] = float(p[key])
        return p

    def _prepare(self, train: Samples) -> _Prepared:
        """Standardise the training segments and differentiate each one, once per process for the same
        training data and settings: a job's final fit reuses what its grid search prepared (the
        total-variation derivatives of full-size training data take minutes). The kept arrays
        are read-only, so no fit can change what a later one reads."""
        self.check_mode(train.mode)
        if not train.has_targets:
            raise MethodError("sindy: training samples carry no targets")
        key = digest(
            [a for s in train.segments for a in (s.y, s.U, s.t, np.asarray(s.rows, dtype=np.float64))],
            (tuple(train.target_names), tuple(train.input_names), [len(s.rows) for s in train.segments],
             [s.id for s in train.segments], sorted((k, repr(self.options[k])) for k in _PREPARE_OPTIONS),
             self.derivative_alpha),
        )
        if key in _prepared:
            _prepared.move_to_end(key)
            return _prepared[key]
        prep = self._prepare_uncached(train)
        for a in (*prep.x, *(prep.u or []), *prep.t, *prep.x_dot):
            a.flags.writeable = False
        _prepared[key] = prep
        while len(_prepared) > PREPARED_CACHE_SIZE:
            _prepared.popitem(last=False)
        return prep

    def _prepare_uncached(self, train: Samples) -> _Prepared:
        notes: list[str] = []
        segs = []
        for s in train.segments:
            rows = np.asarray(s.rows)
            if rows.size and np.any(np.diff(rows) != 1):
                raise MethodError(
                    f"sindy: training segment {s.id!r} is not a contiguous run of rows (resampled rows?); "
                    "SINDy differentiates trajectories, so resample whole segments (block/segment bootstrap)"
                )
            if len(s) < MIN_ROWS:
                notes.append(f"training segment {s.id!r} skipped: {len(s)} rows, fewer than {MIN_ROWS}")
                continue
            segs.append((s, rows))
        if not segs:
            raise MethodError(f"sindy: no training segment has at least {MIN_ROWS} rows; nothing to differentiate")
        y_all = np.concatenate([s.y for s, _ in segs])
        u_all = np.concatenate([s.U[rows] for s, rows in segs])
        x_mean, x_std = y_all.mean(axis=0), y_all.std(axis=0)
        u_mean, u_std = u_all.mean(axis=0), u_all.std(axis=0)
        for names, std, role in ((train.target_names, x_std, "target"), (train.input_names, u_std, "input")):
            flat = [n for n, sd in zip(names, std) if not sd > 0]
            if flat:
                raise MethodError(
                    f"sindy: {role} column(s) {', '.join(flat)} constant over the training data; they cannot be "
                    "standardised; drop them from the experiment's inputs/targets"
                )
        ts = float(self.options["time_scale"])
        xs, us, tt, xd = [], [], [], []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for s, rows in segs:
                t = np.asarray(s.t, dtype=np.float64)[rows]
                steps = np.diff(t)
                dt = steps[0]
                if not (dt > 0 and np.allclose(steps, dt, rtol=1e-6, atol=0)):
                    bad = int(np.flatnonzero(~np.isclose(steps, dt, rtol=1e-6, atol=0) | (steps <= 0))[0]) + 1
                    raise MethodError(
                        f"sindy: training segment {s.id!r}: time is not uniformly sampled at row {bad} "
                        f"(step {steps[bad - 1]:g} s, expected {dt:g} s); split the segment at gaps"
                    )
                x = (s.y - x_mean) / x_std
                xs.append(x)
                us.append((s.U[rows] - u_mean) / u_std)
                tt.append(t / ts)
                xd.append(differentiate(
                    x, dt / ts, kind=self.options["derivative"], alpha=self.derivative_alpha,
                    chunk=int(self.options["derivative_chunk"]), margin=int(self.options["derivative_margin"]),
                    max_iter=int(self.options["derivative_max_iter"]), solver=self.options["derivative_solver"],
                ))
        xd_all = np.concatenate(xd)
        rms = np.sqrt(np.mean(xd_all ** 2, axis=0))
        n_conv = sum("converge" in str(w.message) for w in caught)
        if n_conv:
            notes.append(f"differentiation: {n_conv} chunk(s) did not fully converge (derivative_max_iter)")
        span = y_all.max(axis=0) - y_all.min(axis=0)
        env = float(self.options["envelope"])
        lower = (y_all.min(axis=0) - env * span - x_mean) / x_std
        upper = (y_all.max(axis=0) + env * span - x_mean) / x_std
        return _Prepared(
            x=xs, u=us if len(train.input_names) else None, t=tt, x_dot=xd, state_mean=x_mean, state_std=x_std,
            control_mean=u_mean, control_std=u_std, lower=lower, upper=upper, notes=notes,
            derivative_rms=np.where(np.isfinite(rms) & (rms > 0), rms, 1.0),
        )

    def _fit_prepared(self, prep: _Prepared, train: Samples, params: Params) -> SINDyFit:
        p = self._params(params)
        model = ps.SINDy(
            optimizer=ps.STLSQ(threshold=p["threshold"], alpha=p["alpha"]),
            feature_library=ps.PolynomialLibrary(degree=p["degree"]),
        )
        names = list(train.target_names) + list(train.input_names)
        notes = list(prep.notes)
        relative = self.options["threshold_scale"] == "relative"
        # relative: STLSQ on each derivative over its unit, so one threshold cuts equation k at threshold x unit_k
        unit = threshold_unit(prep, p["degree"], p["alpha"]) if relative else np.ones_like(prep.derivative_rms)
        x_dot = [xd / unit for xd in prep.x_dot] if relative else prep.x_dot
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.fit(prep.x, t=prep.t, x_dot=x_dot, u=prep.u, feature_names=names)
        notes += sorted({str(w.message) for w in caught})
        if relative:
            model.optimizer.coef_ = np.asarray(model.optimizer.coef_, dtype=np.float64) * unit[:, None]
        coef = np.array(model.coefficients(), dtype=np.float64)
        powers = np.asarray(model.feature_library.powers_, dtype=np.int64)
        empty = [n for n, row in zip(train.target_names, coef) if not np.any(row)]
        if empty:
            notes.append(
                f"every term of d({', '.join(empty)})/dt was thresholded away (threshold {p['threshold']:g}, "
                f"{self.options['threshold_scale']}): the model is "
                "dx/dt = 0, so each prediction is the segment's initial value held constant (a flat line that is "
                "not a divergence); lower the threshold for a model with terms"
            )
        return SINDyFit(
            model=model, coef=coef, powers=powers, **prep.scaling(),
            time_scale=float(self.options["time_scale"]), params=p, state_names=tuple(train.target_names),
            control_names=tuple(train.input_names), derivative=self.options["derivative"],
            derivative_alpha=self.derivative_alpha, notes=notes, threshold_scale=self.options["threshold_scale"],
            derivative_rms=prep.derivative_rms, threshold_unit=unit,
        )
