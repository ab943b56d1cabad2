"""Hybrid strategies: the ways of combining the physical model (PM) with KRLS, side by side.

Every strategy uses the dataset's PM calibrated on the training rows only (``methods/pm.py``)
and its prediction p at the rows of the samples (in window mode p at the current row only,
as ``mtl-krls`` does: the window's lagged inputs and outputs are features, the PM is not
lagged). With K the Gaussian kernel matrix of the training features (standardised),
lambda the ridge and a bar the training mean:

==================  ===================  ==================================================
strategy            registered as        prediction h(x)
==================  ===================  ==================================================
shared              ``mtl-krls``         the egt-hybrid paper's shared model: a spectral
                                         smoother of (y + p) / 2 on features [x, p]
                                         (``methods/mtl_krls.py``)
task                ``mtl-krls-task``    the same objective's y-task model
feature             ``krls-pm``          ybar + k(x~)^T (K~ + lambda I)^-1 (y - ybar),
                                         x~ = [x, p(x)]: the PM as one more input
residual            ``residual-krls``    p(x) + rbar + k(x)^T (K + lambda I)^-1 (r - rbar),
                                         r = y - p: KRLS learns the PM's error
residual-feature    ``residual-krls-pm`` residual learning on x~ = [x, p(x)]
==================  ===================  ==================================================

``hybrid`` selects the strategy with the other hyperparameters on training data only.
Its hyperparameter ``strategy`` carries the MTL strategies' theta in its value
(``"task theta=0.01"``), so the product grid strategy x gamma x lambda is exactly the union
of the strategies' own grids (no residual model is repeated for every theta), and
``predict_grid`` hands each strategy's block to that strategy's own shared-factorisation
path: one tridiagonalisation (or certified Krylov basis) per gamma for all lambdas
(``ridge_solutions`` through ``KRLS.predict_grid``), two shifts per (lambda, theta) for
the shared model, one eigendecomposition per gamma for the task model.

Residual learning with a large lambda returns the PM with its mean error removed
(p + rbar); with a small one it interpolates the measurements. Every fitted model records
how far it stayed from the PM on the training rows: ``rms_from_pm`` = RMS(h - p) (target
units) and ``pm_share`` = RMS(h - p) / RMS(y - p), 0 for the PM unchanged and 1 for a model
as far from the PM as the measurements are (pooled over targets).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence

import numpy as np

from enginebench.declare import Invalid, choice, listing, log_grid as grid
from enginebench.errors import MethodError
from enginebench.method import Params, SearchSpace, log_grid
from enginebench.methods.krls import KRLS, KRLSFitted
from enginebench.methods.mtl_krls import MTLFitted, MTLKRLS
from enginebench.methods.pm import calibration_signals, physical_model, simulate_rows
from enginebench.samples import Samples

STRATEGIES = ("shared", "task", "feature", "residual", "residual-feature")
"""The hybrid strategies, in the order ``hybrid`` searches them."""
MTL_STRATEGIES = ("shared", "task")
"""Strategies with the multi-task hyperparameter theta."""
THETA_LABEL = " theta="
"""Separates an MTL strategy from its theta in a ``hybrid`` grid value: ``"shared theta=0.1"``."""


# -- the PM and the distance from it ----------------------------------------------------------

def calibrate_pm(train: Samples) -> dict[str, Any]:
    """The PM's parameters by its own rule, from the training rows only."""
    return physical_model(train).calibrate(calibration_signals(train))


def pm_rows(method: str, data: Samples, pm_params: dict[str, Any]) -> list[np.ndarray]:
    """The PM's prediction at each segment's rows, (n_i, k); MethodError naming the first nan/inf."""
    out = simulate_rows(physical_model(data), pm_params, data)
    for seg, p in zip(data.segments, out):
        bad = ~np.isfinite(p)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise MethodError(
                f"method {method!r}: the physical model's prediction of {data.target_names[col]!r} is nan/inf at "
                f"row {int(seg.rows[row])} of segment {seg.id!r}; the hybrid strategies need a finite PM prediction "
                f"on every row (check that segment's inputs)"
            )
    return out


def pm_share(rms_from_pm: float, rms_pm_error: float) -> float:
    """RMS(h - p) / RMS(y - p): 0 = the PM unchanged, 1 = as far from the PM as the measurements."""
    if rms_pm_error > 0:
        return rms_from_pm / rms_pm_error
    return 0.0 if rms_from_pm == 0 else float("inf")


@dataclass(frozen=True)
class HybridFitted:
    """A fitted hybrid strategy: its model plus how far it stayed from the PM on the training rows."""

    strategy: str
    model: KRLSFitted | MTLFitted
    pm_params: dict[str, Any]
    n_features: int
    """Feature columns of the data (without the PM's prediction)."""
    rms_from_pm: float
    """RMS(h - p) on the training rows, target units, pooled over targets."""
    rms_pm_error: float
    """RMS(y - p) on the training rows: the calibrated PM's own training error."""
    pm_name: str = ""
    """The physical model's name, the targets and the sample period: what the C step (``c_model``) builds the PM's
    own C step from; empty in a model stored before the hybrids had a C step."""
    target_names: tuple[str, ...] = ()
    dt: float = 0.0

    @property
    def pm_share(self) -> float:
        return pm_share(self.rms_from_pm, self.rms_pm_error)


def _fitted(strategy: str, model: KRLSFitted | MTLFitted, pm_params: dict[str, Any], train: Samples,
            pred: np.ndarray, p: np.ndarray) -> HybridFitted:
    y = train.y
    return HybridFitted(strategy=strategy, model=model, pm_params=pm_params, n_features=train.X.shape[1],
                        rms_from_pm=float(np.sqrt(np.mean((pred - p) ** 2))),
                        rms_pm_error=float(np.sqrt(np.mean((y - p) ** 2))),
                        pm_name=str(physical_model(train).name), target_names=tuple(train.target_names),
                        dt=float(train.dt))


EXPORT_NOTE = ("FMU of a static-mode model (or window mode with a 0 s window: inputs only) where the dataset's "
               "physical model has a C step (marine-diesel-pm, gas-turbine-tat): enginebench export RUN --method M "
               "--fmu OUT.fmu; a window model reading past measured outputs: not exportable")


def _check_feature_count(method: str, data: Samples, expected: int) -> None:
    got = data.X.shape[1]
    if got != expected:
        raise MethodError(
            f"method {method!r}: the data have {got} feature columns but the model was trained on {expected}; "
            f"predict with samples built for the same inputs, mode and window"
        )


def _description(fitted: HybridFitted, theta: float | None, extra: dict[str, Any]) -> dict[str, Any]:
    """The keys every strategy's ``describe`` has, then the strategy's own."""
    model = fitted.model
    return {"strategy": fitted.strategy, "gamma": float(model.gamma), "lambda": float(model.lam), "theta": theta,
            "pm_share": fitted.pm_share, "rms_from_pm": fitted.rms_from_pm, "rms_pm_error": fitted.rms_pm_error,
            "pm_params": fitted.pm_params, **extra}


# -- KRLS with the PM as an input, on the PM's error, or both -----------------------------------

class KRLSPM(KRLS):
    """KRLS with the PM's prediction as one more input feature (``feature``)."""

    name = "krls-pm"
    family = "hybrid"
    modes = frozenset({"static", "window"})
    summary = "hybrid: KRLS with the physical model's prediction as an extra input feature"
    export_note = EXPORT_NOTE
    strategy = "feature"
    pm_input = True
    """The PM's prediction is a feature."""
    residual = False
    """KRLS is fitted to y - p and p is added back."""

    def _augment(self, data: Samples, p: Sequence[np.ndarray]) -> Samples:
        """The samples KRLS sees: features [X, p] (pm_input), targets y - p (residual, where present)."""
        segments = tuple(
            replace(s, X=np.hstack([s.X, ps]) if self.pm_input else s.X,
                    y=s.y - ps if self.residual and s.y is not None else s.y)
            for s, ps in zip(data.segments, p)
        )
        names = data.feature_names + tuple(f"pm:{t}" for t in data.target_names) if self.pm_input else data.feature_names
        return replace(data, segments=segments, feature_names=names)

    def _predict_model(self, model: KRLSFitted, data: Samples, p: Sequence[np.ndarray]) -> list[np.ndarray]:
        out = super().predict(model, self._augment(data, p))
        return [o + ps for o, ps in zip(out, p)] if self.residual else list(out)

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> HybridFitted:
        pm_params = calibrate_pm(train)
        p = pm_rows(self.name, train, pm_params)
        model = super().fit(self._augment(train, p), params, rng)
        pred = np.concatenate(self._predict_model(model, train.without_targets(), p))
        return _fitted(self.strategy, model, pm_params, train, pred, np.concatenate(p))

    def predict(self, fitted: HybridFitted, data: Samples) -> list[np.ndarray]:
        _check_feature_count(self.name, data, fitted.n_features)
        return self._predict_model(fitted.model, data, pm_rows(self.name, data, fitted.pm_params))

    def c_model(self, fitted: HybridFitted) -> Any:
        """The C step for an FMU (``methods/export/models.py`` ``hybrid_c``): the PM's own C step p, KRLS's kernel
        sum on the features (with p where it is one), plus p for residual learning. One line where the PM has no
        C step or a feature is a past measured output (window mode with Delta > 0)."""
        from enginebench.methods.export.models import hybrid_c

        return hybrid_c(self.name, fitted)

    def describe(self, fitted: HybridFitted) -> dict[str, Any]:
        return _description(fitted, None, {k: v for k, v in super().describe(fitted.model).items()
                                           if k not in ("gamma", "lambda")})

    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator) -> np.ndarray:
        """KRLS's grid path (one factorisation per gamma serves every lambda) on the augmented samples."""
        _check_feature_count(self.name, data, train.X.shape[1])
        pm_params = calibrate_pm(train)
        p_train, p_data = pm_rows(self.name, train, pm_params), pm_rows(self.name, data, pm_params)
        out = super().predict_grid(self._augment(train, p_train), self._augment(data, p_data), grid, rng)
        if self.residual and len(out):
            out += np.concatenate(p_data)[None]
        return out


class ResidualKRLS(KRLSPM):
    """The PM plus KRLS fitted to the PM's error y - p on the ordinary features (``residual``)."""

    name = "residual-krls"
    summary = "hybrid: the physical model plus KRLS fitted to its error y - p"
    strategy = "residual"
    pm_input = False
    residual = True


class ResidualKRLSPM(KRLSPM):
    """The PM plus KRLS fitted to y - p with the PM's prediction as a feature too (``residual-feature``)."""

    name = "residual-krls-pm"
    summary = "hybrid: the physical model plus KRLS fitted to its error, the PM's prediction a feature too"
    strategy = "residual-feature"
    pm_input = True
    residual = True


# -- the multi-task models ----------------------------------------------------------------------

class MTLDistanceKRLS(MTLKRLS):
    """MTL-KRLS (``predict_with`` chooses the shared or the y-task model) recording its distance from the PM.

    Unregistered under its own name: ``hybrid``'s ``shared`` and ``task`` strategies. The
    registered ``mtl-krls`` is the unchanged paper model.
    """

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> HybridFitted:
        model = super().fit(train, params, rng)
        p = np.concatenate(pm_rows(self.name, train, model.pm_params))
        pred = np.concatenate(super().predict(model, train.without_targets()))
        return _fitted(self.options["predict_with"], model, model.pm_params, train, pred, p)

    def predict(self, fitted: HybridFitted, data: Samples) -> list[np.ndarray]:
        return super().predict(fitted.model, data)

    def describe(self, fitted: HybridFitted) -> dict[str, Any]:
        model = fitted.model
        return _description(fitted, float(model.theta), {
            "n_train": int(model.X_train.shape[0]), "pm_feature": self.options["pm_feature"],
            "pm_task": self.options["pm_task"], "predict_with": self.options["predict_with"]})


class MTLTaskKRLS(MTLDistanceKRLS):
    """The y-task model of MTL-KRLS: w_y, tied to the shared model by theta (``task``)."""

    name = "mtl-krls-task"
    summary = "hybrid multi-task KRLS, predicting with the measurement task's own model"
    declared_options = MTLKRLS.declared_options.extend(
        choice("predict_with", "task", "the y-task model (for the shared model use method mtl-krls)", ("task",),
               message="{name} must be 'task' (the y-task model), got {value}; for the shared model use method "
                       "'mtl-krls'"),
    )


# -- the strategy as a hyperparameter ---------------------------------------------------------

def _check_strategies(value: Any) -> list[str]:
    """The ``strategies`` option: distinct names from ``STRATEGIES`` (``Invalid`` otherwise)."""
    names = list(value)
    if any(s not in STRATEGIES for s in names) or len(set(names)) != len(names):
        raise Invalid("{name} must be a non-empty list of distinct names from " + ", ".join(STRATEGIES)
                      + ", got {value}")
    return names


def strategy_label(strategy: str, theta: float | None = None) -> str:
    """A ``hybrid`` grid value: the strategy, with its theta for the MTL strategies (exact float repr)."""
    return strategy if theta is None else f"{strategy}{THETA_LABEL}{float(theta)!r}"


class Hybrid(KRLS):
    """The strategy of combining PM and KRLS selected on training data with the other hyperparameters."""

    name = "hybrid"
    family = "hybrid"
    modes = frozenset({"static", "window"})
    summary = "hybrid: the PM/KRLS combination (shared, task, feature, residual, residual-feature) selected on training data"
    export_note = EXPORT_NOTE
    declared_options = KRLS.declared_options.extend(
        grid("theta_grid", (-4, 4, 41), "task couplings searched for the shared and task strategies: log10 of "
             "theta (low, high, count)"),
        listing("strategies", list(STRATEGIES), "the strategies searched (shared, task, feature, residual, "
                "residual-feature)", items="str", check=_check_strategies),
    )

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        mtl = [s for s in self.options["strategies"] if s in MTL_STRATEGIES]
        if self.options["solver"] == "falkon" and mtl:
            raise MethodError(f"method 'hybrid': strategies {', '.join(mtl)} have only the exact solver; drop them "
                              f"from option strategies or use solver = 'exact' or 'auto'")
        self._methods: dict[str, KRLS] = {}

    def strategy_method(self, strategy: str) -> KRLS:
        """The method of one strategy, with this method's KRLS options (and theta grid for MTL)."""
        if strategy not in self._methods:
            krls = {k: self.options[k] for k in KRLS.default_options()}
            if strategy in MTL_STRATEGIES:
                self._methods[strategy] = MTLDistanceKRLS(**krls, theta_grid=self.options["theta_grid"],
                                                          predict_with=strategy)
            else:
                cls = {"feature": KRLSPM, "residual": ResidualKRLS, "residual-feature": ResidualKRLSPM}[strategy]
                self._methods[strategy] = cls(**krls)
        return self._methods[strategy]

    def search_space(self, data: Samples) -> SearchSpace:
        t_lo, t_hi, t_n = self.options["theta_grid"]
        thetas = log_grid(t_lo, t_hi, int(t_n))
        labels = [strategy_label(s, t) for s in self.options["strategies"]
                  for t in (thetas if s in MTL_STRATEGIES else [None])]
        return {"strategy": np.array(labels, dtype=object), **super().search_space(data)}

    def _point(self, params: Params, cache: dict[str, tuple[str, float | None]] | None = None
               ) -> tuple[str, dict[str, Any]]:
        """(strategy, the strategy method's own grid point) of a ``hybrid`` grid point."""
        unknown = sorted(set(params) - {"strategy", "gamma", "lambda", "theta"})
        if unknown:
            raise MethodError(f"method 'hybrid': unknown hyperparameter(s) {', '.join(unknown)}; "
                              f"it has strategy, gamma, lambda (and theta for {' and '.join(MTL_STRATEGIES)})")
        if "strategy" not in params:
            raise MethodError(f"method 'hybrid': hyperparameter strategy missing from {dict(params)!r}; "
                              f"give one of {', '.join(STRATEGIES)}")
        label = params["strategy"]
        parsed = cache.get(label) if cache is not None and isinstance(label, str) else None
        if parsed is None:
            parsed = _parse_label(label)
            if cache is not None:
                cache[label] = parsed
        strategy, theta = parsed
        inner = {k: params[k] for k in ("gamma", "lambda") if k in params}
        if strategy in MTL_STRATEGIES:
            if theta is not None and "theta" in params:
                raise MethodError(f"method 'hybrid': theta given twice, in strategy {label!r} and as theta = "
                                  f"{params['theta']!r}; give it once")
            inner["theta"] = params["theta"] if theta is None and "theta" in params else theta
            if inner["theta"] is None:
                raise MethodError(f"method 'hybrid': strategy {strategy!r} needs theta, e.g. "
                                  f"{strategy_label(strategy, 1.0)!r} or theta = 1.0")
        elif "theta" in params:
            raise MethodError(f"method 'hybrid': theta applies to the strategies {' and '.join(MTL_STRATEGIES)}, "
                              f"not {strategy!r}")
        return strategy, inner

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> HybridFitted:
        strategy, inner = self._point(params)
        return self.strategy_method(strategy).fit(train, inner, rng)

    def predict(self, fitted: HybridFitted, data: Samples) -> list[np.ndarray]:
        return self.strategy_method(fitted.strategy).predict(fitted, data)

    def c_model(self, fitted: HybridFitted) -> Any:
        """The selected strategy's C step (``KRLSPM.c_model``, ``MTLKRLS.c_model``)."""
        from enginebench.methods.export.models import hybrid_c

        return hybrid_c(self.name, fitted)

    def describe(self, fitted: HybridFitted) -> dict[str, Any]:
        out = self.strategy_method(fitted.strategy).describe(fitted)
        theta = out.get("theta")
        t_lo, t_hi, t_n = self.options["theta_grid"]
        if theta is not None and int(t_n) >= 3:
            edge = "lower" if np.isclose(theta, 10.0 ** t_lo) else "upper" if np.isclose(theta, 10.0 ** t_hi) else None
            if edge:
                out["warnings"] = [f"theta = {theta:g} selected at the {edge} edge of its grid "
                                   f"[{10.0 ** t_lo:g} .. {10.0 ** t_hi:g}]; the optimum may lie beyond it: widen theta_grid"]
        return out

    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator) -> np.ndarray:
        """(n_grid, n_rows, k), in the order of ``grid``: each strategy's points through its own grid path."""
        cache: dict[str, tuple[str, float | None]] = {}
        points = [self._point(p, cache) for p in grid]
        out = np.empty((len(points), len(data), len(train.target_names)))
        strategies = np.array([s for s, _ in points], dtype=object)
        for strategy in dict.fromkeys(strategies.tolist()):
            idx = np.flatnonzero(strategies == strategy)
            out[idx] = self.strategy_method(strategy).predict_grid(train, data, [points[i][1] for i in idx], rng)
        return out


def _parse_label(label: Any) -> tuple[str, float | None]:
    """(strategy, theta or None) of a ``hybrid`` strategy value; MethodError naming the valid ones."""
    text = label if isinstance(label, str) else None
    strategy, _, theta_text = (text or "").partition(THETA_LABEL)
    theta: float | None = None
    if text is not None and theta_text:
        try:
            theta = float(theta_text)
        except ValueError:
            strategy = ""
    if strategy not in STRATEGIES or (theta is not None and strategy not in MTL_STRATEGIES):
        raise MethodError(f"method 'hybrid': strategy {label!r} is not one of {', '.join(STRATEGIES)} "
                          f"(the MTL strategies may carry their theta: {strategy_label('shared', 0.1)!r})")
    return strategy, theta
