"""SINDy with control inputs: sparse polynomial ODEs (pysindy's library, STLSQ), simulated open loop.

The state is the target(s) (order 1) or the targets and their time derivatives (order 2:
d2y/dt2 = Theta(y, y', u) xi, which can oscillate; d(y)/dt = y' is kinematic), the
control is the run-time inputs, all standardised with training statistics; ``orders``
searches both by default and selection keeps the order whose free run is better.
Derivatives come from a regularised differentiator of the ``derivative`` package, by
default on each segment standardised by itself (``derivative_scale = "segment"``), so a
record shared by the k-fold training sets and the final fit is differentiated once per
process; the standardised set is prepared once per training set and shared by every grid
point. STLSQ runs on the library's Gram matrix, formed once per order and degree
(``stlsq = "gram"``; ``"pysindy"`` fits every point on the samples). Prediction never calls
pysindy's ``simulate`` (one scipy ``solve_ivp`` per segment); every model of the grid and
every segment are stepped together (``sindy_grid.simulate_candidates``) by a fixed-step
integrator (RK4 or Euler at the data's sample period, inputs held between samples). A trajectory that goes non-finite or leaves a bounded envelope around the
training range is stopped, held at its last in-envelope value and flagged diverged
(the turboshaft-moe paper reports SINDy blow-ups; they must be counted, never silently dropped).

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
``threshold_scale = "absolute"`` restores the turboshaft-moe paper's absolute thresholds (default grid
1e-2 .. 1e3, per ``time_scale`` second), which the turboshaft experiments pin. With
relative thresholds ``time_scale`` is only the unit of the reported equations. A state
whose every term is still removed (STLSQ's later passes may drop the first pass's
largest term) is named in describe's ``constant_states`` and ``warnings`` (the job's
warnings).

State initialisation: a segment with an initialisation window (``y_init``, N measured
outputs) is simulated from its last sample, row N - 1, so the model starts from the most
recent measured state; without one, from y0 at row 0. A second-order model also needs
dy/dt there: the window's derivative at its last sample, by the training differentiator
(a window of 2 samples: their difference; y0 alone: 0, a start at rest).
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from dataclasses import dataclass, field, fields
from typing import Any, Iterator, Sequence

import numpy as np

from enginebench.declare import Declaration, Field, Invalid, choice, listing, positive, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions, log_grid
from enginebench.methods.numerics.derivatives import digest
from enginebench.methods.sindy_grid import library_gram, segment_derivative, simulate_candidates, stlsq_gram
from enginebench.methods.sindy_library import (
    DERIVATIVE_KINDS, DERIVATIVE_SOLVERS, INTEGRATORS, differentiate, raw_coefficients,
)
from enginebench.samples import Samples

DEFAULT_DERIVATIVE_ALPHA = {"trend_filtered": 1e-3, "kalman": 1.0}
DEFAULT_PARAMS = {"order": 1, "degree": 2, "threshold": 0.1, "alpha": 0.05}
ORDERS = (1, 2)
"""Model orders: dy/dt = Theta(y, u) xi, or d2y/dt2 = Theta(y, dy/dt, u) xi with the state (y, dy/dt)."""
THRESHOLD_SCALES = ("relative", "absolute")
STLSQ_ROUTES = ("gram", "pysindy")
"""How STLSQ is solved: from the library's Gram matrix, formed once per order and degree and shared by the
grid's thresholds and alphas, or by pysindy on the samples for every fit (earlier results)."""
DERIVATIVE_SCALES = ("segment", "training")
"""What ``derivative_alpha`` is relative to: each segment's own standard deviation (its derivative then
depends on the segment alone and is computed once per process), or the training set's (before)."""
DEFAULT_THRESHOLD_RANGE = {"relative": (1e-2, 0.5), "absolute": (1e-2, 1e3)}
RELATIVE_THRESHOLD_BOUND = (1e-4, 1.0)
"""Hard bounds of a relative STLSQ threshold past the grid's edge: below 1e-4 of its unit a threshold drops
nothing a ridge fit would not, and at 1 it keeps only each equation's largest first-pass term (``threshold_unit``).
An absolute threshold is in the ODE's own units and has none: its grid keeps the advice to widen it."""
ALPHA_BOUND = (1e-10, 1e3)
"""Hard bounds of STLSQ's ridge alpha past the grid's edge (added to the library Gram's diagonal)."""
"""Default STLSQ threshold grids: relative to each derivative's rms, or the turboshaft-moe paper's absolute range."""
MIN_ROWS = 4
_PREPARE_OPTIONS = ("derivative", "derivative_solver", "derivative_chunk", "derivative_margin", "derivative_max_iter",
                    "derivative_scale", "time_scale", "envelope")
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


def _orders(value: Any) -> Any:
    if not len(value) or any(not float(o).is_integer() or int(o) not in ORDERS for o in value):
        raise Invalid("{name} must list model orders from 1 (dy/dt) and 2 (d2y/dt2), got {value}")
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
    order: int = 1
    """1: the states are the targets; 2: the targets then their time derivatives (``state_names`` end in ')."""

    @property
    def n_states(self) -> int:
        return self.coef.shape[0]

    @property
    def n_targets(self) -> int:
        return self.n_states // self.order

    @property
    def learned(self) -> range:
        """The rows of ``coef`` that STLSQ identified (order 2: the d(y')/dt rows; d(y)/dt = y' is kinematic)."""
        return range(self.n_states - self.n_targets, self.n_states)


@dataclass
class _Prepared(Scaling):
    """Standardised training trajectories and their derivatives (grid-independent)."""

    x: list[np.ndarray]
    u: list[np.ndarray] | None
    t: list[np.ndarray]
    x_dot: list[np.ndarray]
    notes: list[str]
    derivative_rms: np.ndarray
    dt: list[float] = field(default_factory=list)
    """Each segment's sample period (s)."""
    raw_dot: list[np.ndarray] | None = None
    """``derivative_scale = "segment"``: each segment's kept derivative in raw units per second."""
    memo: dict[Any, Any] = field(default_factory=dict)
    """Results derived on demand and shared by every fit of this preparation (second order, threshold units)."""


@dataclass
class _SecondOrder:
    """The second-order system of a preparation: states (x, w) with w the standardised dx/dt, and d/dt of both.

    ``w = (dx/dt - w_mean) / w_std`` (dx/dt in standardised units per ``time_scale``); the
    scaling fields hold both states' means and deviations in raw units (the derivative's
    per second) and the envelope of (x, w), as ``SINDyFit`` keeps them.
    """

    z: list[np.ndarray]
    z_dot: list[np.ndarray]
    w_mean: np.ndarray
    w_std: np.ndarray
    state_mean: np.ndarray
    state_std: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    rms: np.ndarray
    notes: list[str]


def threshold_unit(prep: "_Prepared", degree: int, alpha: float, order: int = 1) -> np.ndarray:
    """Per equation, what a relative threshold multiplies: min(rms of dx_k/dt, largest first-pass coefficient).

    The first pass is STLSQ's own first step, the ridge fit (``alpha``) of dx_k/dt on the
    whole degree-``degree`` library. Capping the unit there keeps that pass's largest term
    for every threshold below 1, so a relative grid below 1 does not empty an equation
    whose library explains little of its derivative (the rms alone would).
    """
    key = ("unit", int(order), int(degree), float(alpha))
    if key in prep.memo:
        return prep.memo[key]
    _, targets, rms = _system(prep, order)
    _, G, B = gram(prep, order, degree)
    A = G.copy()
    A.flat[:: G.shape[0] + 1] += float(alpha)
    first = np.linalg.solve(A, B).T  # the ridge fit of every derivative on the whole library
    largest = np.abs(np.atleast_2d(first)).max(axis=1)
    unit = np.where(np.isfinite(largest) & (largest > 0), np.minimum(rms, largest), rms)
    prep.memo[key] = unit
    return unit


def gram(prep: "_Prepared", order: int, degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(powers, Theta' Theta, Theta' X_dot) of the order's degree-``degree`` library, formed once per preparation."""
    key = ("gram", int(order), int(degree))
    if key not in prep.memo:
        import pysindy as ps  # here, not at the top: pysindy imports scikit-learn and scipy.stats (seconds)

        states, targets, _ = _system(prep, order)
        n_vars = states[0].shape[1] + (prep.u[0].shape[1] if prep.u else 0)
        powers = np.asarray(ps.PolynomialLibrary(degree=int(degree)).fit(np.zeros((1, n_vars))).powers_, dtype=np.int64)
        prep.memo[key] = (powers, *library_gram(states, prep.u, targets, powers))
    return prep.memo[key]


def _system(prep: "_Prepared", order: int) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """(states, their derivatives, rms of each derivative) per training segment of the order's model."""
    if order == 1:
        return prep.x, prep.x_dot, prep.derivative_rms
    second = prep.memo["second"]
    return second.z, second.z_dot, second.rms


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


def constant_states(fitted: "SINDyFit") -> list[str]:
    """The states whose identified equation lost every term (order 2: their derivative is held)."""
    return [fitted.state_names[i] for i in fitted.learned if not np.any(fitted.coef[i])]


def constant_state_warnings(fitted: "SINDyFit") -> list[str]:
    """One line per state whose every term was thresholded away (the job's warnings)."""
    held = "its initial value held, a flat line" if fitted.order == 1 else "a constant rate (a straight line)"
    return [
        f"every term of d({n})/dt was thresholded away (threshold {fitted.params['threshold']:g}, "
        f"{fitted.threshold_scale}): {n} is simulated as {held}; lower the threshold"
        for n in constant_states(fitted)
    ]


def _format_terms(coef_row: np.ndarray, names: Sequence[str], digits: int = 4) -> str:
    terms = [f"{c:+.{digits}g} {n}" if n != "1" else f"{c:+.{digits}g}" for c, n in zip(coef_row, names) if c != 0]
    return " ".join(terms) if terms else "0"


# --------------------------------------------------------------------------- method
class SINDy(Method):
    """Sparse identification of nonlinear dynamics with control (the turboshaft-moe benchmark)."""

    name = "sindy"
    family = "data-driven"
    modes = frozenset({"simulation"})
    summary = "pysindy polynomial ODE with control inputs, STLSQ, batched open-loop simulation"

    declared_options = Declaration(
        listing("orders", ORDERS, "model orders searched: 1 (dy/dt = Theta(y, u) xi) and 2 (d2y/dt2 = "
                "Theta(y, dy/dt, u) xi, which can oscillate)", items="float", searches=("order",), check=_orders),
        listing("degrees", (1, 2, 3), "polynomial degrees of the library searched", items="float", searches=("degree",),
                edges="high", check=_degrees, bound=(1.0, 5.0)),
        choice("threshold_scale", "relative", "STLSQ thresholds relative to the rms of each state's derivative, or "
               "absolute (per time_scale second, the turboshaft-moe paper's)", THRESHOLD_SCALES),
        span("threshold_range", None, "STLSQ thresholds searched (log grid); None = (0.01, 0.5) relative or "
             "(1e-2, 1e3) absolute", nullable=True, searches=("threshold",)),
        whole("n_thresholds", 4, "thresholds on the grid", low=1),
        span("alpha_range", (1e-4, 1e-1), "ridge alphas of STLSQ searched (log grid)", searches=("alpha",),
             bound=ALPHA_BOUND),
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
        choice("derivative_scale", "segment", "derivative_alpha relative to each segment's own standard deviation "
               "(each record differentiated once per process, shared by k-fold fits) or the training set's (earlier "
               "results)", DERIVATIVE_SCALES),
        choice("stlsq", "gram", "how STLSQ is solved: from the library's Gram matrix (formed once per order and "
               "degree, shared by the grid) or by pysindy on every sample for every fit (earlier results)", STLSQ_ROUTES),
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

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """The declared alpha bound, and a relative threshold's (``RELATIVE_THRESHOLD_BOUND``)."""
        bounds = dict(super().search_bounds(data))
        if self.options["threshold_scale"] == "relative":
            bounds["threshold"] = RELATIVE_THRESHOLD_BOUND
        return bounds

    @property
    def derivative_alpha(self) -> float:
        a = self.options["derivative_alpha"]
        return float(DEFAULT_DERIVATIVE_ALPHA[self.options["derivative"]] if a is None else a)

    # -- protocol ----------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        """Order x degree x STLSQ threshold (log grid, relative by default) x ridge alpha (log grid)."""
        o = self.options
        return {
            "order": np.array(sorted({int(k) for k in o["orders"]})),
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
        trajs, diverged = self._simulate([fitted], data)
        return SegmentPredictions(trajs[0], diverged[0])

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Every grid point's free runs in one time loop per model order (``sindy_grid.simulate_candidates``):
        the same numbers as ``predict`` of each model of ``fit_grid``, model by model."""
        self.check_mode(data.mode)
        fits: list[SINDyFit | None] = [None] * len(grid)
        for i, fitted in self.fit_grid(train, grid, rng):
            fits[i] = fitted
        self.check_grid_covered([f is not None for f in fits])
        out = np.empty((len(grid), len(data), len(train.target_names)))
        if not data.segments:
            return out
        groups: dict[tuple[int, int], list[int]] = {}
        for i, f in enumerate(fits):
            self._check_signals(f, data)
            groups.setdefault((f.order, id(f.lower)), []).append(i)
        for idx in groups.values():
            trajs, _ = self._simulate([fits[i] for i in idx], data)
            for i, arrays in zip(idx, trajs):
                out[i] = np.concatenate(arrays)
        return out

    def keeps_grid_models(self) -> bool:
        """``predict_grid`` predicts exactly the models of ``fit_grid`` (the same arithmetic as ``predict``)."""
        return True

    def fit_grid(
        self, train: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> Iterator[tuple[int, SINDyFit]]:
        """Every grid point shares one standardisation and one differentiation of the training data."""
        prepared = self._prepare(train)
        for i, params in enumerate(grid):
            yield i, self._fit_prepared(prepared, train, params)

    def describe(self, fitted: SINDyFit) -> dict[str, Any]:
        """Equations (standardised and in raw units), term count and the selected parameters."""
        raw = raw_coefficients(fitted)
        if fitted.order == 2:  # d(y)/dt = y' exactly (the expansion leaves rounding residue in the constant)
            k = fitted.n_targets
            raw[:k] = 0.0
            for i in range(k):
                raw[i, int(np.flatnonzero((fitted.powers == np.eye(fitted.powers.shape[1], dtype=np.int64)[k + i])
                                            .all(axis=1))[0])] = 1.0
        import pysindy as ps

        raw_names = ps.PolynomialLibrary(degree=fitted.params["degree"]).fit(
            np.zeros((1, fitted.powers.shape[1]))
        ).get_feature_names(list(fitted.state_names) + list(fitted.control_names))
        names = raw_names  # the library's terms, named by signal (the same for standardised signals)
        lhs = [f"d({n})/dt" for n in fitted.state_names]
        equations = (fitted.model.equations(precision=4) if fitted.model is not None
                     else [_format_terms(row, names) for row in fitted.coef])
        return {
            "equations": [f"{l} = {eq}" for l, eq in zip(lhs, equations)],
            "equations_units": "standardised signals (z-scores with training mean/std); time in units of "
            f"{fitted.time_scale:g} s",
            "equations_raw": [f"{l} = {_format_terms(row, raw_names)}" for l, row in zip(lhs, raw)],
            # identified terms (order 2: of the d(y')/dt equations; d(y)/dt = y' is kinematic)
            "term_count": int(np.count_nonzero(fitted.coef[fitted.learned.start:])),
            "terms_per_equation": [int(c) for c in np.count_nonzero(fitted.coef, axis=1)],
            # states whose equation lost every term: dx/dt = 0, simulated as their initial value held
            "constant_states": constant_states(fitted),
            "library_size": int(fitted.powers.shape[0]),
            "order": int(fitted.order),
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
    def _derivative_settings(self) -> dict[str, Any]:
        """``sindy_library.differentiate``'s keywords from the options."""
        o = self.options
        return {"kind": o["derivative"], "alpha": self.derivative_alpha, "chunk": int(o["derivative_chunk"]),
                "margin": int(o["derivative_margin"]), "max_iter": int(o["derivative_max_iter"]),
                "solver": o["derivative_solver"]}

    def _simulate(self, fits: Sequence[SINDyFit], data: Samples) -> tuple[list[list[np.ndarray]], np.ndarray]:
        """Free runs (targets only, at each segment's rows) and diverged flags (C, S) of models that share one
        preparation (order, standardisation, envelope), every model and segment in one time loop."""
        first = fits[0]
        k = first.n_targets
        starts, controls, times = [], [], []
        for s in data.segments:
            start, y_start = initial_state(s)
            if y_start is None or not np.all(np.isfinite(y_start)):
                where = "y0" if start == 0 else f"y_init (row {start})"
                raise MethodError(
                    f"sindy: segment {s.id!r} has no finite initial output {where}; simulation starts from the "
                    "measured outputs of the segment's first row or initialisation window"
                )
            starts.append(start)
            controls.append((s.U[start:] - first.control_mean) / first.control_std)
            times.append(s.t[start:] / first.time_scale)
        shared: dict[int, np.ndarray] = {}
        x0 = []
        for f in fits:
            if id(f.state_mean) not in shared:
                shared[id(f.state_mean)] = self._initial_states(f, data, starts)
            x0.append(shared[id(f.state_mean)])
        traj, _, diverged = simulate_candidates(
            [f.coef for f in fits], [f.powers for f in fits], np.stack(x0), controls, times, first.lower, first.upper,
            integrator=self.options["integrator"], substeps=int(self.options["substeps"]),
        )
        arrays = [[(traj[c, j, :, :k] * f.state_std[:k] + f.state_mean[:k])[np.asarray(s.rows) - a]
                   for j, (s, a) in enumerate(zip(data.segments, starts))] for c, f in enumerate(fits)]
        return arrays, diverged

    def _initial_states(self, fitted: SINDyFit, data: Samples, starts: Sequence[int]) -> np.ndarray:
        """Standardised initial states (S, n_states): the measured output at each start row and, for a
        second-order model, its derivative there, estimated from the initialisation window as in training
        (a window of 2 samples: their difference; of 1: 0)."""
        k = fitted.n_targets
        out = np.empty((len(data.segments), fitted.n_states))
        for j, (s, start) in enumerate(zip(data.segments, starts)):
            window = (np.asarray(s.y_init, dtype=np.float64).reshape(-1, k)[: start + 1] if start > 0
                      else np.asarray(s.y0, dtype=np.float64).reshape(1, k))
            out[j, :k] = (window[-1] - fitted.state_mean[:k]) / fitted.state_std[:k]
            if fitted.order == 1:
                continue
            dt = float(s.t[1] - s.t[0]) if len(s.t) > 1 else 1.0
            if len(window) >= 3:
                if self.options["derivative_scale"] == "segment":
                    v = segment_derivative(window, dt, self._derivative_settings())[0][-1]
                else:
                    x = (window - fitted.state_mean[:k]) / fitted.state_std[:k]
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        d = differentiate(x, dt / fitted.time_scale, **self._derivative_settings())
                    v = d[-1] * fitted.state_std[:k] / fitted.time_scale
            elif len(window) == 2:
                v = (window[1] - window[0]) / dt
            else:
                v = np.zeros(k)
            out[j, k:] = (v - fitted.state_mean[k:]) / fitted.state_std[k:]
        return out

    def _check_signals(self, fitted: SINDyFit, data: Samples) -> None:
        if tuple(data.target_names) != fitted.state_names[: fitted.n_targets] or tuple(data.input_names) != fitted.control_names:
            raise MethodError(
                f"sindy: model was fitted for targets {list(fitted.state_names[: fitted.n_targets])} with inputs "
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
        order = p["order"]
        if isinstance(order, (bool, np.bool_)) or not (isinstance(order, (int, np.integer, float, np.floating))
                                                        and float(order) in ORDERS):
            raise MethodError(f"sindy: parameter order must be 1 (dy/dt) or 2 (d2y/dt2), got {order!r}")
        p["order"] = int(order)
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
            a.flags.writeable = False  # (raw_dot's arrays are the per-segment cache's, read-only already)
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
        xs, us, tt, xd, dts, raw = [], [], [], [], [], []
        by_segment = self.options["derivative_scale"] == "segment"
        n_kept = 0
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
                dts.append(float(dt))
                if by_segment:
                    d_raw, bad = segment_derivative(s.y, float(dt), self._derivative_settings())
                    raw.append(d_raw)
                    n_kept += bad
                    xd.append(d_raw * (ts / x_std))
                else:
                    xd.append(differentiate(x, dt / ts, **self._derivative_settings()))
        xd_all = np.concatenate(xd)
        rms = np.sqrt(np.mean(xd_all ** 2, axis=0))
        n_conv = n_kept + sum("converge" in str(w.message) for w in caught)
        if n_conv:
            notes.append(f"differentiation: {n_conv} chunk(s) did not fully converge (derivative_max_iter)")
        span = y_all.max(axis=0) - y_all.min(axis=0)
        env = float(self.options["envelope"])
        lower = (y_all.min(axis=0) - env * span - x_mean) / x_std
        upper = (y_all.max(axis=0) + env * span - x_mean) / x_std
        return _Prepared(
            x=xs, u=us if len(train.input_names) else None, t=tt, x_dot=xd, state_mean=x_mean, state_std=x_std,
            control_mean=u_mean, control_std=u_std, lower=lower, upper=upper, notes=notes,
            derivative_rms=np.where(np.isfinite(rms) & (rms > 0), rms, 1.0), dt=dts,
            raw_dot=raw if by_segment else None,
        )

    def _second_order(self, prep: _Prepared) -> _SecondOrder:
        """The preparation's second-order system, built once: w (standardised dx/dt) and its derivative, by the
        same differentiation as dx/dt (per segment, cached, with ``derivative_scale = "segment"``)."""
        if "second" in prep.memo:
            return prep.memo["second"]
        ts = float(self.options["time_scale"])
        v_all = np.concatenate(prep.x_dot)
        w_mean, w_std = v_all.mean(axis=0), v_all.std(axis=0)
        w_std = np.where(np.isfinite(w_std) & (w_std > 0), w_std, 1.0)
        ws = [(v - w_mean) / w_std for v in prep.x_dot]
        wd, n_conv = [], 0
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            for j, w in enumerate(ws):
                if prep.raw_dot is not None:
                    d2, bad = segment_derivative(prep.raw_dot[j], prep.dt[j], self._derivative_settings())
                    n_conv += bad
                    wd.append(d2 * (ts * ts / prep.state_std / w_std))
                else:
                    wd.append(differentiate(w, prep.dt[j] / ts, **self._derivative_settings()))
        n_conv += sum("converge" in str(w.message) for w in caught)
        w_all = np.concatenate(ws)
        lo, hi = w_all.min(axis=0), w_all.max(axis=0)
        env = float(self.options["envelope"])
        rms = np.sqrt(np.mean(np.concatenate(wd) ** 2, axis=0))
        second = _SecondOrder(
            z=[np.hstack([x, w]) for x, w in zip(prep.x, ws)], z_dot=[np.hstack([a, b]) for a, b in zip(prep.x_dot, wd)],
            w_mean=w_mean, w_std=w_std, state_mean=np.r_[prep.state_mean, w_mean * prep.state_std / ts],
            state_std=np.r_[prep.state_std, w_std * prep.state_std / ts],
            lower=np.r_[prep.lower, lo - env * (hi - lo)], upper=np.r_[prep.upper, hi + env * (hi - lo)],
            rms=np.r_[prep.derivative_rms, np.where(np.isfinite(rms) & (rms > 0), rms, 1.0)],
            notes=[f"second derivatives: {n_conv} chunk(s) did not fully converge (derivative_max_iter)"] if n_conv else [],
        )
        for a in (*second.z, *second.z_dot):
            a.flags.writeable = False
        prep.memo["second"] = second
        return second

    def _fit_prepared(self, prep: _Prepared, train: Samples, params: Params) -> SINDyFit:
        import pysindy as ps

        p = self._params(params)
        order = p["order"]
        model = ps.SINDy(
            optimizer=ps.STLSQ(threshold=p["threshold"], alpha=p["alpha"]),
            feature_library=ps.PolynomialLibrary(degree=p["degree"]),
        )
        k = len(train.target_names)
        second = self._second_order(prep) if order == 2 else None
        states, targets, rms = _system(prep, order)
        state_names = list(train.target_names) + ([f"{n}'" for n in train.target_names] if second else [])
        names = state_names + list(train.input_names)
        notes = list(prep.notes) + (second.notes if second else [])
        relative = self.options["threshold_scale"] == "relative"
        # relative: STLSQ on each derivative over its unit, so one threshold cuts equation k at threshold x unit_k
        unit = threshold_unit(prep, p["degree"], p["alpha"], order) if relative else np.ones_like(rms)
        x_dot = [xd / unit for xd in targets] if relative else targets  # (the pysindy route's targets)
        if self.options["stlsq"] == "gram":
            powers, G, B = gram(prep, order, p["degree"])
            coef, said = stlsq_gram(G, B / unit if relative else B, p["threshold"], p["alpha"])
            notes += sorted(set(said))
            model = None
            if relative:
                coef = coef * unit[:, None]
        else:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                model.fit(states, t=prep.t, x_dot=x_dot, u=prep.u, feature_names=names)
            notes += sorted({str(w.message) for w in caught})
            if relative:
                model.optimizer.coef_ = np.asarray(model.optimizer.coef_, dtype=np.float64) * unit[:, None]
            coef = np.array(model.coefficients(), dtype=np.float64)
            powers = np.asarray(model.feature_library.powers_, dtype=np.int64)
        scaling = prep.scaling()
        if second is not None:
            # d(x)/dt = w_mean + w_std w exactly (kinematics, not identified)
            coef[:k] = 0.0
            bias = int(np.flatnonzero(~powers.any(axis=1))[0])
            for i in range(k):
                unit_w = np.zeros(powers.shape[1], dtype=np.int64)
                unit_w[k + i] = 1
                coef[i, bias] = second.w_mean[i]
                coef[i, int(np.flatnonzero((powers == unit_w).all(axis=1))[0])] = second.w_std[i]
            if model is not None:
                model.optimizer.coef_ = coef.copy()
            scaling.update(state_mean=second.state_mean, state_std=second.state_std, lower=second.lower,
                           upper=second.upper)
        empty = [n for n, row in zip(state_names[-k:], coef[-k:]) if not np.any(row)]
        if empty:
            notes.append(
                f"every term of d({', '.join(empty)})/dt was thresholded away (threshold {p['threshold']:g}, "
                f"{self.options['threshold_scale']}): the model is "
                + ("dx/dt = 0, so each prediction is the segment's initial value held constant (a flat line that is "
                   "not a divergence)" if order == 1 else "d2x/dt2 = 0, so each prediction is a straight line at the "
                   "initial rate") + "; lower the threshold for a model with terms"
            )
        return SINDyFit(
            model=model, coef=coef, powers=powers, **scaling,
            time_scale=float(self.options["time_scale"]), params=p, state_names=tuple(state_names),
            control_names=tuple(train.input_names), derivative=self.options["derivative"],
            derivative_alpha=self.derivative_alpha, notes=notes, threshold_scale=self.options["threshold_scale"],
            derivative_rms=rms, threshold_unit=unit, order=order,
        )
