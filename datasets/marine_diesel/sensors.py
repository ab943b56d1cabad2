"""Sensor and lag helpers: first-order lags over runs of rows, noise and quantisation.

A first-order lag tau dy/dt = u - y is discretised exactly for an input held over each
sample period (zero-order hold on the sample *ending* at t_k):
y_k = a y_{k-1} + (1 - a) u_k with a = exp(-dt / tau), evaluated with
``scipy.signal.lfilter`` run by run (a run is a stretch of rows whose state carries on;
each run starts at rest, y = u, unless a start value is given). This is the
thermocouple model of egt-hybrid eqs. 4-5 (first-order response with a time constant
and a bias) and the thermal inertia of the cooling-water and lube-oil blocks.

Logged channels get white Gaussian noise and are rounded to the logger's resolution;
both are drawn from a ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter


def first_order_lag(u: np.ndarray, tau_s: float, dt: float, starts: np.ndarray | None = None,
                    y0: np.ndarray | None = None) -> np.ndarray:
    """Lag ``u`` (n,) through 1/(tau s + 1), restarting at every index in ``starts``.

    ``starts`` are the first rows of the runs (default: one run from row 0); ``y0``,
    one value per run, is the output before the first row of each run (default: the
    run's first input, i.e. starting at rest). ``tau_s`` <= 0 returns ``u`` unchanged.
    """
    u = np.asarray(u, dtype=float)
    if tau_s <= 0:
        return u.copy()
    a = float(np.exp(-dt / tau_s))
    starts = np.array([0]) if starts is None else np.asarray(starts, dtype=np.int64)
    stops = np.r_[starts[1:], len(u)]
    out = np.empty_like(u)
    b_coef, a_coef = [1.0 - a], [1.0, -a]
    for i, (s, e) in enumerate(zip(starts, stops)):
        if e <= s:
            continue
        prev = u[s] if y0 is None else float(y0[i])
        out[s:e], _ = lfilter(b_coef, a_coef, u[s:e], zi=[a * prev])
    return out


def run_starts(run_ids: np.ndarray) -> np.ndarray:
    """Indices where a new run begins in an array of run ids (rows grouped by run)."""
    run_ids = np.asarray(run_ids)
    if run_ids.size == 0:
        return np.zeros(0, dtype=np.int64)
    return np.r_[0, np.flatnonzero(run_ids[1:] != run_ids[:-1]) + 1]


def ar1_noise(n: int, sigma: float, tau_s: float, dt: float, rng: np.random.Generator,
              starts: np.ndarray | None = None) -> np.ndarray:
    """Coloured noise: white noise through a first-order lag, scaled to standard deviation ``sigma``."""
    if tau_s <= 0:
        return sigma * rng.standard_normal(n)
    a = np.exp(-dt / tau_s)
    white = rng.standard_normal(n) * np.sqrt((1.0 + a) / (1.0 - a))  # unit variance after the lag
    n_runs = 1 if starts is None else len(starts)
    return sigma * first_order_lag(white, tau_s, dt, starts, y0=rng.standard_normal(n_runs))


@dataclass(frozen=True)
class SensorSpec:
    """Measurement error of one logged channel: white noise and logger resolution.

    The noise standard deviation is ``noise + noise_rel * |value|`` (absolute plus a
    fraction of the reading, as flow meters and torque meters specify it).
    """

    noise: float
    resolution: float
    noise_rel: float = 0.0

    def measure(self, true: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The logged value: true + N(0, sd^2), rounded to ``resolution``."""
        x = np.asarray(true, dtype=float)
        if self.noise > 0 or self.noise_rel > 0:
            x = x + (self.noise + self.noise_rel * np.abs(x)) * rng.standard_normal(x.shape)
        if self.resolution > 0:
            x = np.round(x / self.resolution) * self.resolution
        return x
