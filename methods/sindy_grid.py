"""SINDy's grid numerics: every candidate model's free run in one time loop, and derivatives kept per segment.

``simulate_candidates`` integrates C polynomial models over the same S segments at once:
the C x S (model, segment) pairs are the rows of one state array, advanced together by
the shared fixed-step integrator's step (``numerics.integrate.advance``: RK4 or Euler,
inputs held between samples) with the shared envelope rule (a row leaving [lower, upper]
or going non-finite is held at its last in-envelope value and flagged). Models with the
same library (the same ``powers``) share one library evaluation per stage; each row then
takes its own model's coefficients. Every operation acts on each row alone and in a fixed
order, so a model's trajectories do not depend on which other models share the loop:
``SINDy.predict`` (C = 1) and ``SINDy.predict_grid`` (the whole grid) give the same numbers.

``segment_derivative`` differentiates one segment scaled by its own mean and standard
deviation and keeps the result (raw units per second) keyed on the segment's content and
the derivative settings, so the k-fold fits and the final fit of a job differentiate a
record they share once (``derivative_scale = "segment"``).
"""

from __future__ import annotations

import warnings
from collections import OrderedDict
from typing import Any, Sequence

import numpy as np

from enginebench.errors import MethodError
from enginebench.methods.numerics.derivatives import digest
from enginebench.methods.numerics.integrate import advance, in_envelope
from enginebench.methods.sindy_library import INTEGRATORS, differentiate, library_features


def _group_rhs(groups: list[tuple[np.ndarray, np.ndarray]], row_group: np.ndarray, row_cand: np.ndarray):
    """A stateful right-hand side: ``bind(rows)`` fixes the running rows, then ``f(x, u)`` evaluates them."""
    state: dict[str, Any] = {}

    def bind(rows: np.ndarray) -> None:
        g = row_group[rows]
        state["parts"] = [(sel, groups[j][1][row_cand[rows[sel]]], groups[j][0])
                          for j in range(len(groups)) if (sel := np.flatnonzero(g == j)).size]

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        z = x if u.shape[1] == 0 else np.hstack([x, u])
        out = np.empty_like(x)
        for sel, weights, powers in state["parts"]:
            theta = library_features(z[sel], powers)
            out[sel] = (theta[:, :, None] * weights).sum(axis=1)
        return out

    return bind, f


def simulate_candidates(
    coefs: Sequence[np.ndarray],
    powers: Sequence[np.ndarray],
    x0: np.ndarray,
    controls: Sequence[np.ndarray],
    times: Sequence[np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    *,
    integrator: str = "rk4",
    substeps: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Free runs of C models ``dx/dt = coefs[c] @ theta_c(x, u)`` on S segments, all in one time loop.

    ``coefs[c]`` (k, n_terms_c) and ``powers[c]`` (n_terms_c, k + m) define model c; ``x0``
    (S, k) or (C, S, k) the initial states; ``controls[s]`` (N_s, m) and ``times[s]``
    (N_s,) segment s's inputs and sample times. Returns the trajectories (C, S, L, k)
    padded to the longest segment (rows past a segment's end repeat its last state), the
    segment lengths (S,) and the diverged flags (C, S). Step for step the same arithmetic
    as ``sindy_library.simulate_batch`` (which multiplies the library by the coefficients
    in one matrix product: the sums may differ in the last bits).
    """
    if integrator not in INTEGRATORS:
        raise MethodError(f"sindy: unknown integrator {integrator!r}; use one of {', '.join(INTEGRATORS)}")
    C, S = len(coefs), len(times)
    if len(powers) != C or len(controls) != S:
        raise MethodError("sindy: simulate_candidates needs one powers table per model and one control array per time array")
    x0 = np.asarray(x0, dtype=np.float64)
    x0 = np.broadcast_to(x0, (C, *x0.shape)) if x0.ndim == 2 else x0
    k = x0.shape[-1]
    lengths = np.array([len(t) for t in times], dtype=np.int64)
    if C == 0 or S == 0:
        return np.zeros((C, S, 0, k)), lengths, np.zeros((C, S), dtype=bool)
    m = controls[0].shape[1] if np.ndim(controls[0]) == 2 else 0
    L = int(lengths.max())
    U = np.zeros((S, L, m))
    H = np.zeros((S, max(L - 1, 0)))
    for j, (c, t) in enumerate(zip(controls, times)):
        U[j, : lengths[j]] = np.asarray(c, dtype=np.float64).reshape(lengths[j], m)
        H[j, : lengths[j] - 1] = np.diff(np.asarray(t, dtype=np.float64))
    # models grouped by library; weights (models of the group, n_terms, k) = coef transposed
    keys: dict[bytes, int] = {}
    members: list[list[int]] = []
    group_of = np.empty(C, dtype=np.int64)
    local = np.empty(C, dtype=np.int64)
    for c, p in enumerate(powers):
        p = np.asarray(p, dtype=np.int64)
        key = repr(p.shape).encode() + p.tobytes()
        j = keys.setdefault(key, len(members))
        if j == len(members):
            members.append([])
        group_of[c], local[c] = j, len(members[j])
        members[j].append(c)
    groups = [(np.asarray(powers[ms[0]], dtype=np.int64),
               np.stack([np.asarray(coefs[c], dtype=np.float64).T for c in ms])) for ms in members]
    row_cand = np.repeat(np.arange(C), S)
    row_seg = np.tile(np.arange(S), C)
    bind, f = _group_rhs(groups, group_of[row_cand], local[row_cand])
    row_len = lengths[row_seg]
    x = x0.reshape(C * S, k).copy()
    traj = np.empty((C * S, L, k))
    traj[:, 0] = x
    alive = np.ones(C * S, dtype=bool)
    with np.errstate(all="ignore"):  # a diverging step may overflow: it is flagged, not warned about
        for n in range(L - 1):
            run = np.flatnonzero(alive & (row_len > n + 1))
            if run.size:
                seg = row_seg[run]
                bind(run)
                xr = x[run]
                step = advance(f, xr, U[seg, n], U[seg, n + 1], H[seg, n : n + 1], method=integrator,
                               inputs="hold", substeps=int(substeps))
                ok = in_envelope(step, lower, upper)
                x[run] = np.where(ok[:, None], step, xr)
                alive[run] = ok
            traj[:, n + 1] = x
    return traj.reshape(C, S, L, k), lengths, ~alive.reshape(C, S)


# --------------------------------------------------------------------------- derivatives per segment
SEGMENT_CACHE_SIZE = 256
"""Segment derivatives kept per process (least recently used dropped first): a campaign's records,
their k-fold pieces and, for second-order models, their derivatives' derivatives."""
_segment_cache: "OrderedDict[bytes, tuple[np.ndarray, int]]" = OrderedDict()


def clear_segment_cache() -> None:
    """Forget every kept segment derivative."""
    _segment_cache.clear()


def segment_scale(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of each column of ``y`` (n, k); a constant column's deviation counts as 1."""
    mean, std = y.mean(axis=0), y.std(axis=0)
    return mean, np.where(std > 0, std, 1.0)


def segment_derivative(y: np.ndarray, dt: float, settings: dict[str, Any]) -> tuple[np.ndarray, int]:
    """d y / dt (raw units per second) of one uniformly sampled segment ``y`` (n, k), kept per content,
    and the number of its derivative windows that did not fully converge.

    ``y`` is standardised by its own mean and deviation (``segment_scale``) and
    differentiated by ``sindy_library.differentiate`` with ``settings`` (kind, alpha, chunk,
    margin, max_iter, solver), so the regularisation is relative to the segment's own
    scale and the result depends on the segment alone: the same record in another fold's
    training set (or the final fit) is read from the cache. The kept array is read-only.
    """

    y = np.asarray(y, dtype=np.float64)
    key = digest([y], (float(dt), sorted(settings.items())))
    if key in _segment_cache:
        _segment_cache.move_to_end(key)
        return _segment_cache[key]
    mean, std = segment_scale(y)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        d = differentiate((y - mean) / std, float(dt), **settings) * std
    d.flags.writeable = False
    kept = (d, sum("converge" in str(w.message) for w in caught))
    _segment_cache[key] = kept
    while len(_segment_cache) > SEGMENT_CACHE_SIZE:
        _segment_cache.popitem(last=False)
    return kept


# --------------------------------------------------------------------------- STLSQ on the library's Gram matrix
STLSQ_MAX_ITER = 20
"""Thresholding passes (pysindy's STLSQ default)."""


def library_gram(states: Sequence[np.ndarray], controls: Sequence[np.ndarray] | None, targets: Sequence[np.ndarray],
                 powers: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(Theta' Theta, Theta' X_dot)`` of the polynomial library over every training segment, summed per segment."""
    T = powers.shape[0]
    G, B = np.zeros((T, T)), np.zeros((T, targets[0].shape[1]))
    for j, (x, xd) in enumerate(zip(states, targets)):
        z = x if controls is None else np.hstack([x, controls[j]])
        theta = library_features(z, powers)
        G += theta.T @ theta
        B += theta.T @ xd
    return G, B


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A symmetric system by Cholesky, or least squares where A is singular."""
    try:
        return np.linalg.solve(A, b) if np.all(np.isfinite(A)) else np.full(b.shape, np.nan)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def stlsq_gram(G: np.ndarray, B: np.ndarray, threshold: float, alpha: float,
               max_iter: int = STLSQ_MAX_ITER) -> tuple[np.ndarray, list[str]]:
    """Sequentially thresholded least squares (pysindy's ``STLSQ`` with its defaults) from the normal equations.

    Each pass fits every equation's kept terms by ridge regression (``alpha``) and drops the
    terms smaller than ``threshold``; passes stop when no term was dropped from the full
    library in the first pass, when the kept terms did not change (the first pass compares
    with the least-squares fit of the full library), or after ``max_iter``; the kept terms are
    then refitted by least squares (unbiased). Working on ``G = Theta' Theta`` and
    ``B = Theta' X_dot`` makes a fit cost O(terms^3) whatever the number of samples.
    Returns the coefficients (targets, terms) and pysindy's warning lines for the notes.
    """
    T, k = G.shape[0], B.shape[1]
    notes: list[str] = []
    previous = np.linalg.lstsq(G, B, rcond=None)[0].T  # the full library's least squares (pysindy's history start)
    ind = np.ones((k, T), dtype=bool)
    coef = np.zeros((k, T))
    empty = f"Sparsity parameter is too big ({threshold}) and eliminated all coefficients"
    for _ in range(max_iter):
        if not ind.any():
            notes.append(empty)
            coef = np.zeros((k, T))
            break
        coef = np.zeros((k, T))
        for i in range(k):
            kept = np.flatnonzero(ind[i])
            if not kept.size:
                notes.append(empty)
                continue
            A = G[np.ix_(kept, kept)].copy()
            A.flat[:: kept.size + 1] += alpha
            c = np.zeros(T)
            c[kept] = _solve(A, B[kept, i])
            big = np.abs(c) >= threshold
            c[~big] = 0.0
            coef[i], ind[i] = c, big
        unchanged = np.array_equal(coef != 0, previous != 0)
        previous = coef
        if ind.sum() == k * T or unchanged:
            break
    else:
        notes.append(f"STLSQ did not converge after {max_iter} iterations.")
    ind = np.abs(coef) > 1e-14
    out = np.zeros((k, T))
    for i in range(k):
        kept = np.flatnonzero(ind[i])
        if kept.size:
            out[i, kept] = np.linalg.lstsq(G[np.ix_(kept, kept)], B[kept, i], rcond=None)[0]
    return out, notes
