"""The gas generator and power turbine: fuel flow WF -> NG -> torque TRQ, with heat soak.

Per engine (the turboshaft-moe paper's eq. 1 with scheduled time constants, plus what it leaves out):

    m'   = (wfc - m) / tau_th(delta)                 slow thermal (heat-soak) state
    wfe  = wfc - kappa (wfc - m)                      fuel that heats the gas
    NG'  = (NG_ss(wfe, theta) - NG) / tau_g(NGc, delta)
    TRQ' = (TRQ_ss(NG, NP, delta, theta) - TRQ) / tau_t

with wfc = w / (fuel_scale delta sqrt(theta)) the corrected fuel flow,
tau_g(NGc, delta) = tau_g (100 / NGc)^2.5 / sqrt(delta) (slower at low power and at
altitude) and tau_th(delta) = tau_th / sqrt(delta). A first-order
model (1 + tau s) TRQ = mu WF captures the fast part; the heat soak adds a tail of about
kappa of each step with a time constant of tens of seconds. First-order lags are
advanced with their exact exponential update, which is stable for any step size.
Engine parameters broadcast over the last axis (one entry per engine).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from enginebench.datasets.turboshaft.atmosphere import P_SL, T_SL
from enginebench.datasets.turboshaft.params import WF_REF, EngineParams, FadecParams

NG_KNEE = 60.0
"""% corrected NG below which the power turbine delivers no power."""
POWER_EXPONENT = 2.2


def ambient_ratios(p0_kpa: np.ndarray, t1_k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """delta = P0/P_SL, theta = T1/T_SL and the fuel schedule s = delta sqrt(theta)."""
    delta = np.asarray(p0_kpa, dtype=np.float64) / P_SL
    theta = np.asarray(t1_k, dtype=np.float64) / T_SL
    return delta, theta, delta * np.sqrt(theta)


def fuel_limits(p0_kpa: np.ndarray, t1_k: np.ndarray, fadec: FadecParams | None = None) -> dict[str, np.ndarray]:
    """The FADEC's fuel-flow limits at the given intake conditions.

    Returns ``wf_min``, ``wf_max`` (kg/h) and ``rate_up``, ``rate_down`` (kg/h per s):
    minimum (flame-out) and maximum fuel flow and the acceleration/deceleration limits,
    all scheduled with delta sqrt(theta) like the control gains.
    """
    fadec = fadec or FadecParams()
    _, _, s = ambient_ratios(p0_kpa, t1_k)
    return {
        "wf_min": fadec.w_min * s * WF_REF,
        "wf_max": fadec.w_max * s * WF_REF,
        "rate_up": fadec.rate_up * s * WF_REF,
        "rate_down": fadec.rate_down * s * WF_REF,
    }


def ng_steady(wfe: np.ndarray, theta: np.ndarray, eng: EngineParams) -> np.ndarray:
    """Steady NG (%) for an effective corrected fuel flow ``wfe``."""
    ngc = 100.0 * (eng.g0 + eng.g1 * np.maximum(wfe, 0.0) ** eng.gamma)
    return ngc * np.sqrt(theta)


def torque_steady(ng: np.ndarray, n: np.ndarray, delta: np.ndarray, theta: np.ndarray,
                  eng: EngineParams) -> np.ndarray:
    """Steady per-unit torque delivered at gas-generator speed ``ng`` (%) and NP = ``n``."""
    sq = np.sqrt(theta)
    x = np.maximum(ng / sq - NG_KNEE, 0.0) / (100.0 - NG_KNEE)
    return delta * sq * eng.gain * x**POWER_EXPONENT / n


def trim_from_torque(q: np.ndarray, n: np.ndarray, delta: np.ndarray, theta: np.ndarray,
                     eng: EngineParams) -> tuple[np.ndarray, np.ndarray]:
    """Steady NG (%) and fuel flow w (per unit) delivering torque ``q`` (inverse maps)."""
    sq = np.sqrt(theta)
    x = (np.maximum(q, 1e-6) * n / (delta * sq * eng.gain)) ** (1.0 / POWER_EXPONENT)
    ngc = NG_KNEE + (100.0 - NG_KNEE) * x
    wfc = (np.maximum(ngc / 100.0 - eng.g0, 1e-9) / eng.g1) ** (1.0 / eng.gamma)
    return ngc * sq, wfc * eng.fuel_scale * delta * sq


@dataclass
class EngineState:
    """Mutable engine states, arrays of one shape (any batch layout)."""

    ng: np.ndarray   # %
    q: np.ndarray    # per-unit torque
    m: np.ndarray    # metal (heat-soak) state, corrected fuel units
    qf: np.ndarray   # lagged torque for the shaft wind-up of NP


@dataclass(frozen=True)
class EngineCoefficients:
    """Per-sample factors of ``engine_step`` at given intake conditions and step ``h``.

    Computed once per sample so that the sub-steps only do element-wise arithmetic on
    arrays of the state's shape (broadcasting in a hot loop is several times slower).
    """

    inv_fuel: np.ndarray   # 1 / (fuel_scale delta sqrt(theta)): w -> corrected fuel
    inv_sq: np.ndarray     # 1 / sqrt(theta)
    ng_scale: np.ndarray   # 100 sqrt(theta)
    trq_scale: np.ndarray  # delta sqrt(theta) gain / 40^2.2
    a_th: np.ndarray       # 1 - exp(-h sqrt(delta) / tau_th)
    g_rate: np.ndarray     # h sqrt(delta) / tau_g, times (NGc/100)^2.5 gives h / tau_g(NGc)
    a_t: np.ndarray        # 1 - exp(-h / tau_t)


def engine_coefficients(delta: np.ndarray, theta: np.ndarray, eng: EngineParams, h: float) -> EngineCoefficients:
    """The factors of ``engine_step`` (arrays broadcast to the common shape)."""
    sq = np.sqrt(theta)
    sd = np.sqrt(delta)
    shape = np.broadcast_shapes(np.shape(delta), np.shape(eng.tau_g))
    return EngineCoefficients(
        inv_fuel=np.broadcast_to(1.0 / (eng.fuel_scale * delta * sq), shape),
        inv_sq=np.broadcast_to(1.0 / sq, shape),
        ng_scale=np.broadcast_to(100.0 * sq, shape),
        trq_scale=np.broadcast_to(delta * sq * eng.gain / (100.0 - NG_KNEE) ** POWER_EXPONENT, shape),
        a_th=np.broadcast_to(1.0 - np.exp(-h * sd / eng.tau_th), shape),
        g_rate=np.broadcast_to(h * sd / eng.tau_g, shape),
        a_t=np.broadcast_to(1.0 - np.exp(-h / eng.tau_t), shape),
    )


def trimmed_state(q: np.ndarray, n: np.ndarray, delta: np.ndarray, theta: np.ndarray,
                  eng: EngineParams) -> tuple[EngineState, np.ndarray]:
    """The steady engine state delivering torque ``q`` and its fuel flow w (per unit)."""
    ng, w = trim_from_torque(q, n, delta, theta, eng)
    wfc = w / (eng.fuel_scale * delta * np.sqrt(theta))
    q = torque_steady(ng, n, delta, theta, eng)
    return EngineState(ng=ng, q=q, m=wfc.copy(), qf=q.copy()), w


def engine_step(st: EngineState, w: np.ndarray, n: np.ndarray, co: EngineCoefficients, eng: EngineParams) -> None:
    """Advance the engine states by one step at fuel flow ``w`` (per unit) and NP = ``n``, in place.

    Same dynamics as the module docstring; ``co`` from ``engine_coefficients``.
    """
    wfc = w * co.inv_fuel
    st.m += co.a_th * (wfc - st.m)
    wfe = wfc - eng.kappa * (wfc - st.m)
    ngc = st.ng * co.inv_sq
    a_g = 1.0 - np.exp(-co.g_rate * (np.maximum(ngc, 40.0) * 0.01) ** 2.5)
    ng_ss = co.ng_scale * (eng.g0 + eng.g1 * np.maximum(wfe, 0.0) ** eng.gamma)
    st.ng += a_g * (ng_ss - st.ng)
    x = np.maximum(st.ng * co.inv_sq - NG_KNEE, 0.0)
    st.q += co.a_t * (co.trq_scale * x**POWER_EXPONENT / n - st.q)


def shaft_step(st: EngineState, a_twist: np.ndarray) -> None:
    """Advance the lagged torque of the shaft wind-up by one step (``a_twist`` = 1 - exp(-h / tau_twist))."""
    st.qf += a_twist * (st.q - st.qf)


def power_turbine_speed(st: EngineState, n: np.ndarray, eng: EngineParams) -> np.ndarray:
    """NP (%): the rotor speed through the gearbox plus the drive shaft's wind-up transient."""
    return 100.0 * n + eng.twist * (st.q - st.qf)


def simulate_engine(wf_kgh: np.ndarray, p0_kpa: np.ndarray, t1_k: np.ndarray, eng: EngineParams,
                    dt: float, np_pct: np.ndarray | float = 100.0, substeps: int = 2
                    ) -> dict[str, np.ndarray]:
    """Open-loop engine response to a given fuel-flow history (no FADEC, no rotor).

    ``wf_kgh`` has shape (T, ...batch, engines); the other signals broadcast against
    it. Starts trimmed at the first sample. Returns NG (%) and TRQ (%) of the same
    shape. Used to study the engine alone, e.g. its step response.
    """
    wf = np.asarray(wf_kgh, dtype=np.float64) / WF_REF
    shape = wf.shape
    p0 = np.broadcast_to(p0_kpa, shape)
    t1 = np.broadcast_to(t1_k, shape)
    n = np.broadcast_to(np.asarray(np_pct, dtype=np.float64) / 100.0, shape)
    delta, theta, s = ambient_ratios(p0, t1)
    wfc0 = wf[0] / (eng.fuel_scale * s[0])
    ng0 = ng_steady(wfc0, theta[0], eng)
    q0 = torque_steady(ng0, n[0], delta[0], theta[0], eng)
    st = EngineState(ng=ng0, q=q0, m=wfc0.copy(), qf=q0.copy())
    ng_out = np.empty(shape)
    q_out = np.empty(shape)
    h = dt / substeps
    for k in range(shape[0]):
        ng_out[k] = st.ng
        q_out[k] = st.q
        co = engine_coefficients(delta[k], theta[k], eng, h)
        for _ in range(substeps):
            engine_step(st, wf[k], n[k], co, eng)
    return {"NG": ng_out, "TRQ": 100.0 * q_out}
