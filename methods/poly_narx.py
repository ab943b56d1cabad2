"""``poly-narx``: polynomial NARX, linear in its parameters, refined on the simulation error, run free.

Model, per target y (one MISO model per target; its own past outputs, every input), on
standardised signals (each signal's training mean and standard deviation)::

    y(t) = c + a_1 y(t-1) + ... + a_na y(t-na)
             + sum_j [ b_j0 u_j(t-nk) + ... + b_j(nb-1) u_j(t-nk-nb+1) ]          (linear ARX part)
             + sum over monomials m of degree 2..degree in y(t-1), ..., y(t-ky) of theta_m m   (polynomial part)

with ky = ``nonlinear_lags`` (at most na). The polynomial part reads past OUTPUTS only: a
static nonlinear restoring force, like the cubic stiffness of a Duffing oscillator
(Silverbox: y'' + d y' + a y + b y^3 = u), is a polynomial in the lagged outputs, and a
polynomial extrapolates that law past the training amplitudes where a Gaussian kernel
reverts to its mean. Monomials in the inputs were measured and left out (Silverbox: mixed
input-output monomials of degree <= 3 on 3 lags each gave 0.21 mV on the first 32,000 test
samples but 0.52 mV on the whole test part, the input monomials extrapolating badly; see
docs/benchmarks.md).

Fitting, per target and grid point:

1. Equation error: least squares one step ahead on measured outputs (rows where every lag lies
   inside its training segment), columns scaled to unit max-abs, LAPACK gelsd, on the constant, the
   linear part and the monomials a forward selection keeps by Akaike's criterion (``terms``;
   ``select_monomials``).
2. Simulation error (``refine = true``, the default): the coefficients from 1. start a
   Levenberg-Marquardt search that minimises the squared free-run error over sections of
   ``horizon`` samples cut from the training segments, each section started from its measured
   lags (a multiple-shooting loss: every section's run is free, the sections are independent,
   so a long record costs ``horizon`` time steps per evaluation, batched over sections). The
   gradient is exact: the sensitivities dy(t)/dtheta are propagated along the free run
   (dy(t)/dtheta = phi(t) + sum_i df/dy(t-i) dy(t-i)/dtheta) and the Gauss-Newton matrix
   J^T J accumulated step by step, never stored. The equation-error fit is biased towards
   one-step prediction; on Silverbox the refinement took the test RMSE from 0.45 to 0.32 mV
   (docs/benchmarks.md). A start whose sections diverge is replaced by the linear part alone
   (polynomial coefficients 0); the refined model is kept only where its section error is
   below the start's.

Free run (``predict``, ``predict_grid``): the first lagged outputs are the init window's
measured ones (edge-padded before it, as are inputs before the first sample), then only
simulated outputs are fed back. Every model of a grid (and every target and segment) runs in
one batched time loop on a common lag layout. A run leaving the envelope around the training
outputs, or turning non-finite, is held and flagged diverged (``methods/freerun.py``).

Defaults derived from the data: lags (na = nb, samples) from {2, 4, 8, 16} where the training
data carry them (``freerun.derived_orders``, at most ``max_lag``), nk = 0, nonlinear lags
ky from {1, 2, 4} (a ky above na is na; equal points are fitted once), degree 3. The toolkit's
selection picks them on the free-run error of its validation blocks.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from enginebench.declare import Declaration, choice, flag, whole
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions
from enginebench.methods.freerun import (ENVELOPE, Envelope, GivenOrders, Trajectory, as_orders,
                                         check_prediction_inputs, init_window, orders, training_trajectories)
from enginebench.methods.narx_model import standardise
from enginebench.samples import Samples

NAME = "poly-narx"
LAG_BASE = (2, 4, 8, 16, 32, 64)
NONLINEAR_BASE = (1, 2, 4)
BLOWUP = 1e3
"""A section run whose standardised output passes this magnitude has diverged (its error counts as infinite)."""


# --------------------------------------------------------------------------- structure
def term_table(na: int, nb: int, n_inputs: int, ky: int, degree: int) -> np.ndarray:
    """The model's terms as rows of variable indices (p, max(degree, 1)) into z = [y(t-1) .. y(t-na),
    u_1(t-nk) .. u_1(t-nk-nb+1), ..., 1]: the constant, every lag alone, then the monomials of degree
    2..degree in y(t-1) .. y(t-ky). The index of the trailing 1 (na + n_inputs nb) pads shorter terms."""
    nv = na + n_inputs * nb
    width = max(degree, 1)
    rows: list[tuple[int, ...]] = [()] + [(v,) for v in range(nv)]
    for deg in range(2, degree + 1):
        rows += list(itertools.combinations_with_replacement(range(min(ky, na)), deg))
    table = np.full((len(rows), width), nv, dtype=np.int64)
    for i, r in enumerate(rows):
        table[i, :len(r)] = r
    return table


def term_names(table: np.ndarray, na: int, nb: int, nk: int, inputs: Sequence[str], target: str) -> list[str]:
    """Readable names of the terms ("1", "y(t-1)", "y(t-1)^2*y(t-2)", "u(t-0)")."""
    nv = na + len(inputs) * nb

    def var(v: int) -> str:
        if v < na:
            return f"{target}(t-{v + 1})"
        j, lag = divmod(v - na, nb)
        return f"{inputs[j]}(t-{nk + lag})"

    names = []
    for row in table:
        used = [int(v) for v in row if v != nv]
        if not used:
            names.append("1")
            continue
        parts = [var(v) + (f"^{used.count(v)}" if used.count(v) > 1 else "") for v in dict.fromkeys(used)]
        names.append("*".join(parts))
    return names


def spread(count: int, cap: int) -> np.ndarray | None:
    """``cap`` indices spread evenly over ``count`` (first and last included), or None when ``count <= cap`` or
    ``cap`` is 0 (all): a deterministic subsample that keeps a long record's cost bounded."""
    if cap <= 0 or count <= cap:
        return None
    return np.unique(np.round(np.linspace(0, count - 1, cap)).astype(np.int64))


def lag_rows(traj: Sequence[Trajectory], target: int, na: int, nb: int, nk: int, max_rows: int = 0
             ) -> tuple[np.ndarray, np.ndarray]:
    """Rows z(t) = [y(t-1) .. y(t-na), u_j(t-nk) .. u_j(t-nk-nb+1) per input] and y(t), lags inside each segment;
    above ``max_rows`` rows (0: no cap) only that many, spread evenly over all segments' rows (``spread``), built
    alone."""
    L = max(na, nk + nb - 1)
    keep = spread(sum(max(len(tr.Y) - L, 0) for tr in traj), max_rows)
    Z, y = [], []
    start = 0
    for tr in traj:
        n = len(tr.Y)
        if n <= L:
            continue
        t = np.arange(L, n)
        if keep is not None:
            lo, hi = np.searchsorted(keep, [start, start + n - L])
            t = keep[lo:hi] - start + L
        start += n - L
        cols = [tr.Y[t[:, None] - np.arange(1, na + 1)[None, :], target]]
        for j in range(tr.U.shape[1]):
            cols.append(tr.U[t[:, None] - (nk + np.arange(nb))[None, :], j])
        Z.append(np.hstack(cols))
        y.append(tr.Y[t, target])
    c = traj[0].U.shape[1] if traj else 0
    if not Z:
        return np.empty((0, na + c * nb)), np.empty(0)
    return np.vstack(Z), np.concatenate(y)


def features(Z: np.ndarray, table: np.ndarray) -> np.ndarray:
    """The terms' values on rows ``Z`` (rows, nv): (rows, p)."""
    Zx = np.hstack([Z, np.ones((len(Z), 1))])
    out = Zx[:, table[:, 0]].copy()
    for col in range(1, table.shape[1]):
        out *= Zx[:, table[:, col]]
    return out


def least_squares(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """min |Phi theta - y| by LAPACK gelsd on columns scaled to unit max-abs, one BLAS thread."""
    import scipy.linalg
    from threadpoolctl import threadpool_limits

    scale = np.abs(Phi).max(axis=0)
    scale[scale == 0] = 1.0
    with threadpool_limits(limits=1, user_api="blas"):
        theta, *_ = scipy.linalg.lstsq(Phi / scale, y, lapack_driver="gelsd", check_finite=False)
    return theta / scale


TERM_RULES = ("aic", "bic", "all")
"""How the polynomial part's monomials are chosen: by an information criterion on a forward selection, or all."""


def select_monomials(Phi: np.ndarray, y: np.ndarray, always: np.ndarray, rule: str) -> np.ndarray:
    """Which columns of ``Phi`` to keep: every ``always`` column (the constant and the linear ARX part), plus the
    monomials a forward orthogonal selection adds before ``rule``'s criterion stops paying.

    Forward selection by error reduction (the polynomial NARX field's structure detection): the
    candidates are made orthogonal to the kept columns, the one that lowers the residual sum of
    squares most is added, the rest made orthogonal to it, until every candidate is in; the kept
    count minimises n log(RSS / n) + penalty k over that path (AIC: penalty 2; BIC: log n). A short
    record's cubic model then carries only the monomials the data support: all 30 cubic and
    quadratic monomials of four lags on 1,000 rows were what made it diverge (docs/benchmarks.md).
    ``rule = "all"`` keeps every column.
    """
    keep = np.ones(Phi.shape[1], dtype=bool)
    candidates = np.flatnonzero(~always)
    if rule == "all" or not len(candidates):
        return keep
    n = len(y)
    Q, _ = np.linalg.qr(Phi[:, always])
    r = y - Q @ (Q.T @ y)
    raw = Phi[:, candidates]
    floor = 1e-20 * np.maximum(np.einsum("ij,ij->j", raw, raw), 1e-300)
    C = raw - Q @ (Q.T @ raw)
    open_ = np.ones(len(candidates), dtype=bool)
    rss, order = [float(r @ r)], []
    while True:
        norms = np.einsum("ij,ij->j", C, C)
        usable = open_ & (norms > floor)
        if not usable.any():
            break
        gain = np.where(usable, (C.T @ r) ** 2 / np.where(usable, norms, 1.0), -1.0)
        j = int(np.argmax(gain))
        q = C[:, j] / np.sqrt(norms[j])
        r = r - q * (q @ r)
        C -= np.outer(q, q @ C)
        open_[j] = False
        order.append(candidates[j])
        rss.append(float(r @ r))
    penalty = np.log(n) if rule == "bic" else 2.0
    count = int(always.sum()) + np.arange(len(rss))
    criterion = n * np.log(np.maximum(np.asarray(rss), 1e-300) / n) + penalty * count
    keep = always.copy()
    keep[order[:int(np.argmin(criterion))]] = True
    return keep


# --------------------------------------------------------------------------- simulation-error fit
@dataclass(frozen=True)
class Sections:
    """Sections of the standardised training trajectories: measured outputs (B, L + H) and input lag rows
    (B, H, n_inputs nb) of the H simulated steps; the first L outputs of a section are its measured lags."""

    y: np.ndarray
    z_u: np.ndarray
    L: int


def sections(traj: Sequence[Trajectory], target: int, na: int, nb: int, nk: int, horizon: int,
             max_sections: int = 0) -> Sections | None:
    """Sections of L + H samples (H = ``horizon``, less where the shortest usable segment is shorter), stride H;
    a remainder is covered by one more section ending at the segment's end; above ``max_sections`` (0: no cap)
    only that many, spread evenly over all of them (``spread``). None when no segment is usable."""
    L = max(na, nk + nb - 1)
    usable = [tr for tr in traj if len(tr.Y) - L >= 2]
    if not usable:
        return None
    H = int(min(horizon, min(len(tr.Y) - L for tr in usable)))
    ys, zs = [], []
    for tr in usable:
        n = len(tr.Y)
        starts = list(range(0, n - (L + H) + 1, H))
        if starts[-1] != n - (L + H):
            starts.append(n - (L + H))
        ix = np.asarray(starts)[:, None] + np.arange(L + H)[None, :]
        ys.append(tr.Y[ix, target])
        t = np.asarray(starts)[:, None] + np.arange(L, L + H)[None, :]  # (b, H) simulated times
        zs.append(np.concatenate([tr.U[t[..., None] - (nk + np.arange(nb))[None, None, :], j]
                                  for j in range(tr.U.shape[1])], axis=2))
    y_all, z_all = np.vstack(ys), np.vstack(zs)
    keep = spread(len(y_all), max_sections)
    return Sections(y_all, z_all, L) if keep is None else Sections(y_all[keep], z_all[keep], L)


def section_error(theta: np.ndarray, table: np.ndarray, na: int, sec: Sections, gradient: bool
                  ) -> tuple[float, np.ndarray | None, np.ndarray | None]:
    """Squared free-run error summed over the sections; with ``gradient`` also J^T J and J^T r (J the
    sensitivities of the simulated outputs to ``theta``, propagated along the runs). inf when a run diverges."""
    B = len(sec.y)
    H = sec.z_u.shape[1]
    p, width = table.shape
    nv = table.max()  # the pad index (the constant 1)
    hist = sec.y[:, sec.L - na:sec.L][:, ::-1].copy() if na else np.zeros((B, 0))  # y(t-1) .. y(t-na)
    z = np.ones((B, nv + 1))
    cost = 0.0
    JTJ = np.zeros((p, p)) if gradient else None
    JTr = np.zeros(p) if gradient else None
    if gradient:
        S = np.zeros((B, na, p))  # S[:, i] = d y(t-1-i) / d theta
        onehot = [(table[:, k][:, None] == np.arange(na)[None, :]).astype(float) for k in range(width)]
    for h in range(H):
        z[:, :na] = hist
        z[:, na:nv] = sec.z_u[:, h]
        Zt = z[:, table]  # (B, p, width)
        phi = Zt.prod(axis=2)
        y = phi @ theta
        if not np.all(np.abs(y) < BLOWUP):
            return np.inf, None, None
        r = y - sec.y[:, sec.L + h]
        cost += float(r @ r)
        if gradient:
            g = np.zeros((B, na))
            for k in range(width):
                others = np.ones((B, p))
                for m in range(width):
                    if m != k:
                        others *= Zt[:, :, m]
                g += (others * theta) @ onehot[k]
            J = phi + np.matmul(g[:, None, :], S)[:, 0]
            JTJ += J.T @ J
            JTr += J.T @ r
            S = np.concatenate([J[:, None, :], S[:, :-1]], axis=1)
        hist = np.concatenate([y[:, None], hist[:, :-1]], axis=1)
    return cost, JTJ, JTr


def refine(theta0: np.ndarray, table: np.ndarray, na: int, sec: Sections, max_iter: int,
           tol: float = 1e-6) -> tuple[np.ndarray, float, float, int]:
    """Levenberg-Marquardt on ``section_error`` from ``theta0``: (theta, start error, final error, iterations).

    Marquardt's diagonal scaling; a step that raises the error (or diverges) is refused and the damping
    raised 4x, an accepted one lowers it 3x; stops after ``max_iter`` accepted steps, when the relative
    decrease falls below ``tol`` or the damping passes 1e10.
    """
    theta = np.asarray(theta0, dtype=np.float64).copy()
    cost, A, g = section_error(theta, table, na, sec, gradient=True)
    start = cost
    if not np.isfinite(cost):
        return theta, start, cost, 0
    mu, it = 1e-3, 0
    while it < max_iter and mu < 1e10:
        d = np.diag(A).copy()
        d[d <= 0] = 1.0
        try:
            step = np.linalg.solve(A + mu * np.diag(d), -g)
        except np.linalg.LinAlgError:
            mu *= 4
            continue
        trial = theta + step
        new, _, _ = section_error(trial, table, na, sec, gradient=False)
        if new < cost:
            it += 1
            done = cost - new < tol * cost
            theta = trial
            cost, A, g = section_error(theta, table, na, sec, gradient=True)
            mu = max(mu / 3, 1e-12)
            if done:
                break
        else:
            mu *= 4
    return theta, start, cost, it


# --------------------------------------------------------------------------- fitted model
@dataclass(frozen=True)
class PolyModel:
    """One target's polynomial NARX in standardised units: ``terms`` (p, width) indices into
    [y(t-1) .. y(t-na), u_j(t-nk) .. per input, 1] and coefficients ``theta`` (p,)."""

    na: int
    nb: int
    nk: int
    ky: int
    degree: int
    terms: np.ndarray
    theta: np.ndarray
    target: int
    refined: bool
    iterations: int
    error_start: float
    """Root-mean-square section error (standardised) of the equation-error start (inf: diverged)."""
    error: float
    """Root-mean-square section error (standardised) of the kept coefficients (nan: not refined)."""

    @property
    def max_lag(self) -> int:
        return max(self.na, self.nk + self.nb - 1)


@dataclass(frozen=True)
class PolyNARXFit:
    models: tuple[PolyModel, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    envelope: Envelope
    n_rows: int


def free_run(models: Sequence[PolyModel], U: Sequence[np.ndarray], W: Sequence[np.ndarray],
             limits: np.ndarray) -> np.ndarray:
    """Free runs of every model on every segment, in one time loop: (models, segments, longest) standardised.

    ``U`` per segment its standardised inputs (n_s, c), ``W`` its standardised init window (N, ...) of the
    model's target (all windows of one call share N), ``limits`` (models, 2) the standardised envelope a run
    is held just outside of (so that it stays finite and is flagged by ``Envelope.clip_run``). The models'
    lags are laid out on one common grid: output lags 1..max na, input delays 0..max(nk + nb - 1).
    """
    G, S = len(models), len(U)
    c = U[0].shape[1]
    N = len(W[0])
    n_max = max(len(u) for u in U)
    NA = max(m.na for m in models)
    D = max(m.nk + m.nb for m in models)  # input delays 0 .. D-1
    nv = NA + c * D
    width = max(m.terms.shape[1] for m in models)
    P = max(len(m.terms) for m in models)
    idx = np.full((G, P, width), nv, dtype=np.int64)
    theta = np.zeros((G, P))
    for g, m in enumerate(models):
        own_nv = m.na + c * m.nb
        remap = np.empty(own_nv + 1, dtype=np.int64)
        remap[:m.na] = np.arange(m.na)
        for j in range(c):
            remap[m.na + j * m.nb:m.na + (j + 1) * m.nb] = NA + j * D + m.nk + np.arange(m.nb)
        remap[own_nv] = nv
        idx[g, :len(m.terms), :m.terms.shape[1]] = remap[m.terms]
        theta[g, :len(m.terms)] = m.theta
    # input lag rows per segment: (S, n_max, c D), u_j(t - d) edge-padded before row 0 and past the segment's end
    Ulag = np.empty((S, n_max, c * D))
    for s, u in enumerate(U):
        padded = np.concatenate([np.repeat(u[:1], D, axis=0), u, np.repeat(u[-1:], n_max - len(u), axis=0)])
        for j in range(c):
            for d in range(D):
                Ulag[s, :, j * D + d] = padded[D - d:D - d + n_max, j]
    R = G * S
    rows_idx = (idx[:, None] + (np.arange(R).reshape(G, S) * (nv + 1))[:, :, None, None]).reshape(R, P, width)
    theta_r = np.repeat(theta, S, axis=0)
    lo = np.repeat(limits[:, 0], S)
    hi = np.repeat(limits[:, 1], S)
    out = np.empty((G, S, n_max))
    hist = np.empty((R, NA))
    for g in range(G):
        for s in range(S):
            w = W[s][:, models[g].target] if W[s].ndim == 2 else W[s]
            out[g, s, :N] = w
            past = np.concatenate([np.repeat(w[:1], NA, axis=0), w])[::-1][:NA]  # y(N-1) .. y(N-NA)
            hist[g * S + s] = past
    z = np.ones((R, nv + 1))
    flat = z.reshape(-1)
    seg_of_row = np.tile(np.arange(S), G)
    with np.errstate(all="ignore"):
        for t in range(N, n_max):
            z[:, :NA] = hist
            z[:, NA:nv] = Ulag[seg_of_row, t]
            y = (flat[rows_idx].prod(axis=2) * theta_r).sum(axis=1)
            y = np.where(np.isfinite(y), y, hi)
            y = np.minimum(np.maximum(y, lo), hi)
            out[:, :, t] = y.reshape(G, S)
            hist[:, 1:] = hist[:, :-1].copy()
            hist[:, 0] = y
    return out


# --------------------------------------------------------------------------- method
class PolyNARX(GivenOrders, Method):
    """Polynomial NARX: equation-error least squares, refined on the multi-step simulation error; free run."""

    name = NAME
    family = "data-driven"
    modes = frozenset({"simulation"})
    joint_targets = True
    summary = ("polynomial NARX: linear ARX part + monomials (degree <= 3) of the lagged outputs, least squares "
               "refined on the simulation error, selected and predicted in free run")

    declared_options = Declaration(
        orders("na", None, "output lags: None = tied to nb on a derived grid", low=1,
               why="a NARX feeds back its output", searches=("na", "lags"), edges="high"),
        orders("nb", None, "input lags per input: None = tied to na on a derived grid", low=1,
               why="at least one lag of each input", searches=("nb", "lags"), edges="high"),
        orders("nk", 0, "input delay: u(t - nk) is the newest input regressor", searches=("nk",), edges="high"),
        whole("max_lag", 16, "cap of the derived lag grid", low=1, unit="samples"),
        orders("nonlinear_lags", None, "output lags the polynomial part reads (ky, at most na): None = searched "
               "over 1, 2, 4", low=1, why="the polynomial part reads at least y(t-1)", searches=("nonlinear_lags",),
               edges="high", bound=(1.0, 4.0)),
        whole("degree", 3, "highest degree of the monomials (1: a linear ARX model)", low=1, high=5),
        choice("terms", "aic", "which monomials the model keeps: those a forward selection adds while the information "
               "criterion (aic or bic) falls, or all", TERM_RULES),
        flag("refine", True, "refine the equation-error coefficients on the free-run error of training sections"),
        whole("horizon", 500, "samples each training section is simulated over in the refinement", low=2,
              unit="samples"),
        whole("max_iter", 30, "most accepted Levenberg-Marquardt steps of the refinement", low=0),
        whole("max_rows", 200000, "least-squares rows used: above, this many spread evenly over the training rows "
              "(0 = all); Silverbox's estimation part has 86,750", low=0, unit="rows"),
        whole("max_sections", 200, "refinement sections used: above, this many spread evenly over the training "
              "records (0 = all), so a long record's refinement costs what 100,000 samples cost", low=0),
        ENVELOPE,
    )

    # -- grid ---------------------------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        """Lags (tied na = nb unless given), nk and the polynomial part's output lags."""
        space: SearchSpace = self.order_space(data, int(self.options["max_lag"]), LAG_BASE, tied="lags")
        space["nk"] = np.array(self.given_orders["nk"])
        ky = as_orders(self.options["nonlinear_lags"])
        space["nonlinear_lags"] = np.array(ky if ky is not None else list(NONLINEAR_BASE))
        return space

    def search_bounds(self, data: Samples) -> dict[str, tuple[float | None, float | None]]:
        """The declared bound of the nonlinear lags and the lags the training data carry (within ``max_lag``)."""
        return {**super().search_bounds(data), **self.order_bounds(data, int(self.options["max_lag"]), "lags")}

    @staticmethod
    def _point(params: Params) -> tuple[int, int, int, int]:
        """(na, nb, nk, ky) of a grid point, checked; ky above na is na."""
        allowed = {"lags", "na", "nb", "nk", "nonlinear_lags"}
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise MethodError(f"method {NAME!r}: unknown hyperparameter(s) {', '.join(unknown)}; "
                              "it has lags (or na and nb), nk, nonlinear_lags")
        given = {"na": params.get("na", params.get("lags")), "nb": params.get("nb", params.get("lags")),
                 "nk": params.get("nk"), "nonlinear_lags": params.get("nonlinear_lags")}
        missing = [k for k, v in given.items() if v is None]
        if missing:
            raise MethodError(f"method {NAME!r}: hyperparameter(s) {', '.join(missing)} missing from "
                              f"{dict(params)!r}; give lags (or na and nb), nk and nonlinear_lags (samples)")
        values = []
        for key, low in (("na", 1), ("nb", 1), ("nk", 0), ("nonlinear_lags", 1)):
            v = given[key]
            if isinstance(v, (bool, np.bool_)) or np.ndim(v) or not float(v).is_integer() or v < low:
                raise MethodError(f"method {NAME!r}: hyperparameter {key} must be a whole number >= {low}, got {v!r}")
            values.append(int(v))
        na, nb, nk, ky = values
        return na, nb, nk, min(ky, na)

    # -- fitting ------------------------------------------------------------------------------------
    def _fit_model(self, traj: list[Trajectory], target: int, point: tuple[int, int, int, int]
                   ) -> tuple[PolyModel, int] | MethodError:
        """One target's model at ``point``, or the error saying why the data cannot carry it."""
        na, nb, nk, ky = point
        c = traj[0].U.shape[1]
        degree = int(self.options["degree"])
        table = term_table(na, nb, c, ky, degree)
        Z, y = lag_rows(traj, target, na, nb, nk, int(self.options["max_rows"]))
        if len(y) < 2 * len(table):
            longest = max(len(tr.Y) for tr in traj)
            return MethodError(f"method {NAME!r}: lags na={na}, nb={nb}, nk={nk} with nonlinear_lags={ky} leave "
                               f"{len(y)} regression rows for {len(table)} coefficients (longest training segment "
                               f"{longest} rows); use fewer lags or a lower degree")
        Phi = features(Z, table)
        linear = (table[:, 1:] == table.max()).all(axis=1)
        keep = select_monomials(Phi, y, linear, str(self.options["terms"]))
        table = table[keep]
        theta = least_squares(Phi[:, keep], y)
        refined, iterations, start, error = False, 0, np.nan, np.nan
        if self.options["refine"] and int(self.options["max_iter"]) > 0:
            sec = sections(traj, target, na, nb, nk, int(self.options["horizon"]), int(self.options["max_sections"]))
            if sec is not None:
                count = sec.y.shape[0] * (sec.y.shape[1] - sec.L)
                first, _, _ = section_error(theta, table, na, sec, gradient=False)
                if not np.isfinite(first):  # the one-step fit diverges on the sections: start from its linear part
                    linear = (table[:, 1:] == table.max()).all(axis=1)
                    theta_lin = np.zeros_like(theta)
                    theta_lin[linear] = least_squares(features(Z, table[linear]), y)
                    theta = theta_lin
                new, cost0, cost, iterations = refine(theta, table, na, sec, int(self.options["max_iter"]))
                start = float(np.sqrt(first / count)) if np.isfinite(first) else np.inf
                if cost < cost0:
                    theta, refined = new, True
                error = float(np.sqrt(min(cost, cost0) / count)) if np.isfinite(min(cost, cost0)) else np.inf
        model = PolyModel(na=na, nb=nb, nk=nk, ky=ky, degree=degree, terms=table, theta=theta, target=target,
                          refined=refined, iterations=iterations, error_start=start, error=error)
        return model, len(y)

    def _fits(self, train: Samples, points: Sequence[tuple[int, int, int, int]]
              ) -> list[PolyNARXFit | MethodError]:
        """A fit per point (equal points fitted once), or the error of a point the data cannot carry."""
        std = standardise(training_trajectories(NAME, train), float(self.options["envelope"]))  # as narx's
        traj, y_mean, y_std, u_mean, u_std = std.traj, std.y_mean, std.y_std, std.u_mean, std.u_std
        env = std.envelope
        k = len(train.target_names)
        done: dict[tuple[int, int, int, int], PolyNARXFit | MethodError] = {}
        for point in dict.fromkeys(points):
            models, rows = [], 0
            for target in range(k):
                res = self._fit_model(traj, target, point)
                if isinstance(res, MethodError):
                    done[point] = res
                    break
                models.append(res[0])
                rows = res[1]
            else:
                done[point] = PolyNARXFit(models=tuple(models), y_mean=y_mean, y_std=y_std, u_mean=u_mean,
                                          u_std=u_std, input_names=tuple(train.input_names),
                                          target_names=tuple(train.target_names), envelope=env, n_rows=rows)
        return [done[p] for p in points]

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> PolyNARXFit:
        """Least squares, then the simulation-error refinement, per target. Deterministic: ``rng`` is not drawn."""
        self.check_mode(train.mode)
        (fitted,) = self._fits(train, [self._point(params)])
        if isinstance(fitted, MethodError):
            raise fitted
        return fitted

    # -- prediction ------------------------------------------------------------------------------
    def _simulate(self, fits: Sequence[PolyNARXFit], data: Samples) -> list[tuple[list[np.ndarray], np.ndarray]]:
        """Free runs of every fit on ``data``, batched per init-window length: per fit (arrays, diverged)."""
        first = fits[0]
        check_prediction_inputs(NAME, data, len(first.input_names))
        k = len(first.target_names)
        results: list[list[Any]] = [[None] * len(data.segments) for _ in fits]
        flags = [np.zeros(len(data.segments), dtype=bool) for _ in fits]
        windows = [init_window(NAME, s, k) for s in data.segments]
        by_window: dict[int, list[int]] = {}
        for i, w in enumerate(windows):
            by_window.setdefault(len(w), []).append(i)
        models = [m for f in fits for m in f.models]
        lower = (first.envelope.lower - first.y_mean) / first.y_std
        upper = (first.envelope.upper - first.y_mean) / first.y_std
        margin = 1e-6 * (upper - lower)
        limits = np.array([[lower[m.target] - 2 * margin[m.target], upper[m.target] + 2 * margin[m.target]]
                           for m in models])
        for N, members in by_window.items():
            U = [(np.asarray(data.segments[i].U, dtype=np.float64) - first.u_mean) / first.u_std for i in members]
            W = [(windows[i] - first.y_mean) / first.y_std for i in members]
            runs = free_run(models, U, W, limits).reshape(len(fits), k, len(members), -1)
            for f_idx, f in enumerate(fits):
                for r, i in enumerate(members):
                    n = len(data.segments[i].t)
                    traj = runs[f_idx, :, r, :n].T * f.y_std + f.y_mean
                    traj[:N] = windows[i]
                    traj, bad = f.envelope.clip_run(traj, N)
                    results[f_idx][i] = traj[data.segments[i].rows]
                    flags[f_idx][i] = bad
        return [(arrays, fl) for arrays, fl in zip(results, flags)]

    def predict(self, fitted: PolyNARXFit, data: Samples) -> SegmentPredictions:
        """Free run of every segment from its init window; predictions at the evaluated rows."""
        if not data.segments:
            return SegmentPredictions([])
        ((arrays, diverged),) = self._simulate([fitted], data)
        return SegmentPredictions(arrays, diverged)

    def predict_grid(self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
                     ) -> np.ndarray:
        """Free-run predictions of ``data`` for every grid point (n_grid, rows, targets), all in one batched run;
        a point the training data cannot carry is nan (scored +inf), the others go on."""
        self.check_mode(train.mode)
        fits = self._fits(train, [self._point(p) for p in grid])
        out = np.full((len(grid), len(data), len(train.target_names)), np.nan)
        good = [i for i, f in enumerate(fits) if not isinstance(f, MethodError)]
        if good and data.segments:
            for i, (arrays, _) in zip(good, self._simulate([fits[i] for i in good], data)):  # type: ignore[misc]
                out[i] = np.concatenate(arrays)
        return out

    def describe(self, fitted: PolyNARXFit) -> dict[str, Any]:
        """Orders, terms and coefficients (standardised units) per target, the refinement's section errors."""
        targets = {}
        for m in fitted.models:
            name = fitted.target_names[m.target]
            names = term_names(m.terms, m.na, m.nb, m.nk, fitted.input_names, name)
            targets[name] = {
                "terms": dict(zip(names, (float(v) for v in m.theta))),
                "refined": m.refined, "iterations": m.iterations,
                "section_rmse_start": m.error_start, "section_rmse": m.error,
            }
        m0 = fitted.models[0]
        return {
            "na": m0.na, "nb": m0.nb, "nk": m0.nk, "nonlinear_lags": m0.ky, "degree": m0.degree,
            "model": "y(t) = c + linear ARX part + monomials of degree 2..degree in the lagged outputs, on "
                     "standardised signals (y_mean, y_std, u_mean, u_std)",
            "targets": targets, "regression_rows": fitted.n_rows,
            "y_mean": fitted.y_mean.tolist(), "y_std": fitted.y_std.tolist(),
            "u_mean": fitted.u_mean.tolist(), "u_std": fitted.u_std.tolist(),
        }
