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

Solvers: up to ``exact_max_rows`` regression rows, exact (the centres c_i are all rows);
above,
``centres`` Nystroem centres drawn uniformly without replacement with the job's generator
(as FALKON draws them, ``methods/falkon.py``) and the Nystroem problem
min |K_nm beta + Phi theta - y|^2 + lambda beta^T K_mm beta (Phi the linear regressors)
solved directly (``nystroem_ridge``: ridge on the features K_nm V s^-1/2 with Phi
projected out, one eigendecomposition per gamma serves every lambda).
Direct, because free-run selection prefers small gamma and lambda, where FALKON's
conjugate gradient had not converged after 50 iterations on Silverbox (relative residual
0.016 at gamma = 0.03, lambda = 1e-10): its early stop would be a hidden regulariser.
Training sets larger than ``max_rows`` rows are subsampled uniformly (rows are independent
regression pairs one step ahead). A simulated step costs O(centres x d), never
O(training rows).

Free run (``predict``): the first lagged outputs are the init window's measured ones
(``y_init``; ``y0`` alone without a window; edge padding before row 0), after the window
only simulated outputs are fed back. All segments, and in ``predict_grid`` all grid
points (and targets), step together in one time loop: per step one product of the
output-lag history with the centres, one addition of the input part, one exp2 and one
product with the coefficients. The input part of the exponent does not depend on the
simulated outputs, so it is computed for blocks of time steps at once (a matrix
product); the |z|^2 terms are folded into both products (the history stores y and y^2),
so the exponent is -(gamma/d) |z - c|^2 <= 0 exactly as written and f stays bounded; the
linear part is added from the same history. An unstable linear part can still blow a run
up: a run leaving the envelope [min - e span, max + e span] of the training outputs, or
turning non-finite, is flagged and held at its last in-envelope value
(``methods/freerun.py``), as for ``sindy``.

Selection: the toolkit scores ``predict_grid``'s free runs on validation blocks, so
orders and kernel hyperparameters are chosen on simulation error, not one-step error.

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
- exact up to 1,000 rows, else 500 Nystroem centres on at most 20,000 rows (on
  Silverbox 1,000 centres gave the same free-run error: at the small gammas selected the
  centres' kernel matrix has numerical rank ~100-250 anyway; a step costs half as much).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from enginebench.datasets.samples import Samples
from enginebench.errors import MethodError
from enginebench.declare import Declaration, flag, whole
from enginebench.declare import log_grid as grid
from enginebench.methods.base import Method, Params, SearchSpace, SegmentPredictions, log_grid
from enginebench.methods.freerun import (ENVELOPE, Envelope, GivenOrders, Trajectory, check_prediction_inputs,
                                         derived_orders, init_window, orders, training_trajectories)
from enginebench.methods.kernels import check_positive, gaussian, sq_distances

NAME = "narx"
LAG_BASE = (2, 4, 8, 16, 32, 64)
NYSTROEM_RTOL = 1e-10
"""Eigenvalues of K_mm below this fraction of the largest are dropped (Nystroem pseudo-inverse)."""
CHUNK_MIB = 32.0
"""Memory budget of one block of precomputed input exponents (models x segments x steps x centres)."""
LN2 = math.log(2.0)


# --------------------------------------------------------------------------- fitted model
@dataclass(frozen=True)
class KernelModel:
    """One target's model, standardised: a linear ARX part plus the kernel sum f.

    The linear part reads y(t-1..t-na) (``a[i-1]`` multiplies y(t-i)), u_j(t-nk..t-nk-nb+1)
    (``b[j, l]`` multiplies u_j(t-nk-l)) and a constant ``c0``; all zero without it. The
    kernel reads the last ``ka`` outputs and ``kb`` input lags: centres (m, ka + inputs x kb)
    in the layout [y(t-ka) .. y(t-1), u_1(t-nk) .. u_1(t-nk-kb+1), u_2 ...].
    """

    na: int
    nb: int
    nk: int
    ka: int
    kb: int
    a: np.ndarray
    b: np.ndarray
    c0: float
    centres: np.ndarray
    beta: np.ndarray
    gamma: float
    """Relative gamma; the kernel is exp(-(gamma / d) |z - c|^2)."""
    lam: float
    """Relative lambda; the solve used lambda x rows."""
    target: int
    """Column of the target in the fitted model's targets."""

    @property
    def d(self) -> int:
        return self.centres.shape[1]

    @property
    def s(self) -> float:
        """exp(-(gamma/d) D) = 2^(-s D)."""
        return self.gamma / self.d / LN2


@dataclass(frozen=True)
class NARXFit:
    """Per-target kernel models plus the standardisation, the envelope and what the solver did."""

    models: tuple[KernelModel, ...]
    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    input_names: tuple[str, ...]
    target_names: tuple[str, ...]
    envelope: Envelope
    solver: str
    n_rows: int
    info: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------- regression data
@dataclass(frozen=True)
class _Standardised:
    """Training trajectories in standardised units and the statistics used."""

    traj: list[Trajectory]
    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    envelope: Envelope


def _standardise(traj: list[Trajectory], envelope: float) -> _Standardised:
    Y = np.vstack([t.Y for t in traj])
    U = np.vstack([t.U for t in traj])
    y_mean, y_std = Y.mean(axis=0), Y.std(axis=0)
    u_mean, u_std = U.mean(axis=0), U.std(axis=0)
    y_std[y_std == 0] = 1.0
    u_std[u_std == 0] = 1.0
    scaled = [Trajectory(t.id, (t.U - u_mean) / u_std, (t.Y - y_mean) / y_std) for t in traj]
    return _Standardised(scaled, y_mean, y_std, u_mean, u_std, Envelope.around(Y, envelope))


def regressors(traj: Sequence[Trajectory], target: int, na: int, nb: int, nk: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows z(t) = [y(t-na) .. y(t-1), u_j(t-nk) .. u_j(t-nk-nb+1) per input] and y(t), lags inside each segment."""
    L = max(na, nk + nb - 1)
    Z, y = [], []
    for tr in traj:
        n = len(tr.Y)
        if n <= L:
            continue
        t = np.arange(L, n)
        cols = [tr.Y[t[:, None] - np.arange(na, 0, -1)[None, :], target]]
        for j in range(tr.U.shape[1]):
            cols.append(tr.U[t[:, None] - (nk + np.arange(nb))[None, :], j])
        Z.append(np.hstack(cols))
        y.append(tr.Y[L:, target])
    if not Z:
        return np.empty((0, na + nb * (traj[0].U.shape[1] if traj else 0))), np.empty(0)
    return np.vstack(Z), np.concatenate(y)


# --------------------------------------------------------------------------- batched free run
def _input_lags(U: np.ndarray, lags: int, length: int) -> np.ndarray:
    """(n, c) inputs -> (length, c * (lags + 1)): input j at lag l in column j * (lags + 1) + l.

    Edge padding before the first row; rows past the end repeat the last row.
    """
    n, c = U.shape
    idx = np.clip(np.arange(length)[:, None] - np.arange(lags + 1)[None, :], 0, n - 1)
    return U[idx].transpose(0, 2, 1).reshape(length, c * (lags + 1))


def free_run(models: Sequence[KernelModel], inputs: Sequence[np.ndarray], windows: Sequence[np.ndarray],
             lengths: Sequence[int]) -> np.ndarray:
    """Simulate every model on every segment at once, in standardised units: (models, segments, max length).

    See ``_free_run``; BLAS runs single-threaded here: each step's products are far too
    small for threads, which would only add synchronisation to every step.
    """
    with threadpool_limits(limits=1, user_api="blas"), np.errstate(all="ignore"):  # blow-ups are flagged later
        return _free_run(models, inputs, windows, lengths)


def _free_run(models: Sequence[KernelModel], inputs: Sequence[np.ndarray], windows: Sequence[np.ndarray],
              lengths: Sequence[int]) -> np.ndarray:
    """The time loop of ``free_run``.

    ``inputs[s]`` (n_s, c) standardised inputs, ``windows[s]`` (N, k) standardised measured
    outputs of the init window (the same N for every segment), ``lengths[s]`` = n_s.
    Rows < N are the window (model g reads column ``models[g].target``); from N on each
    model's own outputs are fed back. Values past a segment's length are undefined.
    """
    G, S = len(models), len(inputs)
    N = len(windows[0])
    lengths = np.asarray(lengths, dtype=np.int64)
    T = int(lengths.max())
    order = np.argsort(-lengths, kind="stable")  # longest first: live segments are a prefix
    sorted_len = lengths[order]
    na_max = max(m.na for m in models)
    lu = max(m.nk + m.kb - 1 for m in models)
    c = inputs[0].shape[1]
    du = c * (lu + 1)
    m_max = max(len(m.beta) for m in models)

    # per-model matrices in the common layout: history part (2 na_max rows: y, y^2 per lag, oldest first)
    # and input part ([u lags, u lags^2, 1] rows); padded centres have beta = 0 and contribute nothing
    Cy = np.zeros((G, 2 * na_max, m_max))
    Cu = np.zeros((G, 2 * du + 1, m_max))
    beta = np.zeros((G, m_max, 1))
    for g, m in enumerate(models):
        s, k = m.s, len(m.beta)
        cy, cu = m.centres[:, :m.ka], m.centres[:, m.ka:]
        for i in range(1, m.ka + 1):  # lag i sits at history position na_max - i
            p = na_max - i
            Cy[g, 2 * p, :k] = 2 * s * cy[:, m.ka - i]
            Cy[g, 2 * p + 1, :k] = -s
        for j in range(c):
            for l in range(m.kb):
                col = j * (lu + 1) + m.nk + l
                Cu[g, col, :k] = 2 * s * cu[:, j * m.kb + l]
                Cu[g, du + col, :k] = -s
        Cu[g, 2 * du, :k] = -s * (m.centres ** 2).sum(axis=1)
        beta[g, :k, 0] = m.beta

    # the linear part: output lags as a history product, inputs and constant precomputed for every step
    Ay = np.zeros((G, na_max, 1))
    ll = max(m.nk + m.nb - 1 for m in models)
    Bl = np.zeros((c * (ll + 1), G))
    c0 = np.array([m.c0 for m in models])
    for g, m in enumerate(models):
        Ay[g, na_max - np.arange(1, m.na + 1), 0] = m.a
        for j in range(c):
            Bl[j * (ll + 1) + m.nk + np.arange(m.nb), g] = m.b[j]
    linear = bool(Ay.any() or Bl.any() or c0.any())
    V = np.zeros((S, T, G))
    if linear:
        for r, s_idx in enumerate(order):
            V[r] = _input_lags(inputs[s_idx], ll, T) @ Bl + c0

    Zu = np.zeros((S, T, 2 * du + 1))
    for r, s_idx in enumerate(order):
        lag = _input_lags(inputs[s_idx], lu, T)
        Zu[r, :, :du] = lag
        Zu[r, :, du:2 * du] = lag ** 2
        Zu[r, :, 2 * du] = 1.0
    H = np.zeros((G, S, na_max + T, 2))
    for r, s_idx in enumerate(order):
        w = windows[s_idx][:, [m.target for m in models]].T  # (G, N)
        H[:, r, :na_max, 0] = w[:, :1]
        H[:, r, na_max:na_max + N, 0] = w
    H[..., 1] = H[..., 0] ** 2

    steps = max(1, int(CHUNK_MIB * 2**20 // (8 * G * S * m_max)))
    E_buf = np.empty((G, S, m_max))
    y_buf = np.empty((G, S, 1))
    e1 = np.empty(m_max)
    Cy1, H1 = Cy[0], H[0, 0]
    Cu2 = np.ascontiguousarray(Cu.transpose(1, 0, 2).reshape(2 * du + 1, G * m_max))
    beta1 = beta[0, :, 0]
    ay1 = Ay[0, :, 0]
    H0 = H[..., 0]  # the outputs alone, (G, S, na_max + T) strided view
    for t0 in range(N, T, steps):
        t1 = min(T, t0 + steps)
        live = int(np.searchsorted(-sorted_len, -(t0 + 1), side="right"))  # segments with row t0
        # the input part of every step's exponent in the block, one 2-D product (BLAS): rows (segment, step),
        # columns (model, centre); a step then adds its row to the history product and takes one exp2
        P = (Zu[:live, t0:t1].reshape(live * (t1 - t0), -1) @ Cu2).reshape(live, t1 - t0, G, m_max)
        if G == 1 and live == 1:  # the common predict case, in 1-D operations (half the overhead)
            P1, V1, h1 = P[0, :, 0], V[0, :, 0], H0[0, 0]
            for t in range(t0, t1):
                np.dot(H1[t:t + na_max].reshape(-1), Cy1, out=e1)
                e1 += P1[t - t0]
                np.exp2(e1, out=e1)
                v = float(np.dot(e1, beta1))
                if linear:
                    v += float(np.dot(h1[t:t + na_max], ay1)) + V1[t]
                H1[na_max + t, 0] = v
                H1[na_max + t, 1] = v * v
            continue
        for t in range(t0, t1):
            while live and sorted_len[live - 1] <= t:
                live -= 1
            hist = H[:, :live, t:t + na_max, :].reshape(G, live, 2 * na_max)
            E = E_buf[:, :live] if live < S else E_buf
            np.matmul(hist, Cy, out=E)
            E += P[:live, t - t0].transpose(1, 0, 2)
            np.exp2(E, out=E)
            y = y_buf[:, :live] if live < S else y_buf
            np.matmul(E, beta, out=y)
            if linear:
                y += np.matmul(H0[:, :live, t:t + na_max], Ay)
                y += V[:live, t].T[..., None]
            H[:, :live, na_max + t, 0] = y[..., 0]
            np.square(y[..., 0], out=H[:, :live, na_max + t, 1])
    out = np.empty((G, S, T))
    out[:, order] = H[:, :, na_max:, 0]
    return out


def nystroem_ridge(Z: np.ndarray, y: np.ndarray, C: np.ndarray, gamma: float, lambdas: np.ndarray,
                   Phi: np.ndarray | None = None, block_rows: int = 4096
                   ) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Nystroem kernel ridge with an optional unpenalised linear part, for every lambda.

    Minimises |K_nm beta + Phi theta - y|^2 + lambda beta^T K_mm beta. Solved directly, not
    iteratively: with K_mm = V diag(s) V^T (components with s below ``NYSTROEM_RTOL`` x max s
    dropped, the pseudo-inverse convention) and T = V s^-1/2, beta = T w and the problem is
    ridge regression on the features F = K_nm T (n x r) with Phi unpenalised: Phi is
    projected out of F and y (its orthonormal basis from a pivoted QR), one
    eigendecomposition of the projected F^T F serves every lambda, and theta is the least
    squares fit of Phi to what the kernel leaves. With every row a centre (C = Z) and no
    Phi this is exact KRLS. Returns beta (L, m), theta (L, p) or None, and the rank r.
    BLAS runs single-threaded here: on a shared 2-core machine a threaded eigh of a 200 x 200
    matrix took 1 s instead of 14 ms (threads spinning against other processes).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _nystroem_ridge(Z, y, C, gamma, lambdas, Phi, block_rows)


def _nystroem_ridge(Z: np.ndarray, y: np.ndarray, C: np.ndarray, gamma: float, lambdas: np.ndarray,
                    Phi: np.ndarray | None, block_rows: int) -> tuple[np.ndarray, np.ndarray | None, int]:
    s, V = scipy.linalg.eigh(gaussian(sq_distances(C), gamma))
    keep = s > NYSTROEM_RTOL * s.max()
    T = V[:, keep] / np.sqrt(s[keep])
    r = T.shape[1]
    F = np.empty((len(Z), r))
    for a in range(0, len(Z), block_rows):
        F[a:a + block_rows] = gaussian(sq_distances(Z[a:a + block_rows], C), gamma) @ T
    Fp, yp = F, y
    if Phi is not None:
        Q, R, _ = scipy.linalg.qr(Phi, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        Q = Q[:, :int(np.sum(diag > diag.max() * 1e-12 * max(Phi.shape)))] if diag.size and diag.max() > 0 else Q[:, :0]
        Fp = F - Q @ (Q.T @ F)
        yp = y - Q @ (Q.T @ y)
    ev, W = scipy.linalg.eigh(Fp.T @ Fp)
    ev = np.maximum(ev, 0.0)
    Wb = W.T @ (Fp.T @ yp)
    ws = [W @ (Wb / (ev + lam)) for lam in np.asarray(lambdas, dtype=np.float64)]
    betas = np.stack([T @ w for w in ws])
    thetas = None
    if Phi is not None:
        thetas = np.stack([scipy.linalg.lstsq(Phi, y - F @ w, lapack_driver="gelsd", check_finite=False)[0]
                           for w in ws])
    return betas, thetas, r


# --------------------------------------------------------------------------- method
class NARX(GivenOrders, Method):
    """Kernel NARX: KRLS on lagged outputs and inputs, one step ahead; predicted in free run."""

    name = NAME
    family = "data-driven"
    modes = frozenset({"simulation"})
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
        grid("gamma_grid", (-3.0, 0.0, 4), "kernel widths searched: log10 of gamma relative to the regressor count d "
             "(low, high, count)", searches=("gamma",)),
        grid("lambda_grid", (-12.0, -4.0, 5), "ridge penalties searched: log10 of lambda relative to the number of "
             "regression rows (low, high, count)", searches=("lambda",)),
        whole("exact_max_rows", 1000, "every regression row a kernel centre up to this many rows, Nystroem centres "
              "above", low=1, unit="rows"),
        whole("centres", 500, "Nystroem centres (the cost of one simulated step)", low=1, unit="rows"),
        whole("max_rows", 20000, "regression rows used (a uniform subsample above; 0 = all)", low=0, unit="rows"),
        ENVELOPE,
    )

    # -- grid ---------------------------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        """Lags (tied na = nb unless given), nk, gamma and lambda (module docstring)."""
        given = self.given_orders
        sizes = [len(s) for s in data.segments] or [0]
        derived = derived_orders(min(sizes), sum(sizes), len(data.input_names), int(self.options["max_lag"]),
                                 LAG_BASE)
        space: SearchSpace = {}
        na, nb = given["na"], given["nb"]
        if na is None and nb is None:
            space["lags"] = np.array(derived)
        else:
            space["na"] = np.array(na if na is not None else derived)
            space["nb"] = np.array(nb if nb is not None else derived)
        space["nk"] = np.array(given["nk"])
        space["gamma"] = log_grid(*self._grid("gamma_grid"))
        space["lambda"] = log_grid(*self._grid("lambda_grid"))
        return space

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

    def _models(self, std: _Standardised, k: int, points: Sequence[tuple[int, int, int, float, float]],
                rng: np.random.Generator, strict: bool = True
                ) -> tuple[list[list[KernelModel] | None], str, int, dict[str, Any]]:
        """Models for every point (one per target), sharing regressors per order and solves per gamma.

        With ``strict=False`` (selection) orders that leave too few regression rows give
        None for their points instead of an error: they score +inf, the others go on.
        """
        out: list[list[KernelModel | None]] = [[None] * k for _ in points]
        solver, n_rows, info = "exact", 0, {}
        linear = bool(self.options["linear"])
        c = len(std.u_mean)
        by_orders: dict[tuple[int, int, int], list[int]] = {}
        for i, (na, nb, nk, _, _) in enumerate(points):
            by_orders.setdefault((na, nb, nk), []).append(i)
        for (na, nb, nk), members in by_orders.items():
            ka, kb = self._kernel_lags(na, nb)
            # kernel columns of the full lag matrix: the last ka output lags, the first kb lags of each input
            kcols = list(range(na - ka, na)) + [na + j * nb + l for j in range(c) for l in range(kb)]
            for target in range(k):
                Z, y = regressors(std.traj, target, na, nb, nk)
                need = 2 + (Z.shape[1] + 1 if linear else 0)
                if len(y) < need and not strict:
                    for i in members:
                        out[i] = None  # type: ignore[call-overload]
                    break
                if len(y) < need:
                    longest = max(len(tr.Y) for tr in std.traj)
                    raise MethodError(f"method {NAME!r}: lags na={na}, nb={nb}, nk={nk} leave {len(y)} regression rows "
                                      f"for {need - 1} linear parameters (longest training segment {longest} rows); "
                                      "use fewer lags")
                rows = self._rows(len(y), rng)
                Z, y = Z[rows], y[rows]
                n_rows = len(y)
                Zk = np.ascontiguousarray(Z[:, kcols])
                Phi = np.hstack([Z, np.ones((n_rows, 1))]) if linear else None
                if n_rows > int(self.options["exact_max_rows"]):  # one draw serves every gamma of these regressors
                    centres = np.sort(rng.choice(n_rows, size=min(int(self.options["centres"]), n_rows), replace=False))
                    C, solver = Zk[centres], "nystroem"
                else:
                    C, solver = Zk, "exact"
                gammas = np.array([points[i][3] for i in members])
                for gamma in dict.fromkeys(gammas.tolist()):
                    idx = [members[j] for j in np.flatnonzero(gammas == gamma)]
                    lams = np.array([points[i][4] for i in idx])
                    betas, thetas, rank = nystroem_ridge(Zk, y, C, gamma / Zk.shape[1], lams * n_rows, Phi)
                    info = {"kernel_rank": rank}
                    for pos, (i, lam) in enumerate(zip(idx, lams)):
                        th = thetas[pos] if thetas is not None else np.zeros(Z.shape[1] + 1)
                        out[i][target] = KernelModel(
                            na=na, nb=nb, nk=nk, ka=ka, kb=kb, a=np.ascontiguousarray(th[:na][::-1]),
                            b=np.ascontiguousarray(th[na:na + c * nb].reshape(c, nb)), c0=float(th[-1]),
                            centres=np.ascontiguousarray(C), beta=np.ascontiguousarray(betas[pos]), gamma=gamma,
                            lam=float(lam), target=target)
        return out, solver, n_rows, info  # type: ignore[return-value]

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> NARXFit:
        """One step ahead on the training segments; the kernel rows and centres are drawn with ``rng``."""
        self.check_mode(train.mode)
        point = self._point(params)
        std = _standardise(training_trajectories(NAME, train), float(self.options["envelope"]))
        models, solver, n_rows, info = self._models(std, len(train.target_names), [point], rng)
        return NARXFit(models=tuple(models[0]), y_mean=std.y_mean, y_std=std.y_std, u_mean=std.u_mean,
                       u_std=std.u_std, input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                       envelope=std.envelope, solver=solver, n_rows=n_rows, info=info)

    # -- prediction ------------------------------------------------------------------------------
    def _simulate(self, fits: Sequence[NARXFit], data: Samples) -> list[tuple[list[np.ndarray], np.ndarray]]:
        """Free runs of every fit (all of them share the standardisation) on ``data``: per fit (arrays, diverged)."""
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
            runs = free_run(models, U, W, lengths)  # (fits * k, segments, T)
            for f_idx, f in enumerate(fits):
                for r, i in enumerate(members):
                    n = lengths[r]
                    traj = runs[f_idx * k:(f_idx + 1) * k, r, :n].T * f.y_std + f.y_mean
                    traj[:N] = windows[i]  # the window is measured (exactly, not through the scaling)
                    traj, bad = f.envelope.clip_run(traj, N)
                    results[f_idx][i] = traj[data.segments[i].rows]
                    flags[f_idx][i] = bad
        return [(arrays, fl) for arrays, fl in zip(results, flags)]  # type: ignore[misc]

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
        std = _standardise(training_trajectories(NAME, train), float(self.options["envelope"]))
        models, solver, n_rows, info = self._models(std, k, points, rng, strict=False)
        usable = [i for i, ms in enumerate(models) if ms is not None]
        out[[i for i in range(len(points)) if i not in usable]] = np.nan  # too few rows for these lags: +inf score
        if not usable:
            return out
        fits = [NARXFit(models=tuple(models[i]), y_mean=std.y_mean, y_std=std.y_std, u_mean=std.u_mean,  # type: ignore
                        u_std=std.u_std, input_names=tuple(train.input_names), target_names=tuple(train.target_names),
                        envelope=std.envelope, solver=solver, n_rows=n_rows) for i in usable]
        for i, (arrays, _) in zip(usable, self._simulate(fits, data)):
            out[i] = np.concatenate(arrays)
        return out

    def describe(self, fitted: NARXFit) -> dict[str, Any]:
        """Orders, kernel hyperparameters, the linear part (standardised) with its poles, solver facts."""
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
            **fitted.info,
        }
