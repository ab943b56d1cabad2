"""Peers: the field's maintained identification libraries as thin adapters under enginebench's protocol.

Optional: ``pip install "enginebench[peers]"`` installs them. The adapters call the
libraries' public APIs and add only what the protocol needs: whole training segments
in, free-run predictions from the state initialisation window out, divergence flags,
and hyperparameters searched by the toolkit's selection on free-run error.

- ``sysidentpy-narx``: SysIdentPy's polynomial NARX, structure by FROLS (forward
  regression orthogonal least squares, the number of terms by SysIdentPy's information
  criterion, AIC by default), parameters by least squares. Searched: polynomial degree
  (1-3) and lags (``ylag = xlag``, samples, on ``LAG_LADDER`` up to 10 within what the data
  carry; SysIdentPy's input lags start at 1). The criterion's curve over 1 ..
  ``n_info_values`` terms is read off one forward regression (``_prefix_information_criterion``:
  the same values as SysIdentPy's own loop, which reruns the regression once per term
  count, 7x the time at degree 2, lags 10). A (degree, lags) point whose candidate set exceeds
  ``max_candidates`` terms is skipped by the grid with its reason noted. Free run through
  SysIdentPy's ``predict`` with the last ``max_lag`` outputs of the init window as initial
  conditions (edge padded when the window is shorter).
- ``n4sid``: a linear state-space model x+ = A x + B u, y = C x + D u by subspace
  identification (the ``nfoursid`` package, PO-MOESP/N4SID). Searched: the state order
  (``ORDER_LADDER`` up to 32); an order the data cannot carry (too few samples for its
  block Hankel matrices, a failed or singular decomposition) is left out or skipped with
  its reason noted (``describe()["skipped"]``), never failing the job.
  The initial state is the least-squares fit of the init window's measured outputs given
  its inputs (y_t = C A^t x0 + forced response); with y0 alone it is the minimum-norm
  state reproducing y0.

Both libraries take one trajectory: several training segments are concatenated (the few
samples after each boundary then mix two records; fine for a few long records, stated
here because it is not the libraries' fault). ``nfoursid`` computes a full singular value
decomposition whose right factor is n x n (n samples: 3 GB at n = 20,000), so ``n4sid``
hands it at most ``max_samples`` (default 5,000) samples, the first ones of the longest
training segment; a linear model of a few dozen parameters needs no more. Signals are standardised with training
statistics before they are handed over, for the libraries' numerical conditioning; the
results are returned in the data's units.
"""

from __future__ import annotations

import importlib.util
import math
import types
import warnings
from dataclasses import dataclass
from typing import Any, ClassVar, Sequence

import numpy as np

from enginebench.declare import Declaration, choice, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.freerun import (ENVELOPE, Envelope, Trajectory, as_orders, carried_order,
                                         check_prediction_inputs, derived_orders, init_window, orders, padded_past,
                                         training_trajectories)
from enginebench.samples import Samples

INSTALL = 'pip install "enginebench[peers]"'
INFO_CRITERIA = ("aic", "aicc", "bic", "fpe", "lilc")
LAG_LADDER = (1, 2, 4, 6, 8, 10)
"""``sysidentpy-narx``'s lags (ylag = xlag) searched by default, within what the data carry."""
LAG_BOUND = 32
"""The most lags model selection extends ``sysidentpy-narx``'s grid to when the best lags sit at its top (within what
the data carry): past it even degree 2 has over 2,000 FROLS candidates with one input, the default
``max_candidates``."""
ORDER_LADDER = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32)
"""``n4sid``'s state orders searched by default, within what the data carry."""
DEGREE_BOUND = 3
"""``sysidentpy-narx``'s highest polynomial degree: its documentation's examples use 2, some 3, and past 3 FROLS's
candidate set outgrows ``max_candidates`` at all but the smallest lags."""
ORDER_BOUND = 64
"""The highest state order model selection extends ``n4sid``'s grid to when the best order sits at its top (within
what the data carry: ``N4SID._infeasible``)."""


class Infeasible(MethodError):
    """A grid point the training data cannot carry: the grid skips it (noted), ``fit`` refuses it."""

    def __init__(self, who: str, reason: str) -> None:
        super().__init__(f"method {who!r}: {reason}")
        self.who, self.reason = who, reason

    def __reduce__(self) -> tuple[type, tuple[str, str]]:
        return type(self), (self.who, self.reason)


def _missing(module: str) -> str | None:
    """Why the peer cannot run here (its package is not installed), or None."""
    try:
        found = importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):  # a broken or blocked installation counts as absent
        found = False
    return None if found else f"needs the optional package {module!r}: {INSTALL}"


class PeerMethod(Method):
    """A method backed by an optional package; refuses to be built (one line, exit 2) when it is absent."""

    family = "data-driven"
    modes = frozenset({"simulation"})
    package: ClassVar[str] = ""

    @classmethod
    def available(cls) -> str | None:
        """None when the method can run; otherwise why not and the install command."""
        return _missing(cls.package)

    def __init__(self, **options: Any) -> None:
        reason = self.available()
        if reason:
            raise MethodError(f"method {self.name!r} {reason}")
        super().__init__(**options)
        self.skipped: list[str] = []
        """Grid values left out or skipped in the last search, each with its reason (``describe()["skipped"]``)."""

    def note_skipped(self, reason: str) -> None:
        """Record a grid value the data cannot carry (once)."""
        if reason not in self.skipped:
            self.skipped.append(reason)

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Each point fitted and predicted; a point the data cannot carry (``Infeasible``) scores +inf (NaN), noted,
        and the others go on."""
        out = np.empty((len(grid), len(data), len(train.target_names)))
        for i, params in enumerate(grid):
            try:
                fitted = self.fit(train, params, rng)
            except Infeasible as exc:
                self.note_skipped(exc.reason)
                out[i] = np.nan
                continue
            if data.segments:
                out[i] = np.concatenate(self.predict(fitted, data))
        return out

    def _with_skipped(self, described: dict[str, Any]) -> dict[str, Any]:
        if self.skipped:
            described["skipped"] = list(self.skipped)
        return described


def _summary(package: str, text: str) -> str:
    reason = _missing(package)
    return text if reason is None else f"UNAVAILABLE ({INSTALL}): {text}"


@dataclass(frozen=True)
class _Scaling:
    u_mean: np.ndarray
    u_std: np.ndarray
    y_mean: np.ndarray
    y_std: np.ndarray

    @classmethod
    def of(cls, traj: Sequence[Trajectory]) -> "_Scaling":
        U, Y = np.vstack([t.U for t in traj]), np.vstack([t.Y for t in traj])
        u_std, y_std = U.std(axis=0), Y.std(axis=0)
        return cls(U.mean(axis=0), np.where(u_std > 0, u_std, 1.0), Y.mean(axis=0), np.where(y_std > 0, y_std, 1.0))

    def u(self, U: np.ndarray) -> np.ndarray:
        return (U - self.u_mean) / self.u_std

    def y(self, Y: np.ndarray) -> np.ndarray:
        return (Y - self.y_mean) / self.y_std

    def y_back(self, Y: np.ndarray) -> np.ndarray:
        return Y * self.y_std + self.y_mean


def _whole(traj: Sequence[Trajectory], scaling: _Scaling) -> tuple[np.ndarray, np.ndarray]:
    """Standardised training segments concatenated: inputs (n, c), outputs (n, k)."""
    return scaling.u(np.vstack([t.U for t in traj])), scaling.y(np.vstack([t.Y for t in traj]))


def _predictions(who: str, data: Samples, k: int, envelope: Envelope, run) -> SegmentPredictions:
    """Per segment: ``run(U, window)`` gives the (n, k) trajectory (window rows included); envelope applied."""
    arrays, flags = [], []
    for s in data.segments:
        window = init_window(who, s, k)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            traj = np.asarray(run(np.asarray(s.U, dtype=np.float64), window), dtype=np.float64)
        traj[:len(window)] = window
        traj, bad = envelope.clip_run(traj, len(window))
        arrays.append(traj[s.rows])
        flags.append(bad)
    return SegmentPredictions(arrays, flags)


def _whole_number(who: str, params: Params, key: str, low: int) -> int:
    if key not in params:
        raise MethodError(f"method {who!r}: hyperparameter {key} missing from {dict(params)!r}")
    v = params[key]
    if isinstance(v, (bool, np.bool_)) or np.ndim(v) or not float(v).is_integer() or v < low:
        raise MethodError(f"method {who!r}: hyperparameter {key} must be a whole number >= {low}, got {v!r}")
    return int(v)


# --------------------------------------------------------------------------- SysIdentPy
def candidate_terms(degree: int, lags: int, n_inputs: int) -> int:
    """FROLS's candidate set: every monomial up to ``degree`` of the lags x (1 + inputs) lagged signals, constant
    included."""
    return math.comb(lags * (1 + n_inputs) + degree, degree)


def _prefix_information_criterion(self: Any, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """SysIdentPy's information criterion of the FROLS models with 1 .. n_info_values terms, from one regression.

    FROLS picks terms greedily, so the model with i terms is the first i terms of the model with
    n_info_values; SysIdentPy's own ``information_criterion`` reruns the regression for each i. Here
    the terms are picked once and each prefix is estimated and scored as SysIdentPy does (its
    estimator, its criterion function, the residual variance with ddof 1): the same values.
    """
    count = min(int(self.n_info_values), x.shape[1])  # SysIdentPy's own cap: no more terms than candidates
    self.n_info_values = count
    _, _, psi, target = self._unpack_mss_output(self.run_mss_algorithm(x, y, count), y)
    n_samples = y.shape[0] - self.max_lag
    values = np.full(count, np.nan)
    for i in range(count):
        columns = psi[:, :i + 1]
        residual = target - columns @ self.estimator.optimize(columns, target)
        values[i] = self.info_criteria_function(i + 1, n_samples, float(np.var(residual, ddof=1)))
    return values


@dataclass(frozen=True)
class SysIdentPyFit:
    models: tuple[Any, ...]
    """One fitted ``sysidentpy`` FROLS model per target."""
    degree: int
    lags: int
    scaling: _Scaling
    envelope: Envelope
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]


class SysIdentPyNARX(PeerMethod):
    """SysIdentPy's polynomial NARX (FROLS structure selection, least squares), simulated in free run."""

    name = "sysidentpy-narx"
    package = "sysidentpy"
    summary = _summary("sysidentpy", "peer: SysIdentPy polynomial NARX, FROLS structure selection (degree 1-3, lags "
                                     "up to 10 searched, terms by information criterion), least squares, free run")

    declared_options = Declaration(
        orders("degrees", (1, 2, 3), "polynomial degrees searched", low=1, searches=("degree",), edges="high",
               high=5, type_label="int in [1, 5] | list[int]", unit="",
               message="{name}={value} must list degrees from 1 to 5"),
        orders("lags", None, "ylag = xlag: None = derived from {" + ", ".join(map(str, LAG_LADDER)) + "} within what "
               "the data carry", low=1, searches=("lags",), edges="high"),
        whole("n_info_values", 30, "FROLS considers at most this many terms (the information criterion picks the "
              "count; a job warns when it kept falling up to this cap)", low=1),
        choice("info_criteria", "aic", "information criterion of FROLS's term count", INFO_CRITERIA,
               message="{name} must be one of " + ", ".join(INFO_CRITERIA) + ", got {value}"),
        whole("max_candidates", 2000, "a (degree, lags) point with more FROLS candidate terms is skipped by the grid "
              "(its regressor matrix is rows x candidates)", low=1, unit="terms"),
        ENVELOPE,
    )

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self._lags = as_orders(self.options["lags"])
        self._degrees = as_orders(self.options["degrees"])

    def search_space(self, data: Samples) -> SearchSpace:
        """Degrees as given; lags as given or ``LAG_LADDER`` within what the data carry (the others noted)."""
        self.skipped = []
        sizes = [len(s) for s in data.segments] or [0]
        if self._lags:
            lags = self._lags
        else:
            lags = derived_orders(min(sizes), sum(sizes), len(data.input_names), max(LAG_LADDER), LAG_LADDER)
            for lag in sorted(set(LAG_LADDER) - set(lags)):
                self.note_skipped(f"lags {lag} left out: a quarter of the shortest training segment ({min(sizes)} "
                                  f"samples) or a tenth of the {sum(sizes)} training rows per parameter is less")
        return {"degree": np.array(self._degrees), "lags": np.array(lags)}

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """Lags from 1 to what the data carry (``derived_orders``' rules) within ``LAG_BOUND``: a best lags at the
        grid's top is searched further, as SysIdentPy's users would, instead of left to a "widen" warning. The
        degree's bound is ``DEGREE_BOUND`` (or the highest degree asked for): a best degree 3 is said to be at it."""
        sizes = [len(s) for s in data.segments] or [0]
        lags = float(max(carried_order(min(sizes), sum(sizes), len(data.input_names), LAG_BOUND), 1))
        return {"lags": (1.0, lags), "degree": (1.0, float(max(DEGREE_BOUND, *self._degrees)))}

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> SysIdentPyFit:
        """FROLS per target on the concatenated standardised training segments. ``rng`` is not drawn from."""
        from sysidentpy.basis_function import Polynomial
        from sysidentpy.model_structure_selection import FROLS
        from sysidentpy.parameter_estimation import LeastSquares

        self.check_mode(train.mode)
        degree = _whole_number(self.name, params, "degree", 1)
        lags = _whole_number(self.name, params, "lags", 1)
        traj = training_trajectories(self.name, train)
        scaling = _Scaling.of(traj)
        U, Y = _whole(traj, scaling)
        terms, cap = candidate_terms(degree, lags, U.shape[1]), int(self.options["max_candidates"])
        if terms > cap:
            raise Infeasible(self.name, f"degree {degree}, lags {lags} give {terms} candidate terms, over "
                                        f"max_candidates = {cap}; raise max_candidates or use lower degrees or lags")
        if len(U) - lags < 2:
            raise Infeasible(self.name, f"lags {lags} leave fewer than 2 regression rows in {len(U)} training samples; "
                                        "use lower lags")
        models = []
        for j in range(Y.shape[1]):
            model = FROLS(order_selection=True, n_info_values=int(self.options["n_info_values"]), ylag=lags,
                          xlag=[list(range(1, lags + 1))] * U.shape[1] if U.shape[1] > 1 else lags,
                          info_criteria=str(self.options["info_criteria"]), estimator=LeastSquares(),
                          basis_function=Polynomial(degree=degree), model_type="NARMAX")
            # SysIdentPy's criterion, read off one regression (same values); the instance override is removed after
            # fitting, so the model pickles and behaves as a plain FROLS
            model.information_criterion = types.MethodType(_prefix_information_criterion, model)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    model.fit(X=U, y=Y[:, j:j + 1])
            except (ValueError, np.linalg.LinAlgError) as exc:
                raise Infeasible(self.name, f"SysIdentPy could not fit degree {degree}, lags {lags}: "
                                            f"{str(exc).splitlines()[0]}") from exc
            finally:
                del model.information_criterion
            models.append(model)
        env = Envelope.around(np.vstack([t.Y for t in traj]), float(self.options["envelope"]))
        return SysIdentPyFit(tuple(models), degree, lags, scaling, env, tuple(train.input_names),
                             tuple(train.target_names))

    def predict(self, fitted: SysIdentPyFit, data: Samples) -> SegmentPredictions:
        """SysIdentPy's free run from the last max_lag measured outputs of each init window."""
        check_prediction_inputs(self.name, data, len(fitted.input_names))
        sc = fitted.scaling

        def run(U: np.ndarray, window: np.ndarray) -> np.ndarray:
            N, n = len(window), len(U)
            out = np.empty((n, window.shape[1]))
            Us, Ws = sc.u(U), sc.y(window)
            for j, model in enumerate(fitted.models):
                lag = int(model.max_lag)
                # the simulation starts at row N: its initial conditions are rows N - lag .. N - 1 (edge padded)
                start = N - lag
                pad = max(0, -start)
                X = padded_past(Us, pad)[start + pad:]
                y_init = padded_past(Ws[:, j:j + 1], pad)[start + pad:start + pad + lag]
                yhat = np.asarray(model.predict(X=X, y=y_init)).reshape(-1)
                out[N:, j] = yhat[lag:lag + n - N]
            return sc.y_back(out)

        return _predictions(self.name, data, len(fitted.target_names), fitted.envelope, run)

    def describe(self, fitted: SysIdentPyFit) -> dict[str, Any]:
        from sysidentpy.utils.display_results import results

        out: dict[str, Any] = {"degree": fitted.degree, "lags": fitted.lags, "package": "sysidentpy",
                               "units": "standardised signals (training mean and std)", "targets": {}}
        cap, criterion, capped = int(self.options["n_info_values"]), str(self.options["info_criteria"]), []
        for name, model in zip(fitted.target_names, fitted.models):
            rows = results(model.final_model, model.theta, model.err, model.n_terms, err_precision=6, dtype="dec")
            values = [float(v) for v in np.asarray(model.info_values).reshape(-1)]
            out["targets"][name] = {"terms": [[r[0], float(r[1])] for r in rows], "n_terms": len(rows),
                                    "info_criteria": criterion, "info_values": values}
            if len(values) == cap and int(model.n_terms) == cap:
                capped.append(name)
        if capped:
            out["warnings"] = [f"the information criterion ({criterion}) kept falling up to n_info_values = {cap} "
                               f"terms ({', '.join(capped)}); raise n_info_values"]
        return self._with_skipped(out)


# --------------------------------------------------------------------------- N4SID (nfoursid)
@dataclass(frozen=True)
class StateSpaceFit:
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    order: int
    block_rows: int
    scaling: _Scaling
    envelope: Envelope
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]


def simulate_state_space(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, x0: np.ndarray,
                         U: np.ndarray) -> np.ndarray:
    """y_t = C x_t + D u_t, x_{t+1} = A x_t + B u_t from x0 over the inputs U (n, c): (n, k)."""
    n = len(U)
    X = np.empty((n, len(x0)))
    BU = U @ B.T
    x = np.asarray(x0, dtype=np.float64)
    At = A.T
    for t in range(n):
        X[t] = x
        x = x @ At + BU[t]
    return X @ C.T + U @ D.T


def initial_state(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, U: np.ndarray,
                  window: np.ndarray) -> np.ndarray:
    """Least-squares x0 from the window's outputs (N, k) and inputs U[:N]: min |O x0 - (y - forced)|, min-norm."""
    N, nx = len(window), A.shape[0]
    forced = simulate_state_space(A, B, C, D, np.zeros(nx), U[:N])
    O = np.empty((N, C.shape[0], nx))
    M = C.copy()
    for t in range(N):
        O[t] = M
        M = M @ A
    x0, *_ = np.linalg.lstsq(O.reshape(N * C.shape[0], nx), (window - forced).reshape(-1), rcond=None)
    return x0


class N4SID(PeerMethod):
    """Linear state-space model by subspace identification (nfoursid), simulated from an estimated initial state."""

    name = "n4sid"
    package = "nfoursid"
    summary = _summary("nfoursid", "peer: linear state-space model by subspace identification (nfoursid), order "
                                   "up to 32 searched, state estimated on the init window, free run")

    declared_options = Declaration(
        orders("orders", None, "state orders searched: None = {" + ", ".join(map(str, ORDER_LADDER)) + "} within what "
               "the data carry (the others noted)", low=1, searches=("order",), edges="high"),
        whole("block_rows", None, "Hankel block rows: None = 1.5 x the order / outputs, at least 2", low=1,
              nullable=True),
        whole("max_samples", 5000, "samples handed to nfoursid (its full SVD forms an n x n factor)", low=10,
              unit="samples"),
        ENVELOPE,
    )

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        self._orders = as_orders(self.options["orders"])

    def search_space(self, data: Samples) -> SearchSpace:
        """Orders as given, or the ``ORDER_LADDER`` orders the data can carry (the others noted in ``skipped``)."""
        self.skipped = []
        if self._orders:
            return {"order": np.array(self._orders)}
        sizes = [len(s) for s in data.segments] or [0]
        n = self._samples_used(sizes)
        m, k = len(data.input_names), max(1, len(data.target_names))
        kept = []
        for order in ORDER_LADDER:
            reason = self._infeasible(order, n, m, k)
            if reason is None:
                kept.append(order)
            else:
                self.note_skipped(f"order {order} left out: {reason}")
        return {"order": np.array(kept or [min(ORDER_LADDER)])}

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """Orders from 1 to the highest the data carry (``_infeasible``) within ``ORDER_BOUND``: a best order at
        the grid's top is searched further instead of left to a "widen" warning."""
        sizes = [len(s) for s in data.segments] or [0]
        n = self._samples_used(sizes)
        m, k = len(data.input_names), max(1, len(data.target_names))
        top = next((o for o in range(ORDER_BOUND, 0, -1) if self._infeasible(o, n, m, k) is None), 1)
        return {"order": (1.0, float(top))}

    def _samples_used(self, sizes: Sequence[int]) -> int:
        """How many samples ``_fit_orders`` hands nfoursid: all, or at most ``max_samples`` of the longest segment."""
        cap = int(self.options["max_samples"])
        return int(sum(sizes)) if sum(sizes) <= cap else min(max(sizes), cap)

    def _block_rows(self, order: int, k: int) -> int:
        br = self.options["block_rows"]
        return int(br) if br is not None else max(2, math.ceil(1.5 * order / k))

    def _infeasible(self, order: int, n: int, m: int, k: int) -> str | None:
        """Why ``n`` samples of ``m`` inputs and ``k`` outputs cannot carry ``order`` (None when they can)."""
        br = self._block_rows(order, k)
        if order > br * k:
            return f"order {order} exceeds block_rows x outputs = {br * k}; raise block_rows"
        need = 4 * br * (m + k)
        if n < need:
            return (f"{n} training samples are too few for the {br} Hankel block rows of order {order} (needs {need}); "
                    "use lower orders")
        return None

    def _identify(self, U: np.ndarray, Y: np.ndarray, block_rows: int):
        import pandas as pd
        from nfoursid.nfoursid import NFourSID

        cols_u = [f"u{j}" for j in range(U.shape[1])]
        cols_y = [f"y{j}" for j in range(Y.shape[1])]
        frame = pd.DataFrame(np.hstack([U, Y]), columns=cols_u + cols_y)
        sid = NFourSID(frame, output_columns=cols_y, input_columns=cols_u, num_block_rows=block_rows)
        sid.subspace_identification()
        return sid

    def _fit_orders(self, train: Samples, orders: Sequence[int]) -> list[StateSpaceFit | Infeasible]:
        """A fit per order; an order the data cannot carry is its ``Infeasible`` (grids skip it, ``fit`` raises it)."""
        self.check_mode(train.mode)
        traj = training_trajectories(self.name, train)
        scaling = _Scaling.of(traj)
        U, Y = _whole(traj, scaling)
        cap = int(self.options["max_samples"])
        if len(U) > cap:  # the first samples of the longest segment: one contiguous record, no boundary
            longest = max(traj, key=lambda t: len(t.Y))
            U, Y = _whole([Trajectory(longest.id, longest.U[:cap], longest.Y[:cap])], scaling)
        k = Y.shape[1]
        env = Envelope.around(np.vstack([t.Y for t in traj]), float(self.options["envelope"]))
        fits: list[StateSpaceFit | Infeasible] = []
        cache: dict[int, Any] = {}
        for order in orders:
            br = self._block_rows(order, k)
            reason = self._infeasible(order, len(U), U.shape[1], k)
            if reason is not None:
                fits.append(Infeasible(self.name, reason))
                continue
            try:
                if br not in cache:
                    cache[br] = self._identify(U, Y, br)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    ss, _ = cache[br].system_identification(rank=order)
                mats = [np.array(mat, dtype=np.float64, order="C") for mat in (ss.a, ss.b, ss.c, ss.d)]  # pickle-stable
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                fits.append(Infeasible(self.name, f"nfoursid could not identify order {order}: "
                                                  f"{str(exc).splitlines()[0]}; use lower orders"))
                continue
            if mats[0].shape != (order, order) or not all(np.isfinite(mat).all() for mat in mats):
                fits.append(Infeasible(self.name, f"nfoursid's order-{order} model is singular (A {mats[0].shape}, "
                                                  "non-finite or short of the order); use lower orders"))
                continue
            fits.append(StateSpaceFit(*mats, order, br, scaling, env, tuple(train.input_names), tuple(train.target_names)))
        return fits

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> StateSpaceFit:
        """Subspace identification on the concatenated standardised training segments. ``rng`` is not drawn from."""
        (fitted,) = self._fit_orders(train, [_whole_number(self.name, params, "order", 1)])
        if isinstance(fitted, Infeasible):
            raise fitted
        return fitted

    def predict(self, fitted: StateSpaceFit, data: Samples) -> SegmentPredictions:
        """Free run from the state fitted to each init window."""
        check_prediction_inputs(self.name, data, len(fitted.input_names))
        sc = fitted.scaling

        def run(U: np.ndarray, window: np.ndarray) -> np.ndarray:
            Us = sc.u(U)
            x0 = initial_state(fitted.A, fitted.B, fitted.C, fitted.D, Us, sc.y(window))
            return sc.y_back(simulate_state_space(fitted.A, fitted.B, fitted.C, fitted.D, x0, Us))

        return _predictions(self.name, data, len(fitted.target_names), fitted.envelope, run)

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """One subspace decomposition serves every order; an order the data cannot carry scores +inf (NaN), the
        others go on."""
        out = np.empty((len(grid), len(data), len(train.target_names)))
        fits = self._fit_orders(train, [_whole_number(self.name, p, "order", 1) for p in grid])
        for i, fitted in enumerate(fits):
            if isinstance(fitted, Infeasible):
                self.note_skipped(fitted.reason)
                out[i] = np.nan
            elif data.segments:
                out[i] = np.concatenate(self.predict(fitted, data))
        return out

    def describe(self, fitted: StateSpaceFit) -> dict[str, Any]:
        poles = np.linalg.eigvals(fitted.A)
        radius = float(np.abs(poles).max()) if poles.size else 0.0
        return self._with_skipped({
            "order": fitted.order, "block_rows": fitted.block_rows, "package": "nfoursid",
            "poles": [[float(p.real), float(p.imag)] for p in poles],
            "max_pole_modulus": radius, "stable": bool(radius < 1.0),
            "A": fitted.A.tolist(), "B": fitted.B.tolist(), "C": fitted.C.tolist(), "D": fitted.D.tolist(),
            "units": "standardised signals (training mean and std)",
        })
