"""``narx``: kernel NARX, Gaussian-kernel regularised least squares on lagged outputs AND inputs, run free.

Model, per target y (one MISO model per target; its own past outputs, every input)::

    y(t) = a . [y(t-1) .. y(t-na)] + sum_j b_j . [u_j(t-nk) .. u_j(t-nk-nb+1)] + c0      (linear ARX part)
           + f( y(t-ka), ..., y(t-1), u_j(t-nk), ..., u_j(t-nk-kb+1) for each input j )  (kernel part)
    f(z) = sum_i beta_i exp(-(gamma / d) |z - c_i|^2),   ka = min(na, kernel_lags), kb = min(nb, kernel_lags)

on standardised signals (each signal's training mean and standard deviation, the same
for all of its lags), d the number of kernel regressors, so one relative ``gamma`` grid
suits every order. The linear part is unpenalised and fitted jointly with the kernel
(a semi-parametric kernel ridge: ``nystroem_ridge``): it carries the long memory of
lightly damped systems sampled fast (F-16 at 400 Hz wants ~64 lags), which a Gaussian
kernel in 128 dimensions could not learn from a record, while the kernel, on at most
``kernel_lags`` lags of each signal, models the nonlinearity. ``linear = false`` leaves
the kernel alone. Training is one step ahead on measured outputs (the equation-error
fit); rows start where all lags lie inside their training segment.

Solvers (exact up to ``exact_max_rows`` rows, else Nystroem centres; ``nystroem_ridge``) and
the batched free run (``free_run``) are the numerics in ``methods/narx_model.py``; this module
is the Method: options, grid, selection, fitting and prediction flow. Free run
(``predict``): the first lagged outputs are the init window's measured ones, after the
window only simulated outputs are fed back; a run leaving the envelope of the training
outputs, or turning non-finite, is flagged and held at its last in-envelope value
(``methods/freerun.py``), as for ``sindy``. With ``kernel_box = true`` the kernel reads its
regressors clipped to the training data's range (``narx_model.KernelBox``): past the data the
kernel part holds its edge value and only the linear part extrapolates. Off by default: it
rescued F-16's louder excitation level (fit -471 -> 43 %) and one engine output (gengine2 hc,
NRMSE 0.50 -> 0.40) but doubled Silverbox's error on its extrapolating head (0.39 -> 0.83 mV),
where the restoring force must grow past the training amplitudes (docs/benchmarks.md).

Selection: the toolkit scores ``predict_grid``'s free runs on validation blocks, so
orders and kernel hyperparameters are chosen on simulation error, not one-step error.

Several targets (``joint_targets = true``): one job fits one model per target on the same
standardisation and folds, and every target's candidates run in one batched free run (one
time loop for all outputs instead of one per output job); each target's model is the one a
job of that target alone fits at the same point (exactly, with the exact solver; with
Nystroem centres the centres are drawn per target from the same generator in turn), and one
point (lags, gamma, lambda) is selected for all targets on their scale-free summed error.
Each output's kernel reads its own lags and the inputs; outputs do not read each other's.
``shared_kernel = true`` makes it a MIMO NARX instead: ONE kernel on the last ``kernel_lags``
lags of every output and the inputs, one linear part on every output's ``na`` lags, shared
by all outputs (``MIMOModel``): one regressor matrix, one row and centre draw, one linear
basis and one kernel factorisation per (orders, gamma), solved for the k outputs as k
right-hand sides; in the free run one exponent per centre per step serves every output.
Each output can then read another's past (an emission driven by a temperature); one job
of k outputs costs about one output's kernel work.

Defaults derived from the data:
- lags (na = nb, in samples) from {2, 4, 8, 16, 32, 64} where the training data carry them
  (``freerun.derived_orders``: at most a quarter of the shortest training segment and a
  tenth as many regressors as rows, at most ``max_lag``); nk = 0 (u(t) is a regressor,
  which also covers a one-sample delay); the kernel reads at most 8 of them. Options na,
  nb, nk fix or list them instead.
- gamma relative to d on standardised signals, {0.001, 0.01, 0.1, 1}, and lambda
  relative to the number of regression rows (lambda = lambda_rel x rows, the per-row
  convention), {1e-12, 1e-10, ..., 1e-4}: free-run selection favours smooth maps with
  little regularisation, so both grids reach far down. Neither grid depends on the
  signals' units, the sampling rate or the record length.
- exact up to 1,000 rows, else 500 Nystroem centres (on Silverbox 1,000 centres gave the
  same free-run error: at the small gammas selected the centres' kernel matrix has numerical
  rank ~100-250 anyway; a step costs half as much), solved on at most 20,000 regression
  rows (``max_rows``; a uniform subsample above). Above it the linear part is fitted again
  on every row with the kernel sum held fixed (``linear_on_all_rows``, streamed): it
  carries a lightly damped system's 64 lags, and its free run is sensitive to which rows it
  saw (f16-gvt-quick: 42.5 to 58.5 % over five seeds' subsamples with the kernel switched
  off, 50.11 % with every row). ``max_rows = 100000`` solved the kernel on five times the
  rows: Silverbox 0.394 instead of 0.432 mV, the engine campaign's hc 0.494 instead of
  0.547, at 1.8x narx's time there (its 20-minute budget; docs/benchmarks.md).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from enginebench.declare import Declaration, flag, log_grid as grid, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions, log_grid
from enginebench.methods.freerun import (ENVELOPE, GivenOrders, check_prediction_inputs, init_window, orders,
                                         training_trajectories)
from enginebench.methods.numerics.kernels import check_positive
from enginebench.methods.narx_model import (KernelBox, KernelModel, LinearBasis, MIMOModel, NARXFit, Standardised,
                                            free_run, linear_on_all_rows, mimo_free_run, mimo_regressors,
                                            nystroem_ridge, regression_count, regressors, standardise)
from enginebench.samples import Samples

NAME = "narx"
LAG_BASE = (2, 4, 8, 16, 32, 64)


# --------------------------------------------------------------------------- method
class NARX(GivenOrders, Method):
    """Kernel NARX: KRLS on lagged outputs and inputs, one step ahead; predicted in free run."""

    name = NAME
    family = "data-driven"
    modes = frozenset({"simulation"})
    joint_targets = True  # one model per target, every target's candidates in one free-run batch (module docstring)
    summary = ("kernel NARX: linear ARX part + Gaussian kernel on lagged outputs and inputs (Nystroem for large "
               "sets), selected and predicted in free run")

    declared_options = Declaration(
        orders("na", None, "output lags: None = tied to nb on a derived grid", low=1,
               why="a NARX feeds back its output; use nfir for a model of inputs only", searches=("na", "lags"),
               edges="high"),
        orders("nb", None, "input lags per input: None = tied to na on a derived grid", low=1,
               why="at least one lag of each input", searches=("nb", "lags"), edges="high"),
        orders("nk", 0, "input delay: u(t - nk) is the newest input regressor", searches=("nk",), edges="high"),
        whole("max_lag", 64, "cap of the derived lag grid", low=1, unit="samples"),
        whole("kernel_lags", 8, "the kernel reads at most this many lags of each signal (the linear part all)",
              low=1, unit="samples"),
        flag("linear", True, "an unpenalised linear ARX part beside the kernel"),
        flag("kernel_box", False, "the kernel reads its regressors clipped to the training data's range (outside "
             "it the kernel part holds its edge value and the linear part extrapolates): for records that leave "
             "the training range where the kernel blows up (docs/methods.md)"),
        flag("shared_kernel", False, "with joint_targets: ONE kernel on every output's lags and the inputs for all "
             "outputs (a MIMO NARX, each output reading every output's past; one factorisation, k right-hand "
             "sides) instead of one kernel per output"),
        grid("gamma_grid", (-3.0, 0.0, 4), "kernel widths searched: log10 of gamma relative to the regressor count d "
             "(low, high, count)", searches=("gamma",), bound=(1e-8, 1e3)),
        grid("lambda_grid", (-12.0, -4.0, 5), "ridge penalties searched: log10 of lambda relative to the number of "
             "regression rows (low, high, count)", searches=("lambda",), bound=(1e-15, 1.0)),
        whole("exact_max_rows", 1000, "every regression row a kernel centre up to this many rows, Nystroem centres "
              "above", low=1, unit="rows"),
        whole("centres", 500, "Nystroem centres (the cost of one simulated step)", low=1, unit="rows"),
        whole("max_rows", 20000, "regression rows the kernel is solved on (a uniform subsample above, the linear "
              "part then fitted again on every row; 0 = all)", low=0, unit="rows"),
        ENVELOPE,
    )

    # -- grid ---------------------------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        """Lags (tied na = nb unless given), nk, gamma and lambda (module docstring)."""
        space: SearchSpace = self.order_space(data, int(self.options["max_lag"]), LAG_BASE, tied="lags")
        space["nk"] = np.array(self.given_orders["nk"])
        space["gamma"] = log_grid(*self._grid("gamma_grid"))
        space["lambda"] = log_grid(*self._grid("lambda_grid"))
        return space

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """The declared kernel bounds and the lags the training data carry (within ``max_lag``)."""
        return {**super().search_bounds(data), **self.order_bounds(data, int(self.options["max_lag"]), "lags")}

    def _grid(self, key: str) -> tuple[float, float, int]:
        lo, hi, num = self.options[key]
        return float(lo), float(hi), int(num)

    @staticmethod
    def _point(params: Params) -> tuple[int, int, int, float, float]:
        """(na, nb, nk, gamma, lambda) of a grid point, checked."""
        keys = set(params)
        allowed = {"lags", "na", "nb", "nk", "gamma", "lambda"}
        if keys - allowed:
            raise MethodError(f"method {NAME!r}: unknown hyperparameter(s) {', '.join(sorted(keys - allowed))}; "
                              "it has lags (or na and nb), nk, gamma, lambda")
        na = params.get("na", params.get("lags"))
        nb = params.get("nb", params.get("lags"))
        missing = [k for k, v in (("na (or lags)", na), ("nb (or lags)", nb), ("nk", params.get("nk")),
                                  ("gamma", params.get("gamma")), ("lambda", params.get("lambda"))) if v is None]
        if missing:
            raise MethodError(f"method {NAME!r}: hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}")
        orders = []
        for key, v, low in (("na", na, 1), ("nb", nb, 1), ("nk", params["nk"], 0)):
            if isinstance(v, (bool, np.bool_)) or np.ndim(v) or not float(v).is_integer() or v < low:
                raise MethodError(f"method {NAME!r}: hyperparameter {key} must be a whole number >= {low}, got {v!r}")
            orders.append(int(v))
        gamma = float(check_positive(params["gamma"], "gamma")[0])
        lam = float(check_positive(params["lambda"], "lambda")[0])
        return orders[0], orders[1], orders[2], gamma, lam

    # -- fitting ------------------------------------------------------------------------------------
    def _rows(self, n: int, rng: np.random.Generator) -> np.ndarray:
        cap = int(self.options["max_rows"])
        if cap == 0 or n <= cap:
            return np.arange(n)
        return np.sort(rng.choice(n, size=cap, replace=False))

    def _kernel_lags(self, na: int, nb: int) -> tuple[int, int]:
        cap = int(self.options["kernel_lags"])
        return min(na, cap), min(nb, cap)

    @staticmethod
    def _by_orders(points: Sequence[tuple[int, int, int, float, float]]) -> dict[tuple[int, int, int], list[int]]:
        """The points' indices grouped by their orders (na, nb, nk): one regressor build per group."""
        groups: dict[tuple[int, int, int], list[int]] = {}
        for i, (na, nb, nk, _, _) in enumerate(points):
            groups.setdefault((na, nb, nk), []).append(i)
        return groups

    def _centres(self, Zk: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, str]:
        """(centres, solver): every row up to ``exact_max_rows`` rows, else ``centres`` rows drawn with ``rng``."""
        n = len(Zk)
        if n <= int(self.options["exact_max_rows"]):
            return Zk, "exact"
        return Zk[np.sort(rng.choice(n, size=min(int(self.options["centres"]), n), replace=False))], "nystroem"

    @staticmethod
    def _solutions(Zk: np.ndarray, y: np.ndarray, C: np.ndarray, basis: LinearBasis | None,
                   points: Sequence[tuple[int, int, int, float, float]], members: Sequence[int]):
        """(point, gamma, lambda, beta, theta or None, kernel rank) for each member point of one order group: one
        kernel factorisation per gamma serves its lambdas (and every column of ``y``)."""
        gammas = np.array([points[i][3] for i in members])
        for gamma in dict.fromkeys(gammas.tolist()):
            idx = [members[j] for j in np.flatnonzero(gammas == gamma)]
            lams = np.array([points[i][4] for i in idx])
            betas, thetas, rank = nystroem_ridge(Zk, y, C, gamma / Zk.shape[1], lams * len(y), basis)
            for pos, (i, lam) in enumerate(zip(idx, lams)):
                yield i, gamma, float(lam), betas[pos], None if thetas is None else thetas[pos], rank

    def _models(self, std: Standardised, k: int, points: Sequence[tuple[int, int, int, float, float]],
                rng: np.random.Generator, strict: bool = True
                ) -> tuple[list[list[KernelModel] | None], str, int, dict[str, Any]]:
        """Models for every point (one per target), sharing regressors per order and solves per gamma.

        With ``strict=False`` (selection) orders that leave too few regression rows give
        None for their points instead of an error: they score +inf, the others go on.
        """
        out: list[list[KernelModel | None]] = [[None] * k for _ in points]
        solver, n_rows, info = "exact", 0, {}
        info_rows: dict[str, int] = {}
        linear = bool(self.options["linear"])
        c = len(std.u_mean)
        for (na, nb, nk), members in self._by_orders(points).items():
            ka, kb = self._kernel_lags(na, nb)
            # kernel columns of the full lag matrix: the last ka output lags, the first kb lags of each input
            kcols = list(range(na - ka, na)) + [na + j * nb + l for j in range(c) for l in range(kb)]
            count = regression_count(std.traj, na, nb, nk)
            need = 2 + (na + c * nb + 1 if linear else 0)
            for target in range(k):
                if count < need and not strict:
                    for i in members:
                        out[i] = None  # type: ignore[call-overload]
                    break
                if count < need:
                    longest = max(len(tr.Y) for tr in std.traj)
                    raise MethodError(f"method {NAME!r}: lags na={na}, nb={nb}, nk={nk} leave {count} regression rows "
                                      f"for {need - 1} linear parameters (longest training segment {longest} rows); "
                                      "use fewer lags")
                rows = self._rows(count, rng)  # the rows drawn first, then built alone (never the whole lag matrix)
                Z, y = regressors(std.traj, target, na, nb, nk, None if len(rows) == count else rows)
                n_rows = len(y)
                Zk = np.ascontiguousarray(Z[:, kcols])
                Phi = np.hstack([Z, np.ones((n_rows, 1))]) if linear else None
                C, solver = self._centres(Zk, rng)  # one draw serves every gamma of these regressors
                basis = LinearBasis(Phi) if Phi is not None else None  # one factorisation serves every gamma
                sols = list(self._solutions(Zk, y, C, basis, points, members))
                if basis is not None and len(rows) < count:  # the linear part on every row (its long memory)
                    sols = self._linear_on_all_rows(sols, lambda r, t=target, o=(na, nb, nk): regressors(
                        std.traj, t, *o, rows=r), count, kcols, C, Zk.shape[1])
                    info_rows = {"linear_rows": count}
                for i, gamma, lam, beta, theta, rank in sols:
                    info = {"kernel_rank": rank, **info_rows}
                    th = theta if theta is not None else np.zeros(Z.shape[1] + 1)
                    out[i][target] = KernelModel(
                        na=na, nb=nb, nk=nk, ka=ka, kb=kb, a=np.ascontiguousarray(th[:na][::-1]),
                        b=np.ascontiguousarray(th[na:na + c * nb].reshape(c, nb)), c0=float(th[-1]),
                        centres=np.ascontiguousarray(C), beta=np.ascontiguousarray(beta), gamma=gamma, lam=lam,
                        target=target)
        return out, solver, n_rows, info  # type: ignore[return-value]

    @staticmethod
    def _linear_on_all_rows(sols: list, build: Any, count: int, kcols: list[int], C: np.ndarray, d: int) -> list:
        """``sols`` with each linear part fitted again on all ``count`` rows, its kernel sum held fixed: the kernel
        is solved on at most ``max_rows`` rows, the linear part (a lightly damped system's 64 lags, whose free run
        is sensitive to which rows it saw) on every one (``narx_model.linear_on_all_rows``)."""
        thetas = linear_on_all_rows(build, count, kcols, C, [(gamma / d, beta) for _, gamma, _, beta, _, _ in sols])
        return [(i, gamma, lam, beta, theta, rank) for (i, gamma, lam, beta, _, rank), theta in zip(sols, thetas)]

    def _shared(self, k: int) -> bool:
        return bool(self.options["shared_kernel"]) and k > 1

    def _mimo_models(self, std: Standardised, k: int, points: Sequence[tuple[int, int, int, float, float]],
                     rng: np.random.Generator, strict: bool = True
                     ) -> tuple[list[MIMOModel | None], str, int, dict[str, Any]]:
        """One MIMO model per point (``shared_kernel``): regressors, row draw, centres and the linear basis per
        order, one kernel factorisation per (order, gamma) solved for every output and lambda at once."""
        out: list[MIMOModel | None] = [None] * len(points)
        solver, n_rows, info = "exact", 0, {}
        info_rows: dict[str, int] = {}
        linear = bool(self.options["linear"])
        c = len(std.u_mean)
        for (na, nb, nk), members in self._by_orders(points).items():
            ka, kb = self._kernel_lags(na, nb)
            kcols = ([p * na + l for p in range(k) for l in range(na - ka, na)]
                     + [k * na + j * nb + l for j in range(c) for l in range(kb)])
            count = regression_count(std.traj, na, nb, nk)
            need = 2 + (k * na + c * nb + 1 if linear else 0)
            if count < need:
                if not strict:
                    continue
                raise MethodError(f"method {NAME!r}: lags na={na}, nb={nb}, nk={nk} leave {count} regression rows "
                                  f"for {need - 1} linear parameters per output (shared kernel over {k} outputs); "
                                  "use fewer lags")
            rows = self._rows(count, rng)
            Z, Y = mimo_regressors(std.traj, na, nb, nk, None if len(rows) == count else rows)
            n_rows = len(Y)
            Zk = np.ascontiguousarray(Z[:, kcols])
            basis = LinearBasis(np.hstack([Z, np.ones((n_rows, 1))])) if linear else None
            C, solver = self._centres(Zk, rng)
            sols = list(self._solutions(Zk, Y, C, basis, points, members))
            if basis is not None and len(rows) < count:  # the linear part on every row (its long memory)
                sols = self._linear_on_all_rows(sols, lambda r, o=(na, nb, nk): mimo_regressors(std.traj, *o, rows=r),
                                                count, kcols, C, Zk.shape[1])
                info_rows = {"linear_rows": count}
            for i, gamma, lam, beta, theta, rank in sols:
                info = {"kernel_rank": rank, **info_rows}
                th = theta if theta is not None else np.zeros((Z.shape[1] + 1, k))
                a = np.stack([th[[p * na + na - lag for p in range(k)]] for lag in range(1, na + 1)])
                out[i] = MIMOModel(na=na, nb=nb, nk=nk, ka=ka, kb=kb, a=a,
                                   b=np.ascontiguousarray(th[k * na:k * na + c * nb].reshape(c, nb, k)),
                                   c0=np.array(th[-1]), centres=np.ascontiguousarray(C),
                                   beta=np.ascontiguousarray(beta), gamma=gamma, lam=lam)
        return out, solver, n_rows, info

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> NARXFit:
        """One step ahead on the training segments; the kernel rows and centres are drawn with ``rng``."""
        self.check_mode(train.mode)
        point = self._point(params)
        std = standardise(training_trajectories(NAME, train), float(self.options["envelope"]))
        k = len(train.target_names)
        if self._shared(k):
            mimo, solver, n_rows, info = self._mimo_models(std, k, [point], rng)
            return NARXFit(models=(), y_mean=std.y_mean, y_std=std.y_std, u_mean=std.u_mean, u_std=std.u_std,
                           input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                           envelope=std.envelope, solver=solver, n_rows=n_rows, info=info, mimo=mimo[0],
                           box=self._box(std))
        models, solver, n_rows, info = self._models(std, k, [point], rng)
        return NARXFit(models=tuple(models[0]), y_mean=std.y_mean, y_std=std.y_std, u_mean=std.u_mean,
                       u_std=std.u_std, input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                       envelope=std.envelope, solver=solver, n_rows=n_rows, info=info, box=self._box(std))

    def _box(self, std: Standardised) -> KernelBox | None:
        """The training data's range the kernel's regressors are clipped to (``kernel_box``), or None."""
        return std.box if bool(self.options["kernel_box"]) else None

    # -- prediction ------------------------------------------------------------------------------
    def _simulate(self, fits: Sequence[NARXFit], data: Samples) -> list[tuple[list[np.ndarray], np.ndarray]]:
        """Free runs of every fit (all of them share the standardisation and kernel box) on ``data``: per fit
        (arrays, diverged)."""
        first = fits[0]
        check_prediction_inputs(NAME, data, len(first.input_names))
        k = len(first.target_names)
        models = [m for f in fits for m in f.models]
        results: list[list[np.ndarray | None]] = [[None] * len(data.segments) for _ in fits]
        flags = [np.zeros(len(data.segments), dtype=bool) for _ in fits]
        windows = [init_window(NAME, s, k) for s in data.segments]
        by_window: dict[int, list[int]] = {}
        for i, w in enumerate(windows):
            by_window.setdefault(len(w), []).append(i)
        for N, members in by_window.items():
            U = [(np.asarray(data.segments[i].U, dtype=np.float64) - first.u_mean) / first.u_std for i in members]
            W = [(windows[i] - first.y_mean) / first.y_std for i in members]
            lengths = [len(data.segments[i].t) for i in members]
            if first.mimo is not None:  # (fits, segments, T, k) -> (fits, k, segments, T)
                runs = mimo_free_run([f.mimo for f in fits], U, W, lengths, first.box).transpose(0, 3, 1, 2)
            else:  # (fits * k, segments, T)
                runs = free_run(models, U, W, lengths, self._limits(first, models), first.box)
                runs = runs.reshape(len(fits), k, *runs.shape[1:])
            for f_idx, f in enumerate(fits):
                for r, i in enumerate(members):
                    n = lengths[r]
                    with np.errstate(over="ignore", invalid="ignore"):  # a run that blew up is held just below
                        traj = runs[f_idx, :, r, :n].T * f.y_std + f.y_mean
                    traj[:N] = windows[i]  # the window is measured (exactly, not through the scaling)
                    traj, bad = f.envelope.clip_run(traj, N)
                    results[f_idx][i] = traj[data.segments[i].rows]
                    flags[f_idx][i] = bad
        return [(arrays, fl) for arrays, fl in zip(results, flags)]  # type: ignore[misc]

    @staticmethod
    def _limits(first: NARXFit, models: Sequence[KernelModel]) -> np.ndarray:
        """Each model's envelope in standardised units, widened by a millionth of its span: a run past it is out
        of the envelope in measured units as well, so the free run may stop simulating it (``free_run``)."""
        lower = (first.envelope.lower - first.y_mean) / first.y_std
        upper = (first.envelope.upper - first.y_mean) / first.y_std
        margin = 1e-6 * np.where(np.isfinite(upper - lower), upper - lower, 0.0)
        targets = [m.target for m in models]
        return np.stack([lower[targets] - margin[targets], upper[targets] + margin[targets]], axis=1)

    def predict(self, fitted: NARXFit, data: Samples) -> SegmentPredictions:
        """Free run of every segment from its init window, all segments batched."""
        if not data.segments:
            return SegmentPredictions([], [])
        arrays, flags = self._simulate([fitted], data)[0]
        return SegmentPredictions(arrays, flags)

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Free runs of ``data`` for every grid point, (n_grid, rows, targets), all simulated in one time loop.

        Regressors are built once per order, kernel solves shared per (order, gamma)
        across lambdas; the grid points' free runs are one batch (models x segments).
        """
        self.check_mode(train.mode)
        points = [self._point(p) for p in grid]
        k = len(train.target_names)
        out = np.empty((len(grid), len(data), k))
        if not points or not data.segments:
            return out
        std = standardise(training_trajectories(NAME, train), float(self.options["envelope"]))
        shared = self._shared(k)
        models, solver, n_rows, info = (self._mimo_models if shared else self._models)(std, k, points, rng,
                                                                                      strict=False)
        usable = [i for i, ms in enumerate(models) if ms is not None]
        out[[i for i in range(len(points)) if i not in usable]] = np.nan  # too few rows for these lags: +inf score
        if not usable:
            return out
        box = self._box(std)
        fits = [NARXFit(models=() if shared else tuple(models[i]), y_mean=std.y_mean, y_std=std.y_std,  # type: ignore
                        u_mean=std.u_mean, u_std=std.u_std, input_names=tuple(train.input_names),
                        target_names=tuple(train.target_names), envelope=std.envelope, solver=solver, n_rows=n_rows,
                        mimo=models[i] if shared else None, box=box) for i in usable]  # type: ignore[arg-type]
        for i, (arrays, _) in zip(usable, self._simulate(fits, data)):
            out[i] = np.concatenate(arrays)
        return out

    def describe(self, fitted: NARXFit) -> dict[str, Any]:
        """Orders, kernel hyperparameters, the linear part (standardised) with its poles, solver facts."""
        if fitted.mimo is not None:
            return self._describe_mimo(fitted)
        m = fitted.models[0]
        linear = {}
        for name, mod in zip(fitted.target_names, fitted.models):
            poles = np.roots(np.r_[1.0, -mod.a]) if mod.a.any() else np.empty(0)
            radius = float(np.abs(poles).max()) if poles.size else 0.0
            linear[name] = {"a": mod.a.tolist(), "b": mod.b.tolist(), "c0": mod.c0, "max_pole_modulus": radius,
                            "stable": bool(radius < 1.0)}
        return {
            "na": m.na, "nb": m.nb, "nk": m.nk, "kernel_lags": [m.ka, m.kb],
            "gamma_relative": m.gamma, "gamma": m.gamma / m.d,
            "lambda_relative": m.lam, "lambda": m.lam * fitted.n_rows,
            "regressors": m.d,
            "solver": fitted.solver,
            "centres": int(len(m.beta)),
            "regression_rows": fitted.n_rows,
            "model": "y(t) = a . [y(t-1)..y(t-na)] + b . [u(t-nk)..u(t-nk-nb+1)] + c0 + sum_i beta_i exp(-gamma "
                     "|z(t) - c_i|^2), z(t) = [y(t-ka)..y(t-1), u(t-nk)..u(t-nk-kb+1)], standardised signals, "
                     "one model per target",
            "linear_part": linear if bool(self.options["linear"]) else None,
            "standardisation": {"y_mean": fitted.y_mean.tolist(), "y_std": fitted.y_std.tolist(),
                                "u_mean": fitted.u_mean.tolist(), "u_std": fitted.u_std.tolist()},
            "envelope": {"lower": fitted.envelope.lower.tolist(), "upper": fitted.envelope.upper.tolist()},
            "kernel_box": _box_facts(fitted),
            **fitted.info,
        }

    def _describe_mimo(self, fitted: NARXFit) -> dict[str, Any]:
        """``describe`` of a shared-kernel model: the linear part's stability from its MIMO companion matrix."""
        m = fitted.mimo
        assert m is not None
        k = m.k
        comp = np.zeros((m.na * k, m.na * k))  # state [y(t-1) .. y(t-na)], each a k-vector
        comp[:k] = np.hstack([m.a[i].T for i in range(m.na)])
        comp[k:, :-k] = np.eye((m.na - 1) * k)
        radius = float(np.abs(np.linalg.eigvals(comp)).max()) if comp.size else 0.0
        return {
            "na": m.na, "nb": m.nb, "nk": m.nk, "kernel_lags": [m.ka, m.kb], "shared_kernel": True,
            "gamma_relative": m.gamma, "gamma": m.gamma / m.d, "lambda_relative": m.lam,
            "lambda": m.lam * fitted.n_rows, "regressors": m.d, "solver": fitted.solver, "centres": int(len(m.beta)),
            "regression_rows": fitted.n_rows,
            "model": "y_o(t) = sum_p a_p,o . [y_p(t-1)..y_p(t-na)] + b_o . [u(t-nk)..u(t-nk-nb+1)] + c0_o + sum_i "
                     "beta_i,o exp(-gamma |z(t) - c_i|^2), z(t) = [y_p(t-ka)..y_p(t-1) for every output p, "
                     "u(t-nk)..u(t-nk-kb+1)], standardised signals, one kernel for all outputs",
            "linear_part": ({"max_pole_modulus": radius, "stable": bool(radius < 1.0)}
                            if bool(self.options["linear"]) else None),
            "standardisation": {"y_mean": fitted.y_mean.tolist(), "y_std": fitted.y_std.tolist(),
                                "u_mean": fitted.u_mean.tolist(), "u_std": fitted.u_std.tolist()},
            "envelope": {"lower": fitted.envelope.lower.tolist(), "upper": fitted.envelope.upper.tolist()},
            "kernel_box": _box_facts(fitted),
            **fitted.info,
        }

    def c_model(self, fitted):
        """The C step of ``fitted`` for an FMU and the real-time figures (``methods/export``)."""
        from enginebench.methods.export.models import narx_c, narx_mimo_c

        return narx_mimo_c(fitted) if fitted.mimo is not None else narx_c(fitted)

    def step_times(self, fitted, data):
        """Its C step timed over ``data`` for the real-time figures (``methods/export/harness.py``)."""
        from enginebench.methods.export.harness import c_step_times

        return c_step_times(self.c_model(fitted), data)


def _box_facts(fitted: NARXFit) -> dict[str, list[list[float]]] | None:
    """The range the kernel's regressors are clipped to, in the signals' units: [low, high] per input and output."""
    box = fitted.box
    if box is None:
        return None
    inputs = np.stack([box.u_lo, box.u_hi], axis=1) * fitted.u_std[:, None] + fitted.u_mean[:, None]
    outputs = np.stack([box.y_lo, box.y_hi], axis=1) * fitted.y_std[:, None] + fitted.y_mean[:, None]
    return {"inputs": inputs.tolist(), "outputs": outputs.tolist()}
