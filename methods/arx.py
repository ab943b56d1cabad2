"""``arx``: linear ARX, fitted by least squares one step ahead, simulated in free run.

For each target y (one MISO model per target: its own past outputs and every run-time
input u_j; other targets' outputs are not regressors)::

    y(t) = a_1 y(t-1) + ... + a_na y(t-na)
           + sum_j [ b_j0 u_j(t-nk) + b_j1 u_j(t-nk-1) + ... + b_j(nb-1) u_j(t-nk-nb+1) ] + c

i.e. A(q) y = sum_j B_j(q) u_j + c with A(q) = 1 - a_1 q^-1 - ... - a_na q^-na and
B_j(q) = q^-nk (b_j0 + b_j1 q^-1 + ... ), the convention of identification textbooks
(orders in samples; nk = 0 means a direct feedthrough from u(t)).

Fitting: ordinary least squares on measured outputs (the one-step-ahead, equation-error
estimate). Every grid point of a fit is read from one Gram matrix of the grid's longest lags
per target and solved by the corrected semi-normal equations (Cholesky of the equilibrated
normal matrix plus one refinement step on the true residual; ``numerics/lag_gram.py``); a point
whose equilibrated condition number exceeds 1e6 (or whose columns are dependent) is solved by
``scipy.linalg.lstsq`` (LAPACK's SVD-based gelsd) on its own regression matrix instead. Regression rows start where every lag lies inside its training
segment: lags never cross a segment boundary.

Simulation: free run from the state initialisation window. The first lagged outputs are
the window's measured ones (``y_init``, or ``y0`` alone without a window; a window shorter
than na is padded with its earliest value, as are inputs before the first sample); after
the window only simulated outputs are fed back. The recursion is run by
``scipy.signal.lfilter`` with initial conditions from ``lfiltic`` (exactly the recursion,
in C), one call per segment. A run that leaves the envelope around the training outputs
or goes non-finite (an unstable A(q)) is held and flagged diverged (``methods/freerun.py``).

Default orders (no option given), in samples: na = nb = ``order`` from {1, 2, 4, ..., 128},
keeping the orders the training data can carry (at most ``max_order``, a quarter of the
shortest training segment, and a tenth as many parameters as training rows; see
``freerun.derived_orders``), nk from {0, 1}: 16 candidates at most. Orders are tied so that
the grid can reach the long memories of lightly damped systems sampled fast (F-16 at
400 Hz wants order ~64) without a product grid; options ``na`` and ``nb`` (numbers or
lists) search them separately instead. The toolkit's selection picks the orders on the
free-run error of validation blocks, like every hyperparameter.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from enginebench.declare import Declaration, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.freerun import (ENVELOPE, Envelope, GivenOrders, Trajectory, check_prediction_inputs,
                                         init_window, orders, padded_past, training_trajectories)
from enginebench.methods.numerics.lag_gram import LagGram, Orders
from enginebench.samples import Samples

NAME = "arx"
DEFAULT_NK = (0, 1)
ORDER_BASE = (1, 2, 4, 8, 16, 32, 64, 128)


@dataclass(frozen=True)
class ARXFit:
    """A fitted ARX model per target: ``a`` (k, na), ``b`` (k, inputs, nb), offset ``c`` (k,)."""

    na: int
    nb: int
    nk: int
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    envelope: Envelope
    n_rows: int

    @property
    def max_lag(self) -> int:
        return max(self.na, self.nk + self.nb - 1)


# --------------------------------------------------------------------------- numerics
def regression(traj: Sequence[Trajectory], target: int, na: int, nb: int, nk: int) -> tuple[np.ndarray, np.ndarray]:
    """Stacked regressors [y(t-1..t-na), u_j(t-nk..t-nk-nb+1) per input, 1] and y(t) over every segment.

    Rows are the t of each segment whose lags all lie inside it.
    """
    L = max(na, nk + nb - 1)
    blocks, ys = [], []
    for tr in traj:
        n = len(tr.Y)
        if n <= L:
            continue
        t = np.arange(L, n)
        cols = [tr.Y[t[:, None] - np.arange(1, na + 1)[None, :], target]]
        for j in range(tr.U.shape[1]):
            cols.append(tr.U[t[:, None] - (nk + np.arange(nb))[None, :], j])
        cols.append(np.ones((len(t), 1)))
        blocks.append(np.hstack(cols))
        ys.append(tr.Y[L:, target])
    if not blocks:
        return np.empty((0, na + nb * (traj[0].U.shape[1] if traj else 0) + 1)), np.empty(0)
    return np.vstack(blocks), np.concatenate(ys)


def least_squares(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """min |Phi theta - y| by LAPACK gelsd on columns scaled to unit max-abs (scaled back after).

    Single-threaded BLAS: on the shared 2-core machine a threaded gelsd of 58,000 x 65 took
    2.2 s, one thread 0.5 s.
    """
    import scipy.linalg  # here, not at the top: listing methods imports no scipy
    from threadpoolctl import threadpool_limits

    scale = np.abs(Phi).max(axis=0)
    scale[scale == 0] = 1.0
    with threadpool_limits(limits=1, user_api="blas"):
        theta, *_ = scipy.linalg.lstsq(Phi / scale, y, lapack_driver="gelsd", check_finite=False)
    return theta / scale


def simulate(a: np.ndarray, b: np.ndarray, c: float, nk: int, U: np.ndarray, window: np.ndarray) -> np.ndarray:
    """Free run of one SISO/MISO ARX model over a segment: (n,) outputs, the first len(window) measured.

    ``a`` (na,), ``b`` (inputs, nb), ``U`` (n, inputs) the segment's inputs, ``window``
    (N,) its measured outputs over raw rows 0..N-1.
    """
    n, N = len(U), len(window)
    na, nb = len(a), b.shape[1]
    P = nk + nb - 1
    Up = padded_past(U, P)
    v = np.full(n, float(c))
    for lag in range(nb):  # u(t - nk - lag) sits at padded row t + P - nk - lag
        start = P - nk - lag
        v += Up[start:start + n] @ b[:, lag]
    out = np.empty(n)
    out[:N] = window
    if na == 0:
        out[N:] = v[N:]
        return out
    past = padded_past(window, na)[::-1][:na]  # y(N-1), y(N-2), ..., y(N-na)
    import scipy.signal  # here, not at the top: scipy.signal imports scipy.stats (seconds)

    A = np.r_[1.0, -a]
    zi = scipy.signal.lfiltic([1.0], A, past)
    with np.errstate(all="ignore"):
        out[N:] = scipy.signal.lfilter([1.0], A, v[N:], zi=zi)[0]
    return out


def _poly(coefs: Sequence[float], first_power: int, lead: str = "") -> str:
    terms = [lead] if lead else []
    for i, c in enumerate(coefs):
        p = first_power + i
        q = "" if p == 0 else f" q^-{p}"
        terms.append(f"{'-' if c < 0 else '+'} {abs(c):.6g}{q}")
    text = " ".join(terms) if terms else "0"
    return text[2:] if text.startswith("+ ") else text


# --------------------------------------------------------------------------- method
class ARX(GivenOrders, Method):
    """Linear ARX baseline: least squares one step ahead, free-run simulation from the init window."""

    name = NAME
    family = "baseline"
    joint_targets = True
    modes = frozenset({"simulation"})
    summary = "linear ARX (order, delay searched), least squares, simulated in free run from the init window"

    declared_options = Declaration(
        orders("na", None, "output lags: None = tied to nb on the derived order grid", searches=("na", "order"),
               edges="high"),
        orders("nb", None, "input lags per input: None = tied to na on the derived order grid", low=1,
               why="at least one lag of each input", searches=("nb", "order"), edges="high"),
        orders("nk", None, "input delay: None = searched over (0, 1)", searches=("nk",), edges="high"),
        whole("max_order", 128, "cap of the derived order grid", low=1, unit="samples"),
        ENVELOPE,
    )

    def search_space(self, data: Samples) -> SearchSpace:
        """Tied order (na = nb) derived from the training data, or na and nb from the options; nk (0, 1) by default."""
        nk = self.given_orders["nk"]
        return {**self.order_space(data, int(self.options["max_order"]), ORDER_BASE, tied="order"),
                "nk": np.array(nk if nk is not None else list(DEFAULT_NK))}

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """The orders the training data carry (within ``max_order``): a grid's top order extended up to them."""
        return self.order_bounds(data, int(self.options["max_order"]), "order")

    @staticmethod
    def _orders_of(params: Params) -> tuple[int, int, int]:
        """(na, nb, nk) of a grid point: ``order`` sets na = nb unless they are given."""
        unknown = sorted(set(params) - {"order", "na", "nb", "nk"})
        if unknown:
            raise MethodError(f"method {NAME!r}: unknown hyperparameter(s) {', '.join(unknown)}; "
                              "it has order (or na and nb) and nk")
        given = {"na": params.get("na", params.get("order")), "nb": params.get("nb", params.get("order")),
                 "nk": params.get("nk")}
        missing = [k for k, v in given.items() if v is None]
        if missing:
            raise MethodError(f"method {NAME!r}: hyperparameter(s) {', '.join(missing)} missing from {dict(params)!r}; "
                              "give order (or na and nb) and nk (samples)")
        values = []
        for key, low in (("na", 0), ("nb", 1), ("nk", 0)):
            v = given[key]
            if isinstance(v, (bool, np.bool_)) or np.ndim(v) or not float(v).is_integer() or v < low:
                raise MethodError(f"method {NAME!r}: hyperparameter {key} must be a whole number >= {low}, got {v!r}")
            values.append(int(v))
        return values[0], values[1], values[2]

    def _fit_points(self, traj: list[Trajectory], train: Samples,
                    points: Sequence[tuple[int, int, int]]) -> list[ARXFit | MethodError]:
        """Least squares per target for every (na, nb, nk) of ``points``; a point the data cannot carry is its error.

        One Gram matrix of the points' longest lags per target (``numerics.lag_gram``) serves every
        point; a point too ill-conditioned for it is solved by SVD on its own regression matrix.
        """
        k, m = len(train.target_names), len(train.input_names)
        orders = [Orders(*p) for p in points]
        out: list[ARXFit | MethodError] = []
        coefs = [(np.zeros((k, o.na)), np.zeros((k, m, o.nb)), np.zeros(k)) for o in orders]
        rows = [0] * len(orders)
        failed: dict[int, MethodError] = {}
        longest = max(len(tr.Y) for tr in traj)
        gram = LagGram([(tr.U, tr.Y) for tr in traj], orders)
        for target in range(k):
            for i, o in enumerate(orders):
                if i in failed:
                    continue
                n_params = o.na + m * o.nb + 1
                rows[i] = gram.rows(o)
                if rows[i] < n_params:
                    failed[i] = MethodError(
                        f"method {NAME!r}: orders na={o.na}, nb={o.nb}, nk={o.nk} leave {rows[i]} regression rows for "
                        f"{n_params} parameters (longest training segment {longest} rows); use lower orders")
                    continue
                theta = gram.solve(o, target)
                if theta is None:
                    theta = least_squares(*regression(traj, target, o.na, o.nb, o.nk))
                a, b, c = coefs[i]
                a[target] = theta[:o.na]
                b[target] = theta[o.na:o.na + m * o.nb].reshape(m, o.nb)
                c[target] = theta[-1]
        env = Envelope.around(np.vstack([tr.Y for tr in traj]), float(self.options["envelope"]))
        for i, o in enumerate(orders):
            if i in failed:
                out.append(failed[i])
                continue
            a, b, c = coefs[i]
            out.append(ARXFit(na=o.na, nb=o.nb, nk=o.nk, a=a, b=b, c=c, input_names=tuple(train.input_names),
                              target_names=tuple(train.target_names), envelope=env, n_rows=rows[i]))
        return out

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> ARXFit:
        """Least squares per target on every training segment. Deterministic: ``rng`` is not drawn from."""
        self.check_mode(train.mode)
        (fitted,) = self._fit_points(training_trajectories(NAME, train), train, [self._orders_of(params)])
        if isinstance(fitted, MethodError):
            raise fitted
        return fitted

    def predict(self, fitted: ARXFit, data: Samples) -> SegmentPredictions:
        """Free run of every segment from its init window; predictions at the evaluated rows."""
        check_prediction_inputs(NAME, data, len(fitted.input_names))
        k = len(fitted.target_names)
        arrays, diverged = [], []
        for s in data.segments:
            window = init_window(NAME, s, k)
            U = np.asarray(s.U, dtype=np.float64)
            traj = np.column_stack([simulate(fitted.a[j], fitted.b[j], fitted.c[j], fitted.nk, U, window[:, j])
                                    for j in range(k)])
            traj, bad = fitted.envelope.clip_run(traj, len(window))
            arrays.append(traj[s.rows])
            diverged.append(bad)
        return SegmentPredictions(arrays, diverged)

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """Free-run predictions of ``data`` for every (na, nb, nk): (n_grid, rows, targets).

        The training trajectories are read once; each point is one small least-squares
        fit and one ``lfilter`` call per segment and target.
        """
        self.check_mode(train.mode)
        traj = training_trajectories(NAME, train)
        out = np.empty((len(grid), len(data), len(train.target_names)))
        fits = self._fit_points(traj, train, [self._orders_of(p) for p in grid])
        for i, fitted in enumerate(fits):
            if isinstance(fitted, MethodError):  # orders the fitting pieces cannot carry: +inf, the others go on
                out[i] = np.nan
            elif data.segments:
                out[i] = np.concatenate(self.predict(fitted, data))
        return out

    def describe(self, fitted: ARXFit) -> dict[str, Any]:
        """Orders, A(q) and B_j(q) per target, poles, a stability verdict, static gains and offsets."""
        models = {}
        for j, target in enumerate(fitted.target_names):
            A = np.r_[1.0, -fitted.a[j]]
            poles = np.roots(A) if fitted.na else np.empty(0)
            radius = float(np.abs(poles).max()) if poles.size else 0.0
            a_sum = float(A.sum())
            models[target] = {
                "A(q)": _poly(-fitted.a[j], 1, lead="1"),
                "B(q)": {u: (f"q^-{fitted.nk} ({_poly(fitted.b[j, i], 0)})" if fitted.nk else _poly(fitted.b[j, i], 0))
                         for i, u in enumerate(fitted.input_names)},
                "offset": float(fitted.c[j]),
                "a": fitted.a[j].tolist(),
                "b": {u: fitted.b[j, i].tolist() for i, u in enumerate(fitted.input_names)},
                "poles": [[float(p.real), float(p.imag)] for p in poles],
                "max_pole_modulus": radius,
                "stable": bool(radius < 1.0),
                "static_gain": {u: (float(fitted.b[j, i].sum() / a_sum) if a_sum else None)
                                for i, u in enumerate(fitted.input_names)},
            }
        return {
            "na": fitted.na, "nb": fitted.nb, "nk": fitted.nk,
            "model": "A(q) y(t) = sum_j B_j(q) u_j(t) + offset, one MISO model per target",
            "stable": all(m["stable"] for m in models.values()),
            "targets": models,
            "regression_rows": fitted.n_rows,
            "envelope": {"lower": fitted.envelope.lower.tolist(), "upper": fitted.envelope.upper.tolist()},
        }

    def c_model(self, fitted):
        """The C step of ``fitted`` for an FMU and the real-time figures (``methods/export``)."""
        from enginebench.methods.export.models import arx_c

        return arx_c(fitted)

    def step_times(self, fitted, data):
        """Its C step timed over ``data`` for the real-time figures (``methods/export/harness.py``)."""
        from enginebench.methods.export.harness import c_step_times

        return c_step_times(self.c_model(fitted), data)
