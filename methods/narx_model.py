"""Kernel-NARX numerics: the fitted model, regressors, the batched free run and the Nystroem solve.

The numbers behind the ``narx`` method (``methods/narx.py``, which holds the Method: options,
grid, selection, fitting and prediction flow); kept apart so the Method reads as the
protocol and this module as the arithmetic.

Solvers: up to ``exact_max_rows`` regression rows, exact (the centres c_i are all rows);
above,
``centres`` Nystroem centres drawn uniformly without replacement with the job's generator
(as FALKON draws them, ``methods/numerics/falkon.py``) and the Nystroem problem
min |K_nm beta + Phi theta - y|^2 + lambda beta^T K_mm beta (Phi the linear regressors)
solved directly (``nystroem_ridge``: ridge on the features K_nm V s^-1/2 with Phi
projected out, one eigendecomposition per gamma serves every lambda).
Direct, because free-run selection prefers small gamma and lambda, where FALKON's
conjugate gradient had not converged after 50 iterations on Silverbox (relative residual
0.016 at gamma = 0.03, lambda = 1e-10): its early stop would be a hidden regulariser.
Training sets larger than ``max_rows`` rows are subsampled uniformly for the joint solve (rows
are independent regression pairs one step ahead), and the linear part is then fitted again on
every row with the kernel sum held fixed (``linear_on_all_rows``). A simulated step costs O(centres x d), never
O(training rows).

Free run (``free_run``): the first lagged outputs are the init window's measured ones
(``y_init``; ``y0`` alone without a window; edge padding before row 0), after the window
only simulated outputs are fed back. All segments, and in ``predict_grid`` all grid
points (and targets), step together in one time loop: per step one product of the
output-lag history with the centres, one addition of the input part, one exp2 and one
product with the coefficients. The input part of the exponent does not depend on the
simulated outputs, so it is computed for blocks of time steps at once (a matrix
product); the |z|^2 terms are folded into both products (the history stores y and y^2),
so the exponent is -(gamma/d) |z - c|^2 <= 0 exactly as written and f stays bounded; the
linear part is added from the same history.

With a ``KernelBox`` (narx's ``kernel_box = true``: each standardised input's and output's
training minimum and maximum) the kernel reads its regressors clipped to it: inside the
training data nothing changes, outside it the kernel sum holds the value it has at the
box's edge and only the linear part extrapolates. A Gaussian kernel sum fitted with little
regularisation is a fine cancellation of large coefficients, which can break down just past
the data: on the F-16 records a model selected on excitation levels 1 and 3 fitted level 2
at 55.6 % and the louder level 4 at -548 %; clipped, 40 %. Where the law must go on growing
past the data (Silverbox's cubic stiffness) the clip costs instead (docs/benchmarks.md).
The history holds the clipped outputs (and their squares) for the kernel, a second array
the outputs themselves for the linear part. An unstable linear part can still blow a run
up: a run leaving the envelope [min - e span, max + e span] of the training outputs, or
turning non-finite, is flagged and held at its last in-envelope value
(``methods/freerun.py``), as for ``sindy``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from enginebench.methods.freerun import Envelope, Trajectory
from enginebench.methods.numerics.kernels import gaussian, sq_distances

NYSTROEM_RTOL = 1e-10
"""Eigenvalues of K_mm below this fraction of the largest are dropped (Nystroem pseudo-inverse)."""
CHUNK_MIB = 32.0
"""Memory budget of one block of precomputed input exponents (models x segments x steps x centres)."""
LN2 = math.log(2.0)


# --------------------------------------------------------------------------- fitted model
@dataclass(frozen=True)
class KernelBox:
    """The training data's range per standardised signal: the kernel reads its regressors clipped to it."""

    u_lo: np.ndarray
    u_hi: np.ndarray
    """(inputs,) each input's training minimum and maximum."""
    y_lo: np.ndarray
    y_hi: np.ndarray
    """(targets,) each output's."""

    @classmethod
    def of(cls, traj: Sequence[Trajectory]) -> "KernelBox":
        U = np.vstack([t.U for t in traj])
        Y = np.vstack([t.Y for t in traj])
        return cls(U.min(axis=0), U.max(axis=0), Y.min(axis=0), Y.max(axis=0))

    @classmethod
    def unbounded(cls, inputs: int, targets: int) -> "KernelBox":
        """No clipping (a model fitted with ``kernel_box = false``, or stored before the box existed)."""
        return cls(np.full(inputs, -np.inf), np.full(inputs, np.inf), np.full(targets, -np.inf),
                   np.full(targets, np.inf))

    def clip_inputs(self, U: np.ndarray) -> np.ndarray:
        return np.clip(U, self.u_lo, self.u_hi)


@dataclass(frozen=True)
class KernelParts:
    """What a kernel NARX model holds, standardised: lags, a linear ARX part and the kernel sum's centres and
    coefficients, with its relative gamma and lambda (``KernelModel`` per target, ``MIMOModel`` for all)."""

    na: int
    nb: int
    nk: int
    ka: int
    kb: int
    a: np.ndarray
    b: np.ndarray
    c0: Any
    centres: np.ndarray
    beta: np.ndarray
    gamma: float
    """Relative gamma; the kernel is exp(-(gamma / d) |z - c|^2)."""
    lam: float
    """Relative lambda; the solve used lambda x rows."""

    @property
    def d(self) -> int:
        return self.centres.shape[1]

    @property
    def s(self) -> float:
        """exp(-(gamma/d) D) = 2^(-s D)."""
        return self.gamma / self.d / LN2


@dataclass(frozen=True)
class KernelModel(KernelParts):
    """One target's model, standardised: a linear ARX part plus the kernel sum f.

    The linear part reads y(t-1..t-na) (``a[i-1]`` multiplies y(t-i)), u_j(t-nk..t-nk-nb+1)
    (``b[j, l]`` multiplies u_j(t-nk-l)) and a constant ``c0`` (a float); all zero without it. The
    kernel reads the last ``ka`` outputs and ``kb`` input lags: centres (m, ka + inputs x kb)
    in the layout [y(t-ka) .. y(t-1), u_1(t-nk) .. u_1(t-nk-kb+1), u_2 ...].
    """

    target: int
    """Column of the target in the fitted model's targets."""


@dataclass(frozen=True)
class NARXFit:
    """Per-target kernel models (or one MIMO model) plus the standardisation, the envelope and what the solver did."""

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
    mimo: "MIMOModel | None" = None
    """With ``shared_kernel``: the one model of every output (``models`` is then empty)."""
    box: KernelBox | None = None
    """The range the kernel's regressors are clipped to; None: not clipped (``kernel_box = false``)."""

    def kernel_box(self) -> KernelBox:
        """``box``, or one that clips nothing."""
        return self.box if self.box is not None else KernelBox.unbounded(len(self.u_mean), len(self.y_mean))


# --------------------------------------------------------------------------- regression data
@dataclass(frozen=True)
class Standardised:
    """Training trajectories in standardised units and the statistics used."""

    traj: list[Trajectory]
    y_mean: np.ndarray
    y_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray
    envelope: Envelope

    @property
    def box(self) -> KernelBox:
        return KernelBox.of(self.traj)


def standardise(traj: list[Trajectory], envelope: float) -> Standardised:
    Y = np.vstack([t.Y for t in traj])
    U = np.vstack([t.U for t in traj])
    # column by column: numpy sums a contiguous column pairwise but the columns of a wider array row by row, so a
    # target's scaling (and with it its model) would change in the last bits with the other targets beside it
    y_mean = np.array([np.ascontiguousarray(Y[:, j]).mean() for j in range(Y.shape[1])])
    y_std = np.array([np.ascontiguousarray(Y[:, j]).std() for j in range(Y.shape[1])])
    u_mean, u_std = U.mean(axis=0), U.std(axis=0)
    y_std[y_std == 0] = 1.0
    u_std[u_std == 0] = 1.0
    scaled = [Trajectory(t.id, (t.U - u_mean) / u_std, (t.Y - y_mean) / y_std) for t in traj]
    return Standardised(scaled, y_mean, y_std, u_mean, u_std, Envelope.around(Y, envelope))


def regression_count(traj: Sequence[Trajectory], na: int, nb: int, nk: int) -> int:
    """How many regression rows ``regressors`` gives: every sample whose lags lie inside its segment."""
    L = max(na, nk + nb - 1)
    return sum(max(len(tr.Y) - L, 0) for tr in traj)


def _row_times(traj: Sequence[Trajectory], L: int, rows: np.ndarray | None):
    """(segment, its sample indices t) of the regression rows: all of them, or only ``rows`` (sorted indices into
    the rows of all segments in order), so that a subsample is built without the whole lag matrix."""
    start = 0
    for tr in traj:
        n = len(tr.Y)
        if n <= L:
            continue
        if rows is None:
            yield tr, np.arange(L, n)
        else:
            lo, hi = np.searchsorted(rows, [start, start + n - L])
            yield tr, rows[lo:hi] - start + L
        start += n - L


def regressors(traj: Sequence[Trajectory], target: int, na: int, nb: int, nk: int,
               rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rows z(t) = [y(t-na) .. y(t-1), u_j(t-nk) .. u_j(t-nk-nb+1) per input] and y(t), lags inside each segment.

    ``rows`` (sorted, into the ``regression_count`` rows): only those rows, equal to the full matrix's rows
    ``rows`` but built at their cost alone (a 1e7-sample record's full lag matrix would not fit in memory).
    """
    L = max(na, nk + nb - 1)
    Z, y = [], []
    for tr, t in _row_times(traj, L, rows):
        cols = [tr.Y[t[:, None] - np.arange(na, 0, -1)[None, :], target]]
        for j in range(tr.U.shape[1]):
            cols.append(tr.U[t[:, None] - (nk + np.arange(nb))[None, :], j])
        Z.append(np.hstack(cols))
        y.append(tr.Y[t, target])
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
             lengths: Sequence[int], limits: np.ndarray | None = None, box: KernelBox | None = None) -> np.ndarray:
    """Simulate every model on every segment at once, in standardised units: (models, segments, max length).

    See ``_free_run``; BLAS runs single-threaded here: each step's products are far too
    small for threads, which would only add synchronisation to every step. ``limits``
    (models, 2): each model's envelope (lower, upper) in standardised units, a little wider
    than the one ``Envelope.clip_run`` applies; a model that leaves it on every segment is
    no longer simulated (its rows after that are undefined: the clip holds its run from the
    first row out, which it has already reached). ``box``: the range the kernel's regressors are clipped to
    (standardised; every model's target indexes its outputs); None clips nothing.
    """
    if box is None:
        box = KernelBox.unbounded(inputs[0].shape[1], max(m.target for m in models) + 1)
    with threadpool_limits(limits=1, user_api="blas"), np.errstate(all="ignore"):  # blow-ups are flagged later
        return _free_run(models, inputs, windows, lengths, limits, box)


def _free_run(models: Sequence[KernelModel], inputs: Sequence[np.ndarray], windows: Sequence[np.ndarray],
              lengths: Sequence[int], limits: np.ndarray | None, box: KernelBox) -> np.ndarray:
    """The time loop of ``free_run``.

    ``inputs[s]`` (n_s, c) standardised inputs, ``windows[s]`` (N, k) standardised measured
    outputs of the init window (the same N for every segment), ``lengths[s]`` = n_s.
    Rows < N are the window (model g reads column ``models[g].target``); from N on each
    model's own outputs are fed back. Values past a segment's length are undefined.
    ``H`` holds the kernel's history (outputs clipped to the box, and their squares), ``Y`` the outputs.
    """
    G, S = len(models), len(inputs)
    N = len(windows[0])
    lengths = np.asarray(lengths, dtype=np.int64)
    T = int(lengths.max())
    order = np.argsort(-lengths, kind="stable")  # longest first: live segments are a prefix
    sorted_len = lengths[order]
    na_max = max(m.na for m in models)
    ka_max = max(m.ka for m in models)  # the kernel reads the newest ka lags: its history product spans those alone
    lu = max(m.nk + m.kb - 1 for m in models)
    c = inputs[0].shape[1]
    du = c * (lu + 1)
    m_max = max(len(m.beta) for m in models)

    # per-model matrices in the common layout: history part (2 ka_max rows: y, y^2 per lag, oldest first)
    # and input part ([u lags, u lags^2, 1] rows); padded centres have beta = 0 and contribute nothing
    # the input part is the same for models that share centres and lags up to their scale s (the grid's gammas and
    # lambdas on one draw of centres): one product per such group serves them all, scaled (``_input_groups``)
    group, scale, firsts = _input_groups(models)
    Q = len(firsts)
    Cy = np.zeros((G, 2 * ka_max, m_max))
    Cu = np.zeros((Q, 2 * du + 1, m_max))
    beta = np.zeros((G, m_max, 1))
    for g, m in enumerate(models):
        s, k = m.s, len(m.beta)
        cy = m.centres[:, :m.ka]
        for i in range(1, m.ka + 1):  # lag i sits at history position ka_max - i
            p = ka_max - i
            Cy[g, 2 * p, :k] = 2 * s * cy[:, m.ka - i]
            Cy[g, 2 * p + 1, :k] = -s
        beta[g, :k, 0] = m.beta
    for q, g in enumerate(firsts):  # at unit scale
        m = models[g]
        k, cu = len(m.beta), m.centres[:, m.ka:]
        for j in range(c):
            for l in range(m.kb):
                col = j * (lu + 1) + m.nk + l
                Cu[q, col, :k] = 2 * cu[:, j * m.kb + l]
                Cu[q, du + col, :k] = -1.0
        Cu[q, 2 * du, :k] = -(m.centres ** 2).sum(axis=1)

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
        lag = _input_lags(box.clip_inputs(inputs[s_idx]), lu, T)
        Zu[r, :, :du] = lag
        Zu[r, :, du:2 * du] = lag ** 2
        Zu[r, :, 2 * du] = 1.0
    targets = [m.target for m in models]
    y_lim = np.stack([box.y_lo[targets], box.y_hi[targets]], axis=1)  # (G, 2), swapped with the models
    Y = np.zeros((G, S, na_max + T))
    for r, s_idx in enumerate(order):
        w = windows[s_idx][:, targets].T  # (G, N)
        Y[:, r, :na_max] = w[:, :1]
        Y[:, r, na_max:na_max + N] = w
    H = np.zeros((G, S, na_max + T, 2))
    H[..., 0] = np.clip(Y, y_lim[:, 0, None, None], y_lim[:, 1, None, None])
    H[..., 1] = H[..., 0] ** 2

    steps = max(1, int(CHUNK_MIB * 2**20 // (8 * G * S * m_max)))
    E_buf = np.empty((G, S, m_max))
    y_buf = np.empty((G, S, 1))
    e1 = np.empty(m_max)
    Cu2 = np.ascontiguousarray(Cu.transpose(1, 0, 2).reshape(2 * du + 1, Q * m_max))
    kh = na_max - ka_max  # the kernel's history starts this many rows after the linear part's
    # retirement: models are kept in positions; those still simulated are the prefix [0, Ga)
    perm = np.arange(G)  # position -> model
    dead = np.zeros((G, S), dtype=bool)  # left its limits on that (sorted) segment
    lim = None if limits is None else np.array(limits, dtype=np.float64).reshape(G, 2)
    Ga = G
    for t0 in range(N, T, steps):
        t1 = min(T, t0 + steps)
        live = int(np.searchsorted(-sorted_len, -(t0 + 1), side="right"))  # segments with row t0
        # the input part of every step's exponent in the block, one 2-D product (BLAS): rows (segment, step),
        # columns (model, centre); a step then adds its row to the history product and takes one exp2
        P = (Zu[:live, t0:t1].reshape(live * (t1 - t0), -1) @ Cu2).reshape(live, t1 - t0, Q, m_max)
        if Q == G == Ga:  # every model its own group, none retired: the groups are the positions
            P *= scale[:, None]
        else:
            P = P[:, :, group[:Ga]] * scale[:Ga, None]
        if Ga == 1 and live == 1:  # the common predict case, in 1-D operations (half the overhead)
            P1, V1, h1, H1 = P[0, :, 0], V[0, :, 0], Y[0, 0], H[0, 0]
            Cy1, beta1, ay1 = Cy[0], beta[0, :, 0], Ay[0, :, 0]
            lo, hi = float(y_lim[0, 0]), float(y_lim[0, 1])
            for t in range(t0, t1):
                np.dot(H1[t + kh:t + na_max].reshape(-1), Cy1, out=e1)
                e1 += P1[t - t0]
                np.exp2(e1, out=e1)
                v = float(np.dot(e1, beta1))
                if linear:
                    v += float(np.dot(h1[t:t + na_max], ay1)) + V1[t]
                h1[na_max + t] = v
                vc = min(max(v, lo), hi)  # NaN stays NaN, as np.clip
                H1[na_max + t, 0] = vc
                H1[na_max + t, 1] = vc * vc
        else:
            for t in range(t0, t1):
                while live and sorted_len[live - 1] <= t:
                    live -= 1
                hist = H[:Ga, :live, t + kh:t + na_max, :].reshape(Ga, live, 2 * ka_max)
                E = E_buf[:Ga, :live]
                np.matmul(hist, Cy[:Ga], out=E)
                E += P[:live, t - t0].transpose(1, 0, 2)
                np.exp2(E, out=E)
                y = y_buf[:Ga, :live]
                np.matmul(E, beta[:Ga], out=y)
                if linear:
                    y += np.matmul(Y[:Ga, :live, t:t + na_max], Ay[:Ga])
                    y += V[:live, t, :Ga].T[..., None]
                Y[:Ga, :live, na_max + t] = y[..., 0]
                np.clip(y[..., 0], y_lim[:Ga, 0, None], y_lim[:Ga, 1, None], out=H[:Ga, :live, na_max + t, 0])
                np.square(H[:Ga, :live, na_max + t, 0], out=H[:Ga, :live, na_max + t, 1])
        if lim is not None and t1 < T:
            Ga = _retire(Y, H, y_lim, Cy, group, scale, beta, Ay, V, perm, dead, lim, Ga, na_max + t0, na_max + t1,
                         int(np.searchsorted(-sorted_len, -(t1 + 1), side="right")))
            if Ga == 0:
                break
    out = np.empty((G, S, T))
    out[perm[:, None], order[None, :]] = Y[:, :, na_max:]
    return out


def _input_groups(models: Sequence[KernelModel]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(group of each model, its scale s, each group's first model): models holding the same centres array with the
    same lags have input parts equal up to their scale s = gamma / d / ln 2, so one product serves the group."""
    keys: dict[tuple[int, int, int, int], int] = {}
    firsts: list[int] = []
    group = np.empty(len(models), dtype=np.int64)
    for g, m in enumerate(models):
        key = (id(m.centres), m.ka, m.kb, m.nk)
        if key not in keys:
            keys[key] = len(firsts)
            firsts.append(g)
        group[g] = keys[key]
    return group, np.array([m.s for m in models], dtype=np.float64), firsts


def _retire(Y: np.ndarray, H: np.ndarray, y_lim: np.ndarray, Cy: np.ndarray, group: np.ndarray, scale: np.ndarray,
            beta: np.ndarray, Ay: np.ndarray, V: np.ndarray, perm: np.ndarray, dead: np.ndarray, lim: np.ndarray,
            Ga: int, r0: int, r1: int, live: int) -> int:
    """Move the models that left their limits on every segment still running past the simulated prefix.

    Rows ``r0:r1`` of ``Y`` were just simulated. A model whose output left ``lim`` (lower,
    upper; NaN counts as out) on a segment is dead there; once it is dead on each of the
    ``live`` segments still running it is swapped behind position ``Ga`` with every
    per-model array, so later steps skip it. What it would simulate next is never read: its
    run is held from its first row out of the envelope (``Envelope.clip_run``), which lies
    in the rows already simulated. Returns the new ``Ga``.
    """
    vals = Y[:Ga, :live, r0:r1]
    with np.errstate(invalid="ignore"):
        inside = (vals >= lim[:Ga, 0, None, None]) & (vals <= lim[:Ga, 1, None, None])
    dead[:Ga, :live] |= ~inside.all(axis=2)
    if live == 0:
        return 0
    for p in np.flatnonzero(dead[:Ga, :live].all(axis=1))[::-1]:  # from the back: swaps keep earlier positions
        q = Ga - 1
        if p != q:
            for arr in (Y, H, y_lim, Cy, group, scale, beta, Ay, dead, lim, perm):
                arr[[p, q]] = arr[[q, p]]
            V[:, :, [p, q]] = V[:, :, [q, p]]
        Ga -= 1
    return Ga


# --------------------------------------------------------------------------- one kernel for all outputs
@dataclass(frozen=True)
class MIMOModel(KernelParts):
    """Every output's model on ONE kernel (``shared_kernel = true``), standardised: a MIMO NARX.

    Each output reads every output's past. Linear part: ``a[i-1, p, o]`` multiplies y_p(t-i)
    in output o, ``b[j, l, o]`` multiplies u_j(t-nk-l), constant ``c0[o]``. Kernel regressors
    z = [y_1(t-ka) .. y_1(t-1), ..., y_k(t-ka) .. y_k(t-1), u_1(t-nk) .. u_1(t-nk-kb+1), u_2 ...];
    the centres (m, k ka + inputs x kb) and the exponent per centre are shared by the outputs,
    whose coefficients are the columns of ``beta`` (m, k).
    """

    @property
    def k(self) -> int:
        return self.beta.shape[1]


def mimo_regressors(traj: Sequence[Trajectory], na: int, nb: int, nk: int,
                    rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rows z(t) = [y_p(t-na) .. y_p(t-1) for each output p, u_j(t-nk) .. u_j(t-nk-nb+1) per input] and Y(t) (rows, k).

    With one output this is ``regressors(traj, 0, ...)``; ``rows`` as there.
    """
    L = max(na, nk + nb - 1)
    Z, Y = [], []
    for tr, t in _row_times(traj, L, rows):
        k = tr.Y.shape[1]
        lag_rows = t[:, None] - np.arange(na, 0, -1)[None, :]
        cols = [tr.Y[lag_rows, p] for p in range(k)]
        for j in range(tr.U.shape[1]):
            cols.append(tr.U[t[:, None] - (nk + np.arange(nb))[None, :], j])
        Z.append(np.hstack(cols))
        Y.append(tr.Y[t])
    if not Z:
        k = traj[0].Y.shape[1] if traj else 1
        return np.empty((0, k * na + nb * (traj[0].U.shape[1] if traj else 0))), np.empty((0, k))
    return np.vstack(Z), np.vstack(Y)


def mimo_free_run(models: Sequence[MIMOModel], inputs: Sequence[np.ndarray], windows: Sequence[np.ndarray],
                  lengths: Sequence[int], box: KernelBox | None = None) -> np.ndarray:
    """Simulate every MIMO model on every segment at once, standardised: (models, segments, max length, k).

    As ``free_run`` (window rows measured, then every output fed back; BLAS single-threaded),
    with one exponent per centre per step serving all k outputs, the kernel's regressors clipped to
    ``box`` (None: not clipped). Models are not retired.
    """
    if box is None:
        box = KernelBox.unbounded(inputs[0].shape[1], models[0].k)
    with threadpool_limits(limits=1, user_api="blas"), np.errstate(all="ignore"):  # blow-ups are flagged later
        return _mimo_free_run(models, inputs, windows, lengths, box)


def _mimo_free_run(models: Sequence[MIMOModel], inputs: Sequence[np.ndarray], windows: Sequence[np.ndarray],
                   lengths: Sequence[int], box: KernelBox) -> np.ndarray:
    G, S, k = len(models), len(inputs), models[0].k
    N = len(windows[0])
    lengths = np.asarray(lengths, dtype=np.int64)
    T = int(lengths.max())
    order = np.argsort(-lengths, kind="stable")
    sorted_len = lengths[order]
    na_max = max(m.na for m in models)
    ka_max = max(m.ka for m in models)
    lu = max(m.nk + m.kb - 1 for m in models)
    ll = max(m.nk + m.nb - 1 for m in models)
    c = inputs[0].shape[1]
    du = c * (lu + 1)
    m_max = max(len(m.beta) for m in models)

    # history rows per step: (lag position, y or y^2, output), oldest lag first, as in ``_free_run``
    Cy = np.zeros((G, ka_max, 2, k, m_max))
    Cu = np.zeros((G, 2 * du + 1, m_max))
    beta = np.zeros((G, m_max, k))
    Ay = np.zeros((G, na_max, k, k))
    Bl = np.zeros((c * (ll + 1), G, k))
    c0 = np.zeros((G, k))
    for g, m in enumerate(models):
        s, n_c = m.s, len(m.beta)
        for p in range(k):
            for i in range(1, m.ka + 1):
                Cy[g, ka_max - i, 0, p, :n_c] = 2 * s * m.centres[:, p * m.ka + m.ka - i]
                Cy[g, ka_max - i, 1, p, :n_c] = -s
        cu = m.centres[:, k * m.ka:]
        for j in range(c):
            for l in range(m.kb):
                col = j * (lu + 1) + m.nk + l
                Cu[g, col, :n_c] = 2 * s * cu[:, j * m.kb + l]
                Cu[g, du + col, :n_c] = -s
            Bl[j * (ll + 1) + m.nk + np.arange(m.nb), g] = m.b[j]
        Cu[g, 2 * du, :n_c] = -s * (m.centres ** 2).sum(axis=1)
        beta[g, :n_c] = m.beta
        Ay[g, na_max - np.arange(1, m.na + 1)] = m.a
        c0[g] = m.c0
    Cy = Cy.reshape(G, ka_max * 2 * k, m_max)
    Ay = Ay.reshape(G, na_max * k, k)
    Bl = Bl.reshape(c * (ll + 1), G * k)
    Cu2 = np.ascontiguousarray(Cu.transpose(1, 0, 2).reshape(2 * du + 1, G * m_max))

    V = np.empty((S, T, G, k))
    Zu = np.zeros((S, T, 2 * du + 1))
    Yh = np.zeros((G, S, na_max + T, k))  # the outputs (linear part); H: the kernel's clipped ones and squares
    for r, s_idx in enumerate(order):
        V[r] = (_input_lags(inputs[s_idx], ll, T) @ Bl).reshape(T, G, k) + c0
        lag = _input_lags(box.clip_inputs(inputs[s_idx]), lu, T)
        Zu[r, :, :du] = lag
        Zu[r, :, du:2 * du] = lag ** 2
        Zu[r, :, 2 * du] = 1.0
        w = windows[s_idx]  # (N, k)
        Yh[:, r, :na_max] = w[0]
        Yh[:, r, na_max:na_max + N] = w
    H = np.zeros((G, S, na_max + T, 2, k))
    H[..., 0, :] = np.clip(Yh, box.y_lo, box.y_hi)
    H[..., 1, :] = H[..., 0, :] ** 2

    steps = max(1, int(CHUNK_MIB * 2**20 // (8 * G * S * m_max)))
    kh = na_max - ka_max
    for t0 in range(N, T, steps):
        t1 = min(T, t0 + steps)
        live = int(np.searchsorted(-sorted_len, -(t0 + 1), side="right"))
        P = (Zu[:live, t0:t1].reshape(live * (t1 - t0), -1) @ Cu2).reshape(live, t1 - t0, G, m_max)
        for t in range(t0, t1):
            while live and sorted_len[live - 1] <= t:
                live -= 1
            E = np.matmul(H[:, :live, t + kh:t + na_max].reshape(G, live, ka_max * 2 * k), Cy)
            E += P[:live, t - t0].transpose(1, 0, 2)
            np.exp2(E, out=E)
            y = np.matmul(E, beta)
            y += np.matmul(Yh[:, :live, t:t + na_max].reshape(G, live, na_max * k), Ay)
            y += V[:live, t].transpose(1, 0, 2)
            Yh[:, :live, na_max + t] = y
            yc = np.clip(y, box.y_lo, box.y_hi)
            H[:, :live, na_max + t, 0] = yc
            H[:, :live, na_max + t, 1] = yc * yc
    out = np.empty((G, S, T, k))
    out[:, order] = Yh[:, :, na_max:]
    return out


def linear_on_all_rows(build: Any, count: int, kcols: Sequence[int], C: np.ndarray,
                       solved: Sequence[tuple[float, np.ndarray]], block_rows: int = 8192) -> list[np.ndarray]:
    """The linear part fitted again on every one of ``count`` regression rows, each kernel sum held fixed.

    For a fit whose kernel was solved on a row subsample (``max_rows``): ``solved`` lists (gamma
    per regressor, beta) of the kernel sums; each gets theta = argmin |Phi theta - (y - K(z, C) beta)|
    over all rows, Phi the lag rows with a constant. ``build(rows)`` gives the regressors and
    targets of those rows (sorted indices into the ``count`` rows). Streamed in blocks: a QR
    of [Phi | right-hand sides] is updated block by block (each block stacked under the R so
    far), never the whole matrix, so the rows can be many more than fit in memory as one
    matrix, and no normal equations square the lag matrix's condition number. Minimum-norm
    least squares (LAPACK gelsd) on R where the lags are collinear. Returns theta per solved
    sum, (p,) for one target's y, (p, k) for k outputs.
    """
    gammas = list(dict.fromkeys(gamma for gamma, _ in solved))
    # per gamma, its sums' coefficients side by side (m, columns): one kernel and one product per block
    by_gamma = [np.hstack([beta.reshape(len(C), -1) for g, beta in solved if g == gamma]) for gamma in gammas]
    R = None
    for a in range(0, count, block_rows):
        Z, y = build(np.arange(a, min(count, a + block_rows)))
        Y = y.reshape(len(y), -1)
        D = sq_distances(Z[:, kcols], C)
        rhs = [np.tile(Y, B.shape[1] // Y.shape[1]) - gaussian(D, gamma) @ B for gamma, B in zip(gammas, by_gamma)]
        M = np.hstack([Z, np.ones((len(Z), 1)), *rhs])
        R = scipy.linalg.qr(M if R is None else np.vstack([R, M]), mode="r", check_finite=False)[0][:M.shape[1]]
    assert R is not None
    p = R.shape[1] - sum(B.shape[1] for B in by_gamma)
    thetas = scipy.linalg.lstsq(R[:p, :p], R[:p, p:], lapack_driver="gelsd", check_finite=False)[0]
    columns = iter(np.split(thetas, np.cumsum([B.shape[1] for B in by_gamma])[:-1], axis=1))
    per_gamma = {gamma: iter(np.split(next(columns), B.shape[1] // Y.shape[1], axis=1))
                 for gamma, B in zip(gammas, by_gamma)}
    return [next(per_gamma[gamma]).reshape((p, *np.shape(beta)[1:])) for gamma, beta in solved]


class LinearBasis:
    """The unpenalised linear regressors Phi (n, p) of ``nystroem_ridge``, factorised once (pivoted QR).

    One factorisation serves every gamma and lambda of a set of regressors: ``project``
    removes Phi's span from a matrix, ``solve`` gives the least-squares theta of Phi for
    several right-hand sides at once (back substitution when Phi has full numerical rank,
    LAPACK's minimum-norm gelsd otherwise).
    """

    def __init__(self, Phi: np.ndarray) -> None:
        self.Phi = Phi
        Q, R, piv = scipy.linalg.qr(Phi, mode="economic", pivoting=True)
        diag = np.abs(np.diag(R))
        rank = int(np.sum(diag > diag.max() * 1e-12 * max(Phi.shape))) if diag.size and diag.max() > 0 else 0
        self.Q, self.R, self.piv, self.full = Q[:, :rank], R, piv, rank == Phi.shape[1]

    def project(self, X: np.ndarray) -> np.ndarray:
        """X less its part in the span of Phi."""
        return X - self.Q @ (self.Q.T @ X)

    def solve(self, B: np.ndarray) -> np.ndarray:
        """argmin |Phi theta - b| for each column b of B: (p, columns)."""
        if not self.full:
            return scipy.linalg.lstsq(self.Phi, B, lapack_driver="gelsd", check_finite=False)[0]
        theta = np.empty((self.Phi.shape[1], B.shape[1]))
        theta[self.piv] = scipy.linalg.solve_triangular(self.R, self.Q.T @ B, check_finite=False)
        return theta


def nystroem_ridge(Z: np.ndarray, y: np.ndarray, C: np.ndarray, gamma: float, lambdas: np.ndarray,
                   Phi: np.ndarray | LinearBasis | None = None, block_rows: int = 4096
                   ) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Nystroem kernel ridge with an optional unpenalised linear part, for every lambda.

    Minimises |K_nm beta + Phi theta - y|^2 + lambda beta^T K_mm beta. Solved directly, not
    iteratively: with K_mm = V diag(s) V^T (components with s below ``NYSTROEM_RTOL`` x max s
    dropped, the pseudo-inverse convention) and T = V s^-1/2, beta = T w and the problem is
    ridge regression on the features F = K_nm T (n x r) with Phi unpenalised: Phi is
    projected out of F and y (its orthonormal basis from a pivoted QR, ``LinearBasis``:
    pass one to reuse it across gammas), one eigendecomposition of the projected F^T F
    serves every lambda, and theta is the least squares fit of Phi to what the kernel
    leaves. With every row a centre (C = Z) and no Phi this is exact KRLS. Returns beta
    (L, m), theta (L, p) or None, and the rank r; for several outputs ``y`` (n, k) on the
    same kernel, beta (L, m, k) and theta (L, p, k) from the one factorisation.
    BLAS runs single-threaded here: on a shared 2-core machine a threaded eigh of a 200 x 200
    matrix took 1 s instead of 14 ms (threads spinning against other processes).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        basis = LinearBasis(Phi) if isinstance(Phi, np.ndarray) else Phi
        return _nystroem_ridge(Z, y, C, gamma, lambdas, basis, block_rows)


def _nystroem_ridge(Z: np.ndarray, y: np.ndarray, C: np.ndarray, gamma: float, lambdas: np.ndarray,
                    basis: LinearBasis | None, block_rows: int) -> tuple[np.ndarray, np.ndarray | None, int]:
    s, V = scipy.linalg.eigh(gaussian(sq_distances(C), gamma))
    keep = s > NYSTROEM_RTOL * s.max()
    T = V[:, keep] / np.sqrt(s[keep])
    r = T.shape[1]
    F = np.empty((len(Z), r))
    for a in range(0, len(Z), block_rows):
        F[a:a + block_rows] = gaussian(sq_distances(Z[a:a + block_rows], C), gamma) @ T
    Fp, yp = (F, y) if basis is None else (basis.project(F), basis.project(y))
    ev, W = scipy.linalg.eigh(Fp.T @ Fp)
    ev = np.maximum(ev, 0.0)
    Wb = W.T @ (Fp.T @ yp)
    lams = np.asarray(lambdas, dtype=np.float64)
    if y.ndim == 2:  # several outputs on one kernel: k right-hand sides of the same factorisation
        wk = np.stack([W @ (Wb / (ev + lam)[:, None]) for lam in lams])  # (L, r, k)
        betas = np.einsum("mr,lrk->lmk", T, wk)
        thetas = None if basis is None else np.stack([basis.solve(y - F @ w) for w in wk])
        return betas, thetas, r
    ws = np.stack([W @ (Wb / (ev + lam)) for lam in lams])  # (L, r)
    betas = ws @ T.T
    thetas = None if basis is None else basis.solve(y[:, None] - F @ ws.T).T
    return betas, thetas, r
