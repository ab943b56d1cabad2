"""One batched fixed-step integrator for open-loop simulation, with the shared divergence envelope.

Simulating methods (SINDy, MoE) integrate dx/dt = f(x, u) over many segments at once at
the data's sample times: classical RK4 or explicit Euler, one or more fixed steps per
sample interval, the inputs held at the interval's first sample (``hold``) or linearly
interpolated across it (``linear``). A segment whose state turns non-finite or leaves
its envelope [lower, upper] is stopped: its state is held at the last in-envelope value
for the rest of its rows and it is flagged diverged, so blow-ups are counted, never
silently dropped. Arrays are numpy or torch alike (the same code runs on a GPU); the
right-hand side is the caller's and sees only the rows still running.
"""

from __future__ import annotations

import contextlib
from typing import Any, Callable

import numpy as np

METHODS = ("rk4", "euler")
INPUTS = ("hold", "linear")

Rhs = Callable[[Any, Any], Any]
"""f(x (n, k), u (n, m)) -> dx/dt (n, k)."""


def _is_torch(a: Any) -> bool:
    return type(a).__module__.startswith("torch")


def in_envelope(x: Any, lower: Any, upper: Any) -> Any:
    """Rows of ``x`` (..., k) that are finite and inside [lower, upper] in every column (...,)."""
    return _finite(x).all(-1) & ((x >= lower) & (x <= upper)).all(-1)


def _finite(x: Any) -> Any:
    if _is_torch(x):
        import torch

        return torch.isfinite(x)
    return np.isfinite(x)


def hold_after_exit(part: Any, x_start: Any, alive: Any, lower: Any, upper: Any) -> tuple[Any, Any]:
    """Divergence for a block of precomputed steps ``part`` (S, n, k) that follow states ``x_start`` (S, k).

    Each segment keeps its valid prefix (every state in the envelope, and the segment alive
    before the block); after it the last valid state (or ``x_start``) is held. Returns the
    block and the per-segment alive flags at its end.
    """
    if _is_torch(part):
        import torch

        valid = torch.cumprod(in_envelope(part, lower, upper).to(torch.int8), dim=1).bool() & alive[:, None]
        n_valid = valid.sum(1)
        rows = torch.arange(part.shape[0], device=part.device)
        last = torch.where((n_valid > 0)[:, None], part[rows, (n_valid - 1).clamp(min=0)], x_start)
        return torch.where(valid[..., None], part, last[:, None, :]), valid[:, -1]
    valid = np.cumprod(in_envelope(part, lower, upper), axis=1).astype(bool) & alive[:, None]
    n_valid = valid.sum(1)
    last = np.where((n_valid > 0)[:, None], part[np.arange(part.shape[0]), np.maximum(n_valid - 1, 0)], x_start)
    return np.where(valid[..., None], part, last[:, None, :]), valid[:, -1]


def rk4_step(f: Rhs, x: Any, u0: Any, um: Any, u1: Any, h: Any) -> Any:
    """One classical RK4 step of size ``h`` (n, 1) with inputs ``u0``, ``um``, ``u1`` at its start, middle, end."""
    k1 = f(x, u0)
    k2 = f(x + 0.5 * h * k1, um)
    k3 = f(x + 0.5 * h * k2, um)
    k4 = f(x + h * k3, u1)
    return x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def euler_step(f: Rhs, x: Any, u0: Any, h: Any) -> Any:
    """One explicit Euler step of size ``h`` (n, 1) with the inputs ``u0`` at its start."""
    return x + h * f(x, u0)


def _lerp(u0: Any, u1: Any, w: float) -> Any:
    return u0 if w == 0 else u1 if w == 1 else u0 + w * (u1 - u0)


def advance(f: Rhs, x: Any, u0: Any, u1: Any, h: Any, *, method: str = "rk4", inputs: str = "hold",
            substeps: int = 1) -> Any:
    """``x`` after one sample interval of length ``h`` (n, 1), in ``substeps`` equal fixed steps."""
    m = int(substeps)
    hs = h if m == 1 else h / m
    for j in range(m):
        if inputs == "hold":
            ua = ub = u0
        else:
            ua, ub = _lerp(u0, u1, j / m), _lerp(u0, u1, (j + 1) / m)
        if method == "euler":
            x = euler_step(f, x, ua, hs)
        else:
            x = rk4_step(f, x, ua, ua if inputs == "hold" else 0.5 * (ua + ub), ub, hs)
    return x


def integrate(
    f: Rhs,
    x0: Any,
    U: Any,
    H: Any,
    lengths: Any,
    lower: Any,
    upper: Any,
    *,
    method: str = "rk4",
    inputs: str = "hold",
    substeps: int = 1,
) -> tuple[Any, Any]:
    """Open-loop trajectories of dx/dt = f(x, u) for S padded segments at once.

    ``x0`` (S, k) initial states, ``U`` (S, L, m) inputs at the samples, ``H`` (S, L-1) the
    sample intervals, ``lengths`` (S,) each segment's number of samples (rows past it are
    padding and never stepped), ``lower``/``upper`` (k,) the envelope. Every step advances
    the segments still running and in the envelope together, evaluating ``f`` on those rows
    only. Returns the trajectories (S, L, k) (a segment's padding rows repeat its last
    state) and the diverged flags (S,).
    """
    if method not in METHODS:
        raise ValueError(f"integrator: unknown method {method!r}; use one of {', '.join(METHODS)}")
    if inputs not in INPUTS:
        raise ValueError(f"integrator: unknown input interpolation {inputs!r}; use one of {', '.join(INPUTS)}")
    S, L = U.shape[0], U.shape[1]
    if _is_torch(x0):
        import torch

        traj = x0.new_empty((S, L, x0.shape[1]))
        lengths = torch.as_tensor(lengths, device=x0.device)
        alive = torch.ones(S, dtype=torch.bool, device=x0.device)
        guard: Any = contextlib.nullcontext()
    else:
        traj = np.empty((S, L, x0.shape[1]), dtype=np.result_type(x0, np.float64))
        lengths = np.asarray(lengths)
        alive = np.ones(S, dtype=bool)
        guard = np.errstate(all="ignore")  # a diverging step may overflow: it is flagged, not warned about
    x = x0
    traj[:, 0] = x
    with guard:
        for n in range(L - 1):
            run = _rows(alive & (lengths > n + 1))
            if len(run):
                xr = x[run]
                step = advance(f, xr, U[run, n], U[run, n + 1], H[run, n : n + 1], method=method, inputs=inputs,
                               substeps=substeps)
                ok = in_envelope(step, lower, upper)
                x = x.clone() if _is_torch(x) else x.copy()
                x[run] = _where(ok[:, None], step, xr)  # a diverged segment is held where it left
                alive[run] = alive[run] & ok
            traj[:, n + 1] = x
    return traj, ~alive


def _rows(mask: Any) -> Any:
    return mask.nonzero(as_tuple=True)[0] if _is_torch(mask) else mask.nonzero()[0]


def _where(cond: Any, a: Any, b: Any) -> Any:
    if _is_torch(a):
        import torch

        return torch.where(cond, a, b)
    return np.where(cond, a, b)
