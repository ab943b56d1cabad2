"""Exact kernel regularised least squares with a Gaussian kernel (the KRLS of the egt-hybrid and turboshaft-moe papers).

The whole (gamma, lambda) grid costs at most one Householder tridiagonalisation of the
training kernel per gamma (a third of an eigendecomposition): every lambda is then an
O(n) tridiagonal solve. Where a shifted Lanczos basis certifies every lambda within a
few dozen matrix-vector products (small or large gamma), not even that
(``ridge_solutions`` in ``methods/numerics/shifted.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Iterator, Sequence

import numpy as np

from enginebench.declare import Declaration, choice, flag, log_grid as grid, text, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, log_grid, split_rows
from enginebench.methods.numerics.kernels import (check_positive, gaussian, gaussian_apply, make_scaler,
                                         power_of_two_scale, sq_distances, standardize_rows)
from enginebench.methods.numerics.repeats import RowGroups
from enginebench.methods.numerics.shifted import ridge_solutions
from enginebench.samples import Samples

if TYPE_CHECKING:  # sklearn is imported where a scaler is made: listing methods imports no sklearn
    from sklearn.preprocessing import StandardScaler


SOLVERS = ("auto", "exact", "falkon")
GAMMA_BOUND = (1e-8, 1e6)
"""Hard bounds of a searched kernel width on standardised features: below 1e-8 the kernel is flat to rounding over
any standardised data, above 1e6 it is a nearest-neighbour lookup."""
LAMBDA_BOUND = (1e-14, 1e8)
"""Hard bounds of a searched ridge penalty, relative to the kernel's scale (its diagonal is 1): below 1e-14 the
penalty is lost to rounding in the kernel's largest eigenvalues; above 1e8 the fit is the mean."""


@dataclass(frozen=True)
class KRLSFitted:
    """A fitted KRLS model: h(x) = sum_i alpha_i exp(-gamma |s(x) - s(x_i)|^2) + y_mean.

    With the FALKON solver the x_i are the Nystroem centres, not all training rows.
    """

    scaler: StandardScaler
    X_train: np.ndarray
    """Training features after the scaler, (n, d)."""
    alpha: np.ndarray
    """Dual coefficients, (n, k)."""
    gamma: float
    lam: float
    y_mean: np.ndarray
    """Added back to every prediction, (k,); zeros when the target is not centred."""
    solver: str = "exact"
    feature_names: tuple[str, ...] = ()
    """The training samples' feature columns (static mode: the inputs; window mode: ``u[t-k]``, ``y[t-k]``) and
    input signals, which the C step (``c_model``) reads; empty in a model stored before the C step existed."""
    input_names: tuple[str, ...] = ()


class KRLS(Method):
    """Gaussian-kernel regularised least squares.

    Exact up to ``exact_max_rows`` training rows (one tridiagonalisation per gamma serves
    every lambda, see ``ridge_solutions``); above that, or with
    ``solver = "falkon"``, Nystroem centres plus preconditioned conjugate gradient
    (FALKON, in torch, CPU or CUDA) without ever forming the n x n kernel matrix.
    """

    name = "krls"
    family = "data-driven"
    modes = frozenset({"static", "window"})
    summary = "Gaussian-kernel regularised least squares (exact, one tridiagonalisation per gamma)"
    export_note = ("FMU of a static-mode model (FMI 2.0 co-simulation from its C step: enginebench export RUN "
                   "--method krls --fmu OUT.fmu); a window-mode model reads past measured outputs: not exportable")
    declared_options = Declaration(
        flag("standardize", True, "scale each feature to zero mean and unit variance on the training rows"),
        flag("center_target", True, "fit the targets minus their training mean (added back to predictions)"),
        grid("gamma_grid", (-4, 4, 41), "kernel widths searched: log10 of gamma in exp(-gamma |x - x'|^2) "
             "(low, high, count)", searches=("gamma",), bound=GAMMA_BOUND),
        grid("lambda_grid", (-4, 4, 41), "ridge penalties searched: log10 of lambda (low, high, count)",
             searches=("lambda",), bound=LAMBDA_BOUND),
        choice("solver", "auto", "exact (one tridiagonalisation per gamma), falkon (Nystroem centres + CG), "
               "auto: exact up to exact_max_rows training rows", SOLVERS,
               message="{name} must be one of " + ", ".join(SOLVERS) + ", got {value}"),
        whole("exact_max_rows", 20_000, "solver auto: the exact solver up to this many training rows, FALKON above",
              low=0, unit="rows"),
        whole("centres", 2000, "Nystroem centres of the FALKON solver", low=1, unit="rows"),
        text("device", "auto", "torch device of the FALKON solver: auto, cpu, cuda or cuda:INDEX"),
    )

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """The C step and its note are krls's own: a subclass (nfir, the hybrids) predicts otherwise, so it offers
        the one it or a class between it and krls defines (a hybrid strategy inherits its family's), or none
        (``Method.c_model``)."""
        super().__init_subclass__(**kwargs)
        for attr, none in (("c_model", Method.c_model), ("export_note", None)):
            if next(k for k in cls.__mro__ if attr in k.__dict__) is KRLS:
                setattr(cls, attr, none)

    def uses_falkon(self, n_rows: int) -> bool:
        """Exact below ``exact_max_rows`` training rows (solver 'auto'), FALKON above or on request."""
        solver = self.options["solver"]
        return solver == "falkon" or (solver == "auto" and n_rows > int(self.options["exact_max_rows"]))

    def _falkon(self, gamma: float, lam: float):
        from enginebench.methods.numerics.falkon import FalkonSolver

        return FalkonSolver(gamma=gamma, lam=lam, centres=int(self.options["centres"]), device=self.options["device"])

    def search_space(self, data: Samples) -> SearchSpace:
        g_lo, g_hi, g_n = self.options["gamma_grid"]
        l_lo, l_hi, l_n = self.options["lambda_grid"]
        return {"gamma": log_grid(g_lo, g_hi, int(g_n)), "lambda": log_grid(l_lo, l_hi, int(l_n))}

    # -- shared preparation -------------------------------------------------------------
    def _train_arrays(self, train: Samples) -> tuple[StandardScaler, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Scaler, scaled training features, (centred) targets over their power-of-two scale, the target mean and
        that scale. Dividing by a power of two is exact, so the solutions are the same numbers at every scale: a
        target of 1e-200 fits like one of 1 (its squares would underflow) and any other target bit for bit as
        before; the solutions times the scale are the unscaled ones."""
        X, y = train.X, train.y
        if len(X) == 0:
            raise MethodError(f"method {self.name!r}: the training samples are empty; give at least one training row")
        _check_finite(X, "training features", train.feature_names, self.name)
        _check_finite(y, "training targets", train.target_names, self.name)
        scaler = make_scaler(X, bool(self.options["standardize"]))
        y_mean = y.mean(axis=0) if self.options["center_target"] else np.zeros(y.shape[1])
        yc = y - y_mean
        y_scale = power_of_two_scale(yc)
        return scaler, scaler.transform(X), yc / y_scale, y_mean, y_scale

    def _eval_features(self, scaler: StandardScaler, X_train: np.ndarray, data: Samples) -> np.ndarray:
        blocks = [s.X for s in data.segments]
        width = blocks[0].shape[1] if blocks else len(data.feature_names)
        if width != X_train.shape[1]:
            raise MethodError(
                f"method {self.name!r}: the data have {width} feature columns but the model was trained on "
                f"{X_train.shape[1]}; predict with samples built for the same inputs, mode and window"
            )
        Xe = standardize_rows(scaler, blocks)  # scaler.transform(data.X) without its copies
        _check_finite(Xe, "features to predict", data.feature_names, self.name)  # (x - mean) / scale: nan/inf where x is
        return Xe

    # -- single grid point --------------------------------------------------------------
    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> KRLSFitted:
        gamma, lam = _params(params)
        scaler, Xs, yc, y_mean, y_scale = self._train_arrays(train)
        if self.uses_falkon(len(Xs)):
            solver = self._falkon(gamma, lam).fit(Xs, yc, rng)
            return KRLSFitted(scaler=scaler, X_train=solver.centres_, alpha=solver.coef_ * y_scale, gamma=gamma,
                              lam=lam, y_mean=y_mean, solver="falkon", **_names(train))
        alpha = ridge_solutions(gaussian(sq_distances(Xs), gamma), yc, np.array([lam]), overwrite=True)[0][:, 0, :]
        return KRLSFitted(scaler=scaler, X_train=Xs, alpha=alpha * y_scale, gamma=gamma, lam=lam, y_mean=y_mean,
                          **_names(train))

    def predict(self, fitted: KRLSFitted, data: Samples) -> list[np.ndarray]:
        Xe = self._eval_features(fitted.scaler, fitted.X_train, data)
        return split_rows(gaussian_apply(Xe, fitted.X_train, fitted.gamma, fitted.alpha) + fitted.y_mean, data)

    def c_model(self, fitted: KRLSFitted) -> Any:
        """The C step of ``fitted`` for an FMU (``methods/export/models.py``: the features must be inputs, as in
        static mode; a window model reading past measured outputs is refused in one line)."""
        from enginebench.methods.export.models import krls_c

        return krls_c(fitted)

    def describe(self, fitted: KRLSFitted) -> dict[str, Any]:
        return {"gamma": float(fitted.gamma), "lambda": float(fitted.lam), "solver": fitted.solver,
                "n_train" if fitted.solver == "exact" else "centres": int(fitted.X_train.shape[0])}

    # -- the whole grid at once -----------------------------------------------------------
    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Predictions for every grid point, (n_grid, n_rows, n_targets), in the order of ``grid``.

        Squared distances are computed once; per distinct gamma one call of
        ``ridge_solutions`` (Lanczos, Cholesky or one tridiagonalisation) serves all of that
        gamma's lambdas. Repeated training rows (a bootstrap resample's) are solved once, as
        one weighted row (``numerics/repeats.py``): the same predictions from a smaller system.
        """
        pairs = [_params(p) for p in grid]
        scaler, Xs, yc, y_mean, y_scale = self._train_arrays(train)
        Xe = self._eval_features(scaler, Xs, data)
        out = np.empty((len(pairs), len(Xe), yc.shape[1]))
        if not pairs:
            return out
        gammas = np.array([g for g, _ in pairs])
        lambdas = np.array([lam for _, lam in pairs])
        if self.uses_falkon(len(Xs)):
            from enginebench.methods.numerics.falkon import falkon_path

            for gamma in dict.fromkeys(gammas.tolist()):
                idx = np.flatnonzero(gammas == gamma)
                out[idx], _ = falkon_path(Xs, yc, Xe, gamma, lambdas[idx], int(self.options["centres"]), rng,
                                          device=self.options["device"])
            return out * y_scale + y_mean
        groups = RowGroups.of(Xs)  # a bootstrap's repeated rows: one weighted row each, same solutions
        if groups is not None:
            Xs, yc = Xs[groups.first], groups.targets(yc)
        n, k = yc.shape
        for idx, K, Ke in gamma_kernels(Xs, Xe, gammas, groups):
            alpha, _ = ridge_solutions(K, yc, lambdas[idx], overwrite=True)
            pred = Ke @ alpha.reshape(n, len(idx) * k)
            out[idx] = pred.reshape(len(Xe), len(idx), k).transpose(1, 0, 2)
        out *= y_scale
        out += y_mean
        return out


def gamma_kernels(Xs: np.ndarray, Xe: np.ndarray, gammas: np.ndarray, groups: RowGroups | None
                  ) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per distinct gamma (in order of first appearance): its grid indices, the training kernel and
    the evaluation kernel, weighted for repeated rows (``groups``, numerics/repeats.py).

    Squared distances are computed once; the two kernels live in two buffers that each gamma
    overwrites (a solver may factorise the training kernel in place).
    """
    D_train, D_eval = sq_distances(Xs), sq_distances(Xe, Xs)
    K_train, K_eval = np.empty_like(D_train), np.empty_like(D_eval)
    for gamma in dict.fromkeys(gammas.tolist()):
        K, Ke = gaussian(D_train, gamma, out=K_train), gaussian(D_eval, gamma, out=K_eval)
        if groups is not None:
            groups.weigh(K, Ke)
        yield np.flatnonzero(gammas == gamma), K, Ke


def _names(train: Samples) -> dict[str, tuple[str, ...]]:
    return {"feature_names": tuple(train.feature_names), "input_names": tuple(train.input_names)}


def _params(params: Params) -> tuple[float, float]:
    """(gamma, lambda) from a grid point, checked positive."""
    missing = [k for k in ("gamma", "lambda") if k not in params]
    if missing:
        raise MethodError(
            f"method 'krls': hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}; "
            f"give both 'gamma' and 'lambda'"
        )
    unknown = sorted(set(params) - {"gamma", "lambda"})
    if unknown:
        raise MethodError(
            f"method 'krls': unknown hyperparameter(s) {', '.join(unknown)}; it has 'gamma' and 'lambda'"
        )
    values = []
    for key in ("gamma", "lambda"):
        if np.ndim(params[key]) != 0:
            raise MethodError(f"method 'krls': hyperparameter {key!r} must be one number, got {params[key]!r}")
        values.append(float(check_positive(params[key], key)[0]))
    return values[0], values[1]


def _check_finite(values: np.ndarray, what: str, names: Sequence[str], who: str = "krls") -> None:
    """MethodError naming the first column and row with nan/inf."""
    with np.errstate(over="ignore", invalid="ignore"):
        if np.isfinite(np.sum(values)):  # one pass, no mask: a finite sum has no nan/inf term
            return
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        name = names[col] if col < len(names) else f"#{col}"
        raise MethodError(
            f"method {who!r}: {what} contain nan/inf (column {name!r}, stacked row {row}); "
            f"clean or drop those rows before fitting"
        )
