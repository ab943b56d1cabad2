"""``mtl-krls``: the hybrid model of the egt-hybrid paper, learning from measurements and the PM at once.

Two tasks share the inputs: the measured target y and the physical model's prediction p.
With a shared model w and task models w_y, w_p (egt-hybrid, eq. 20)::

    min |Phi w - y|^2 + |Phi w - p|^2 + |Phi w_y - y|^2 + |Phi w_p - p|^2
        + lambda |w|^2 + theta (|w - w_y|^2 + |w - w_p|^2)

By the representer theorem w = Phi^T a, w_y = Phi^T b, w_p = Phi^T c. In the eigenbasis
of Q = Phi Phi^T = V diag(s) V^T the stationarity conditions decouple into one 3x3
system per component (solved in closed form below; docs/methods.md)::

    [[2s + lambda + 2 theta, -theta, -theta],   [a~]   [y~ + p~]
     [-theta,       s + theta,       0     ], . [b~] = [y~     ]
     [-theta,       0,       s + theta     ]]   [c~]   [p~     ]

whose closed form is a~ = (y~ + p~)(s + 2 theta) / (s (2 s + 4 theta + lambda) + lambda theta),
b~ = (y~ + theta a~) / (s + theta), c~ = (p~ + theta a~) / (s + theta). So the whole
(gamma, lambda, theta) grid costs at most one eigendecomposition per gamma.

It costs less: the shared filter has two real poles. With R = sqrt(16 theta^2 + lambda^2),
mu1 = (4 theta + lambda + R) / 4 and mu2 = lambda theta / (2 mu1) (both > 0),

    (s + 2 theta) / (2 (s + mu1)(s + mu2)) = w1 / (s + mu1) + w2 / (s + mu2),
    w1 = lambda (1 + lambda / (4 theta + R)) / (4 R),   w2 = theta (1 + 4 theta / (R + lambda)) / R,

both weights positive with w1 + w2 = 1/2 (no cancellation), so the shared model is
a = w1 (Q + mu1 I)^-1 (y + p) + w2 (Q + mu2 I)^-1 (y + p): two kernel ridge solutions on
the summed targets. Model selection therefore takes the KRLS path (``shifted_solutions``:
Lanczos with a residual certificate, Cholesky or one tridiagonalisation per gamma) with
two shifts per (lambda, theta); the y-task model keeps the eigendecomposition.

The shared model h(x) = sum_i a_i K(x_i, x) is the prediction, as in the paper. Note what
the closed form says: a~ depends on y and p only through y + p, so the shared model is a
spectral smoother of the average (y + p) / 2. The y-task model (``predict_with = "task"``)
is offered for comparison. The PM's prediction is also an input feature
(``pm_feature``); ``pm_task = false`` replaces p by y in the objective (no PM task).
"""

from __future__ import annotations

import itertools
import operator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from enginebench.declare import choice, flag, log_grid as grid
from enginebench.errors import MethodError
from enginebench.method import Params, SearchSpace, log_grid, split_rows
from enginebench.methods.krls import KRLS, _check_finite, gamma_kernels
from enginebench.methods.numerics.kernels import (Spectral, check_positive, gaussian, gaussian_apply, make_scaler, sq_distances,
                                         standardize_rows)
from enginebench.methods.numerics.repeats import RowGroups
from enginebench.methods.numerics.shifted import shifted_solutions
from enginebench.methods.pm import calibration_signals, physical_model, simulate_rows
from enginebench.samples import Samples

if TYPE_CHECKING:  # sklearn is imported where a scaler is made: listing methods imports no sklearn
    from sklearn.preprocessing import StandardScaler

HYPERPARAMETERS = ("gamma", "lambda", "theta")


def mtl_coefficients(
    s: np.ndarray, y_t: np.ndarray, p_t: np.ndarray, lambdas: np.ndarray, thetas: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenbasis coefficients (a~, b~, c~) for every (lambda, theta): each (n, L, T, k).

    ``s`` (n,) are the kernel eigenvalues, ``y_t``/``p_t`` (n, k) the projected targets.
    """
    s = s[:, None, None, None]
    lam = np.asarray(lambdas, dtype=float)[None, :, None, None]
    th = np.asarray(thetas, dtype=float)[None, None, :, None]
    y_t, p_t = y_t[:, None, None, :], p_t[:, None, None, :]
    a = (y_t + p_t) * (s + 2 * th) / (s * (2 * s + 4 * th + lam) + lam * th)
    b = (y_t + th * a) / (s + th)
    c = (p_t + th * a) / (s + th)
    return a, b, c


def shared_poles(lambdas: np.ndarray, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Partial fractions of the shared model's spectral filter: shifts (mu1, mu2) and weights (w1, w2),
    each (P, 2) for P (lambda, theta) pairs; a~ = (y~ + p~) sum_r w_r / (s + mu_r) (module docstring)."""
    lam = np.asarray(lambdas, dtype=np.float64)
    th = np.asarray(thetas, dtype=np.float64)
    R = np.hypot(4 * th, lam)
    mu1 = (4 * th + lam + R) / 4
    mu2 = lam * th / (2 * mu1)
    w1 = lam * (1 + lam / (4 * th + R)) / (4 * R)
    w2 = th * (1 + 4 * th / (R + lam)) / R
    return np.stack([mu1, mu2], axis=1), np.stack([w1, w2], axis=1)


@dataclass(frozen=True)
class MTLFitted:
    scaler: StandardScaler
    X_train: np.ndarray
    alpha: np.ndarray
    gamma: float
    lam: float
    theta: float
    offset: np.ndarray
    pm_params: dict[str, Any]
    distance_to_pm: float
    """RMS gap between the fitted hybrid and the PM on the training rows (target units)."""
    feature_names: tuple[str, ...] = ()
    """The kernel's feature columns: the samples' features, then ``pm:<target>`` (``pm_feature``); with the input
    and target names, the PM's name and the sample period dt, what the C step (``c_model``) reads. Empty in a
    model stored before the C step existed."""
    input_names: tuple[str, ...] = ()
    target_names: tuple[str, ...] = ()
    pm_name: str = ""
    dt: float = 0.0


class MTLKRLS(KRLS):
    """Multi-task KRLS: a shared model fitted to the measurements and the physical model together."""

    name = "mtl-krls"
    family = "hybrid"
    modes = frozenset({"static", "window"})
    summary = "hybrid multi-task KRLS: measurements and the physical model as two tasks"
    export_note = ("FMU of a static-mode model (or window mode with a 0 s window: inputs only) where the dataset's "
                   "physical model has a C step (marine-diesel-pm, gas-turbine-tat): enginebench export RUN --method "
                   "M --fmu OUT.fmu; a window model reading past measured outputs: not exportable")
    declared_options = KRLS.declared_options.extend(
        grid("theta_grid", (-4, 4, 41), "task couplings searched: log10 of theta, pulling the y and PM task models "
             "towards the shared one (low, high, count)", searches=("theta",), bound=(1e-10, 1e10)),
        flag("pm_feature", True, "the physical model's prediction is also an input feature"),
        flag("pm_task", True, "learn the PM's prediction as a second task (false: the y task twice, no PM task)"),
        choice("predict_with", "shared", "predict with the shared model (the egt-hybrid paper's) or the y-task model",
               ("shared", "task"), message="{name} must be 'shared' or 'task', got {value}"),
    )

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        if self.options["solver"] == "falkon":
            raise MethodError("method 'mtl-krls' has only the exact spectral solver; use solver = 'exact' or 'auto' "
                              "and a training subsample (train_size) it can decompose")

    def uses_falkon(self, n_rows: int) -> bool:
        return False

    def search_space(self, data: Samples) -> SearchSpace:
        t_lo, t_hi, t_n = self.options["theta_grid"]
        return {**super().search_space(data), "theta": log_grid(t_lo, t_hi, int(t_n))}

    # -- data ---------------------------------------------------------------------------
    def _features(self, data: Samples, p: np.ndarray) -> np.ndarray:
        X = data.X
        return np.hstack([X, p]) if self.options["pm_feature"] else X

    def _prepare(self, train: Samples) -> tuple[dict[str, Any], StandardScaler, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        pm = physical_model(train)
        pm_params = pm.calibrate(calibration_signals(train))
        p = np.concatenate(simulate_rows(pm, pm_params, train))
        y = train.y
        X = self._features(train, p)
        if len(X) == 0:
            raise MethodError("method 'mtl-krls': the training samples are empty")
        _check_finite(X, "training features (with the PM prediction)", (*train.feature_names, "pm"), self.name)
        _check_finite(y, "training targets", train.target_names, self.name)
        scaler = make_scaler(X, bool(self.options["standardize"]))
        offset = y.mean(axis=0) if self.options["center_target"] else np.zeros(y.shape[1])
        p_task = p if self.options["pm_task"] else y
        return pm_params, scaler, scaler.transform(X), y - offset, p_task - offset, offset

    def _eval(self, data: Samples, pm_params: dict[str, Any], scaler: StandardScaler) -> np.ndarray:
        expected = scaler.n_features_in_ - (1 if self.options["pm_feature"] else 0)
        blocks = [s.X for s in data.segments]
        width = blocks[0].shape[1] if blocks else len(data.feature_names)
        if width != expected:
            raise MethodError(
                f"method 'mtl-krls': the data have {width} feature columns but the model was trained on "
                f"{expected}; predict with samples built for the same inputs, mode and window"
            )
        pm = physical_model(data)
        p = np.concatenate(simulate_rows(pm, pm_params, data))
        Xe = standardize_rows(scaler, blocks, p if self.options["pm_feature"] else None)  # scaler.transform([X, p])
        _check_finite(Xe, "features to predict (with the PM prediction)", (*data.feature_names, "pm"), self.name)
        return Xe

    # -- one grid point -------------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> MTLFitted:
        gamma, lam, theta = _params(params)
        pm_params, scaler, Xs, yc, pc, offset = self._prepare(train)
        K = gaussian(sq_distances(Xs), gamma)
        if self.options["predict_with"] == "shared":
            shifts, weights = shared_poles(np.array([lam]), np.array([theta]))
            alpha = shifted_solutions(K, yc + pc, shifts, weights)[0][:, 0, :]
            fitted_train = K @ alpha
        else:
            spectral = Spectral.from_kernel(K)
            _, b, _ = mtl_coefficients(spectral.s, spectral.project(yc), spectral.project(pc), np.array([lam]),
                                       np.array([theta]))
            alpha = spectral.lift(b[:, 0, 0, :])
            fitted_train = spectral.lift(spectral.s[:, None] * b[:, 0, 0, :])  # Q alpha = V diag(s) coeffs
        gap = float(np.sqrt(np.mean((fitted_train - pc) ** 2))) if self.options["pm_task"] else float("nan")
        names = (*train.feature_names, *(f"pm:{t}" for t in train.target_names)) if self.options["pm_feature"] \
            else tuple(train.feature_names)
        return MTLFitted(scaler, Xs, alpha, gamma, lam, theta, offset, pm_params, gap, feature_names=names,
                         input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                         pm_name=str(physical_model(train).name), dt=float(train.dt))

    def predict(self, fitted: MTLFitted, data: Samples) -> list[np.ndarray]:
        Xe = self._eval(data, fitted.pm_params, fitted.scaler)
        return split_rows(gaussian_apply(Xe, fitted.X_train, fitted.gamma, fitted.alpha) + fitted.offset, data)

    def c_model(self, fitted: MTLFitted) -> Any:
        """The C step for an FMU (``methods/export/models.py`` ``hybrid_c``): the physical model's own C step, then
        h = sum_i alpha_i K(x_i, [x, p]) + offset, the prediction of ``predict`` (the shared or y-task model's
        coefficients alpha over the training rows). One line where the PM has no C step or a feature is a past
        measured output (window mode with Delta > 0)."""
        from enginebench.methods.export.models import hybrid_c

        return hybrid_c(self.name, fitted)

    def describe(self, fitted: MTLFitted) -> dict[str, Any]:
        return {"gamma": fitted.gamma, "lambda": fitted.lam, "theta": fitted.theta, "n_train": int(fitted.X_train.shape[0]),
                "rms_distance_to_pm_on_training_rows": fitted.distance_to_pm, "pm_params": fitted.pm_params,
                "pm_feature": self.options["pm_feature"], "pm_task": self.options["pm_task"],
                "predict_with": self.options["predict_with"]}

    # -- the whole grid -------------------------------------------------------------------
    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator) -> np.ndarray:
        """(n_grid, n_rows, k): per distinct gamma, one call of ``shifted_solutions`` (two shifts per
        (lambda, theta)) serves the shared model's whole block; the y-task model takes one eigendecomposition.
        Repeated training rows (a bootstrap resample's) are solved once, as one weighted row (``numerics/repeats.py``)."""
        triples = _grid_triples(grid)
        pm_params, scaler, Xs, yc, pc, offset = self._prepare(train)
        Xe = self._eval(data, pm_params, scaler)
        # rows first: each gamma's predictions (rows, points, k) are written in place, no transposed copy
        # of the 41^3-point output (220 MB at 400 rows); returned as a (points, rows, k) view
        out = np.empty((len(Xe), len(triples), yc.shape[1]))
        if not len(triples):
            return out.transpose(1, 0, 2)
        groups = RowGroups.of(Xs)  # a bootstrap's repeated rows: one weighted row each, same solutions
        if groups is not None:
            Xs, yc, pc = Xs[groups.first], groups.targets(yc), groups.targets(pc)
        for idx, K, Ke in gamma_kernels(Xs, Xe, triples[:, 0], groups):
            block = _columns(out, idx)
            if self.options["predict_with"] == "shared":
                shifts, weights = shared_poles(triples[idx, 1], triples[idx, 2])
                pred, _ = shifted_solutions(K, yc + pc, shifts, weights, K_eval=Ke, overwrite=True, out=block)
            else:
                lams, li = np.unique(triples[idx, 1], return_inverse=True)
                ths, ti = np.unique(triples[idx, 2], return_inverse=True)
                spectral = Spectral.from_kernel(K, overwrite=True)
                _, b, _ = mtl_coefficients(spectral.s, spectral.project(yc), spectral.project(pc), lams, ths)
                pred = spectral.predict_coeffs(Ke, b[:, li, ti, :]).transpose(1, 0, 2)
            if block is None:
                out[:, idx] = pred
            elif pred is not block:
                block[...] = pred
        out += offset
        return out.transpose(1, 0, 2)


def _columns(out: np.ndarray, idx: np.ndarray) -> np.ndarray | None:
    """``out[:, idx]`` as a view when ``idx`` is a contiguous ascending range (a grid's gamma block), else None."""
    if len(idx) and idx[-1] - idx[0] + 1 == len(idx):  # idx ascends (flatnonzero): no gaps
        return out[:, idx[0] : idx[-1] + 1]
    return None


def _grid_triples(grid: Sequence[Params]) -> np.ndarray:
    """(gamma, lambda, theta) of every grid point, (G, 3), checked positive; vectorised for 41^3 grids."""
    values = operator.itemgetter(*HYPERPARAMETERS)
    try:
        if any(len(p) != len(HYPERPARAMETERS) for p in grid):
            raise KeyError
        flat = np.fromiter(itertools.chain.from_iterable(map(values, grid)), dtype=np.float64,
                           count=len(HYPERPARAMETERS) * len(grid))
    except (KeyError, TypeError, ValueError):  # the per-point check names what is wrong
        return np.array([_params(p) for p in grid], dtype=np.float64).reshape(-1, 3)
    triples = flat.reshape(-1, 3)
    for j, name in enumerate(HYPERPARAMETERS):
        check_positive(triples[:, j], name)
    return triples


def _params(params: Params) -> tuple[float, float, float]:
    missing = [k for k in HYPERPARAMETERS if k not in params]
    if missing:
        raise MethodError(f"method 'mtl-krls': hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}")
    unknown = sorted(set(params) - set(HYPERPARAMETERS))
    if unknown:
        raise MethodError(f"method 'mtl-krls': unknown hyperparameter(s) {', '.join(unknown)}; it has gamma, lambda, theta")
    return tuple(float(check_positive(params[k], k)[0]) for k in HYPERPARAMETERS)  # type: ignore[return-value]
