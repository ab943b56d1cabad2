"""Closed-loop simulation of the twin-engine drive train, batched over trajectories.

One time loop advances every trajectory of the batch at once (numpy vectors of length
batch for the rotor and engines x batch for the engines). Each step (sub-stepped):

1. each FADEC computes its fuel command from the turboshaft-moe paper's eq. 2 — PID on the rotor-speed
   error plus a lead-lag on the collective — with gains scheduled on delta sqrt(theta),
   a slow torque-matching trim, then applies rate and min/max limits with
   back-calculation anti-windup;
2. the engines respond (``engine.engine_step``);
3. the rotor speed integrates engine torque minus the rotor's load, which depends on
   collective, airspeed, air density and rotor speed.

Each trajectory starts trimmed (steady state) at its first sample.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Callable

import numpy as np

from enginebench.datasets.turboshaft.atmosphere import RHO_SL
from enginebench.datasets.turboshaft.engine import (
    EngineCoefficients, ambient_ratios, engine_coefficients, engine_step, power_turbine_speed, shaft_step, trimmed_state,
)
from enginebench.datasets.turboshaft.params import WF_REF, EngineParams, FadecParams, RotorParams
from enginebench.datasets.turboshaft.rotor import load_terms
from enginebench.errors import DataError

_COEFFICIENT_FIELDS = tuple(f.name for f in fields(EngineCoefficients))


@dataclass(frozen=True)
class LoopInputs:
    """Exogenous signals of a batch, each of shape (T, batch).

    ``col`` is the collective fraction (0..1), ``airspeed`` in kn, ``p0`` intake pressure
    in kPa, ``t1`` intake temperature in K, ``rho`` ambient density in kg/m^3, ``nr_ref``
    the rotor-speed set-point in %, ``load_factor`` a multiplicative disturbance of the
    rotor load (turbulence; 1 = none).
    """

    col: np.ndarray
    airspeed: np.ndarray
    p0: np.ndarray
    t1: np.ndarray
    rho: np.ndarray
    nr_ref: np.ndarray
    load_factor: np.ndarray

    def __post_init__(self) -> None:
        shape = np.shape(self.col)
        if len(shape) != 2:
            raise DataError(f"LoopInputs.col must have shape (T, batch), got {shape}")
        for name in ("airspeed", "p0", "t1", "rho", "nr_ref", "load_factor"):
            if np.shape(getattr(self, name)) != shape:
                raise DataError(
                    f"LoopInputs.{name} has shape {np.shape(getattr(self, name))}, expected {shape} like col"
                )


def simulate_closed_loop(
    inputs: LoopInputs,
    eng: EngineParams,
    fadec: FadecParams | None = None,
    rotor: RotorParams | None = None,
    *,
    dt: float = 1.0 / 12.0,
    substeps: int = 2,
    progress: Callable[[float], None] | None = None,
) -> dict[str, np.ndarray]:
    """Simulate the batch; noise-free signals sampled every ``dt``.

    ``eng`` holds one entry per engine sharing each rotor (normally two). Returns NR (%)
    of shape (T, batch) and NG, NP (%), TRQ (% of maximum-continuous torque) and WF
    (kg/h) of shape (T, batch, engines).

    Engine states are flat vectors, engine-major (all trajectories of engine 1, then
    of engine 2, ...), so the sub-steps run on equal-shape arrays without broadcasting.
    """
    fadec = fadec or FadecParams()
    rotor = rotor or RotorParams()
    T, B = inputs.col.shape
    E = eng.n_engines
    h = dt / substeps
    ef = eng.take(np.repeat(np.arange(E), B))  # engine parameters in the flat layout

    def tile(x: np.ndarray) -> np.ndarray:
        return np.concatenate([x] * E)

    delta_all, theta_all, s_all = ambient_ratios(inputs.p0, inputs.t1)
    sigma_all = inputs.rho / RHO_SL
    c_all = inputs.col
    load_a_all, load_b_all = load_terms(c_all, sigma_all, inputs.airspeed, rotor)  # load = n^2 a + b
    load_a_all = load_a_all * inputs.load_factor
    load_b_all = load_b_all * inputs.load_factor

    # -- trim at the first sample: equal torque share at the set-point ---------------
    n = inputs.nr_ref[0] / 100.0
    q_load0 = n * n * load_a_all[0] + load_b_all[0]
    d0, th0, s0 = tile(delta_all[0]), tile(theta_all[0]), tile(s_all[0])
    st, w = trimmed_state(tile(q_load0 / E), tile(n), d0, th0, ef)
    w = np.clip(w, fadec.w_min * s0, fadec.w_max * s0)
    e = tile(inputs.nr_ref[0] - 100.0 * n) - ef.nr_bias
    xd = e.copy()
    xll = tile(c_all[0])
    integ = w / s0 - fadec.kc * xll - fadec.kp * e

    a_d = 1.0 - np.exp(-h / fadec.tau_d)
    a_ll = 1.0 - np.exp(-h / fadec.tau2)
    a_tw = 1.0 - np.exp(-dt / ef.tau_twist)
    lead = fadec.tau1 / fadec.tau2
    h_ki, h_km, inv_tau_d = h * fadec.ki, h * fadec.km, 1.0 / fadec.tau_d
    kd = fadec.kd * inv_tau_d

    def chunk_factors(k0: int, k1: int) -> dict:
        """Per-sample factors of samples k0..k1 in the flat layout, computed in one go."""
        def tl(x: np.ndarray) -> np.ndarray:
            return np.tile(x[k0:k1], (1, E))
        s = tl(s_all)
        return {
            "c": tl(c_all), "s": s, "inv_s": 1.0 / s,
            "ref_e": tl(inputs.nr_ref) - ef.nr_bias,
            "w_lo": fadec.w_min * s, "w_hi": fadec.w_max * s,
            "r_dn": fadec.rate_down * h * s, "r_up": fadec.rate_up * h * s,
            "co": engine_coefficients(tl(delta_all), tl(theta_all), ef, h),
        }

    out_nr = np.empty((T, B))
    out = {k: np.empty((T, E, B)) for k in ("NG", "NP", "TRQ", "WF")}
    report_every = max(1, T // 50)
    chunk = 256
    for k in range(T):
        if k % chunk == 0:
            fac = chunk_factors(k, min(T, k + chunk))
            co_all = fac["co"]
        i = k % chunk
        n_e = tile(n)
        out_nr[k] = n
        out["NG"][k] = st.ng.reshape(E, B)
        out["NP"][k] = power_turbine_speed(st, n_e, ef).reshape(E, B)
        out["TRQ"][k] = st.q.reshape(E, B)
        out["WF"][k] = w.reshape(E, B)
        # per-sample factors (inputs are held over the sub-steps)
        c, s, inv_s, ref_e = fac["c"][i], fac["s"][i], fac["inv_s"][i], fac["ref_e"][i]
        w_lo, w_hi, r_dn, r_up = fac["w_lo"][i], fac["w_hi"][i], fac["r_dn"][i], fac["r_up"][i]
        co = EngineCoefficients(**{f: getattr(co_all, f)[i] for f in _COEFFICIENT_FIELDS})
        load_a, load_b = load_a_all[k], load_b_all[k]
        for _ in range(substeps):
            e = ref_e - 100.0 * n_e
            diff = e - xd
            xd += a_d * diff
            ll = lead * c + (fadec.kc - lead) * xll
            xll += a_ll * (c - xll)
            cmd = s * (ll + fadec.kp * e + integ + kd * diff)
            w_new = np.minimum(np.maximum(cmd, np.maximum(w_lo, w - r_dn)), np.minimum(w_hi, w + r_up))
            q_sum = st.q.reshape(E, B).sum(axis=0)
            integ += h_ki * e + h_km * (tile(q_sum / E) - st.q) + (w_new - cmd) * inv_s
            w = w_new
            engine_step(st, w, n_e, co, ef)
            n = n + h * (st.q.reshape(E, B).sum(axis=0) - n * n * load_a - load_b) / rotor.t_m
            n_e = tile(n)
        shaft_step(st, a_tw)
        if progress is not None and (k % report_every == 0):
            progress(k / T)
    if progress is not None:
        progress(1.0)
    result = {"NR": 100.0 * out_nr}
    for key, scale in (("NG", 1.0), ("NP", 1.0), ("TRQ", 100.0), ("WF", WF_REF)):
        result[key] = scale * out[key].transpose(0, 2, 1)
    return result
