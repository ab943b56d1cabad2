"""The physical model (PM) of egt-hybrid sec. 4.2: a mean-value engine model, modules A-F.

Inputs: engine speed N and fuel-rack set-point X (dataset columns ``engine_speed`` and
``fuel_rack``). Outputs: bank-averaged exhaust temperature at turbine inlet and outlet
(egt-hybrid eq. 6). The modules, as the paper lists them (our own equations):

A. fuel pump: m_f = m_f,nom (X - X_0) / 100 per cylinder and cycle, through a first-order
   lag (pump inertia and ignition delay).
B. air swallow: trapped mass m_1 = p_1 V_1 / (R T_1) at the charge pressure p_1 and a
   constant temperature at the start of compression T_1 (unit scavenge efficiency, no
   inlet or cooler pressure losses); air excess lambda = m_1 / (sigma m_f); slip
   (scavenge) air s m_1 passes to the exhaust, with a slip ratio s linear in speed.
C. heat release: Q = eta_hr m_f LHV with a heat-release efficiency inversely related
   to speed, eta_hr = eta_hr,MCR (N_MCR / N)^k_hr; shares: isochoric
   x_cv = x_cv0 + x_cv1 N/N_MCR (linear in speed), isobaric x_cp of the rest,
   isothermal the remainder.
D. six-stage Seiliger cycle with constant gas properties: polytropic compression 1-2,
   isochoric 2-3, isobaric 3-4 and isothermal 4-5 heat addition, polytropic expansion
   5-6 to the bottom dead centre, isochoric blow-down 6-1. It gives the closed-cycle work
   w_i, the peak pressure p_max = p_3 and the state (p_6, T_6) when the exhaust valve opens.
E. exhaust receiver and turbocharger: Zinner blow-down to the receiver pressure p_d,
   T_d = T_6 / kappa (1 + (kappa - 1) p_d / p_6), mixed with the slip air; turbine flow
   balance (an equivalent nozzle whose flow function is the ellipse law, so the balance
   has a closed-form root because T_d is linear in p_d); Buechi power balance between
   compressor and turbine, (pi_c^((k_a-1)/k_a) - 1) = eta_TC (m_t c_pg T_d)/(m_a c_pa T_a)
   (1 - (p_o/p_d)^((k_g-1)/k_g)), with a turbocharger efficiency quadratic in charge
   pressure -- no compressor or turbine maps. Turbine outlet temperature by polytropic
   expansion, T_a = T_d (p_o / p_d)^(eta_p (k_g - 1) / k_g), with a polytropic
   efficiency eta_p linear in charge pressure; eta_p above 1 stands for heat lost along
   the expansion (the PM has no other heat loss on the exhaust path). The charge
   pressure that solves the balance is found for every sample at once (bracketed
   secant, Illinois variant); the turbocharger inertia is a first-order lag of the
   charge pressure; the receiver state then follows algebraically.
F. mechanical losses: friction mean effective pressure f_0 + f_2 (N/N_MCR)^2 (including
   attached auxiliaries) and the gas-exchange work (p_1 - p_d) V_d.

Thermocouples (eqs. 4-5): each measured temperature is a first-order lag (time constant
tau) of the model temperature minus a constant bias b.

Everything is vectorised over time: one pass of the quasi-steady cycle over all samples,
then the lags with ``scipy.signal.lfilter``.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.sensors import first_order_lag, run_starts
from enginebench.errors import DataError

PM_NAME = "marine-diesel-pm"
SPEED = "engine_speed"
RACK = "fuel_rack"
T_INLET = "t_exhaust_turbine_inlet"
T_OUTLET = "t_exhaust_turbine_outlet"

DEFAULT_PARAMS: dict[str, float] = {
    # engine data (fixed)
    "n_cyl": float(C.N_CYL),
    "v_d_m3": C.V_D_CYL_M3,
    "compression_ratio": C.COMPRESSION_RATIO,
    "lhv_j_per_kg": C.LHV_J_PER_KG,
    "afr_stoich": C.AFR_STOICH,
    "n_mcr_rpm": C.N_MCR_RPM,
    "p_amb_pa": 1.0e5,
    "t_amb_k": 298.15,
    "p_turbine_out_pa": 1.0e5,
    "t_charge_air_k": 318.15,
    "r_gas": 287.0,
    "kappa_cyl": 1.36,
    "cp_air": C.CP_AIR,
    "kappa_air": C.KAPPA_AIR,
    "cp_gas": C.CP_GAS,
    "kappa_gas": C.KAPPA_GAS,
    # A: fuel pump
    "fuel_nom_kg": 3.3e-3,
    "rack_zero_pct": 0.0,
    "tau_fuel_s": 0.3,
    # B: air swallow
    "t1_k": 350.0,
    "scavenge_ratio": 0.08,
    "scavenge_ratio_speed": 0.0,
    # C: heat release
    "x_cv0": 0.05,
    "x_cv1": 0.20,
    "x_cp": 0.6,
    "eta_hr_mcr": 0.85,
    "k_hr": 0.2,
    # D: Seiliger
    "n_comp": 1.36,
    "n_exp": 1.30,
    # E: exhaust receiver and turbocharger
    "turbine_area_m2": 0.015,
    "eta_tc0": 0.45,
    "eta_tc1": 0.06,
    "eta_tc2": -0.005,
    "eta_tp0": 0.85,
    "eta_tp1": 0.0,
    "tau_tc_s": 5.0,
    "tau_thermo_inlet_s": 30.0,
    "tau_thermo_outlet_s": 30.0,
    "bias_inlet_k": 0.0,
    "bias_outlet_k": 0.0,
    # F: mechanical losses
    "fmep0_bar": 1.2,
    "fmep2_bar": 0.8,
}
"""Every parameter of the PM, SI units unless the name says otherwise."""

BOUNDS: dict[str, tuple[float, float]] = {
    "t1_k": (300.0, 450.0),
    "scavenge_ratio": (0.0, 0.4),
    "scavenge_ratio_speed": (-1.0, 1.0),
    "x_cv0": (0.0, 1.0),
    "x_cv1": (-1.0, 1.0),
    "x_cp": (0.0, 1.0),
    "eta_hr_mcr": (0.6, 1.0),
    "k_hr": (0.0, 1.5),
    "n_comp": (1.25, 1.40),
    "n_exp": (1.20, 1.40),
    "turbine_area_m2": (0.003, 0.05),
    "eta_tc0": (0.0, 0.9),
    "eta_tc1": (-0.3, 0.5),
    "eta_tc2": (-0.1, 0.1),
    "eta_tp0": (0.2, 2.5),
    "eta_tp1": (-0.5, 0.5),
    "compression_ratio": (11.0, 17.0),
    "fmep0_bar": (0.0, 4.0),
    "fmep2_bar": (0.0, 4.0),
    "fuel_nom_kg": (1.0e-3, 6.0e-3),
    "rack_zero_pct": (-20.0, 30.0),
}
"""Physical bounds of the free parameters for calibration."""

FAT_FREE = ("t1_k", "scavenge_ratio", "scavenge_ratio_speed", "x_cv0", "x_cv1", "x_cp", "eta_hr_mcr", "k_hr", "n_comp",
            "n_exp", "turbine_area_m2", "eta_tc0", "eta_tc1", "eta_tc2", "eta_tp0", "eta_tp1", "compression_ratio",
            "fmep0_bar", "fmep2_bar")
"""Parameters fitted to FAT points (plus the pump law when the FAT lists rack positions)."""

P_CHARGE_MAX_PA = 8.0e5
"""Upper bracket of the charge-pressure solve, Pa."""
BLOCK = 65536
"""Samples per block of the vectorised charge-pressure solve."""


def _p(params: Mapping[str, Any], name: str) -> float:
    return float(params[name])


def fuel_per_cycle(params: Mapping[str, Any], rack_pct: np.ndarray) -> np.ndarray:
    """Module A (static part): fuel per cylinder per cycle, kg, from the rack position."""
    stroke = np.maximum(np.asarray(rack_pct, dtype=float) - _p(params, "rack_zero_pct"), 0.0)
    return _p(params, "fuel_nom_kg") * stroke / 100.0


def _cycle(params: Mapping[str, Any], speed: np.ndarray, fuel: np.ndarray, p1: np.ndarray) -> dict[str, np.ndarray]:
    """Modules B-D and the pressure-independent part of E at charge pressure ``p1`` (Pa)."""
    r = _p(params, "compression_ratio")
    R = _p(params, "r_gas")
    kap = _p(params, "kappa_cyl")
    cv = R / (kap - 1.0)
    cp = kap * cv
    v_d = _p(params, "v_d_m3")
    v1 = v_d * r / (r - 1.0)
    t1 = _p(params, "t1_k")
    n_rel = speed / _p(params, "n_mcr_rpm")
    # B: air swallow
    m1 = p1 * v1 / (R * t1)
    mc = m1 + fuel
    # C: heat release
    eta_hr = np.minimum(_p(params, "eta_hr_mcr") * np.maximum(n_rel, 0.2) ** (-_p(params, "k_hr")), 1.0)
    q = eta_hr * fuel * _p(params, "lhv_j_per_kg")
    x_cv = np.clip(_p(params, "x_cv0") + _p(params, "x_cv1") * n_rel, 0.0, 1.0)
    q23 = x_cv * q
    q34 = _p(params, "x_cp") * (q - q23)
    q45 = q - q23 - q34
    # D: six-stage Seiliger cycle
    nc, ne = _p(params, "n_comp"), _p(params, "n_exp")
    t2 = t1 * r ** (nc - 1.0)
    p2 = p1 * r**nc
    t3 = t2 + q23 / (mc * cv)
    p3 = p2 * t3 / t2
    t4 = t3 + q34 / (mc * cp)
    ln54 = np.minimum(q45 / (mc * R * t4), np.log(r * t3 / t4))     # V5 <= V1
    exp_ratio = np.exp(ln54) * t4 / t3 / r                          # V5 / V1
    p5 = p3 * np.exp(-ln54)
    t6 = t4 * exp_ratio ** (ne - 1.0)
    p6 = p5 * exp_ratio**ne
    w = (m1 * R * (t1 - t2) / (nc - 1.0) + mc * R * (t4 - t3) + mc * R * t4 * ln54
         + mc * R * (t4 - t6) / (ne - 1.0))
    # E (first part): Zinner blow-down T_d = a_z + b_z p_d, mixed with slip air
    s = np.clip(_p(params, "scavenge_ratio") + _p(params, "scavenge_ratio_speed") * (n_rel - 1.0), 0.0, 0.6)
    a_z = t6 / kap
    b_z = t6 * (kap - 1.0) / (kap * p6)
    m_t = mc + s * m1
    alpha = (mc * a_z + s * m1 * _p(params, "t_charge_air_k")) / m_t
    beta = mc * b_z / m_t
    cps = _p(params, "n_cyl") * speed / 120.0                        # cycles per second, all cylinders
    return dict(m1=m1, mc=mc, p3=p3, p6=p6, t6=t6, w=w, alpha=alpha, beta=beta,
                m_air=m1 * (1.0 + s) * cps, m_turb=m_t * cps,
                lam=m1 / (_p(params, "afr_stoich") * np.maximum(fuel, 1e-9)))


def _receiver(params: Mapping[str, Any], cyc: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Turbine flow balance: receiver pressure p_d (Pa) and temperature T_d (K), closed form.

    Ellipse law m^2 R T_d = A^2 (p_d^2 - p_o^2) with T_d = alpha + beta p_d.
    """
    R = _p(params, "r_gas")
    A2 = _p(params, "turbine_area_m2") ** 2
    po = _p(params, "p_turbine_out_pa")
    m2R = cyc["m_turb"] ** 2 * R
    b = m2R * cyc["beta"]
    pd = (b + np.sqrt(b * b + 4.0 * A2 * (A2 * po * po + m2R * cyc["alpha"]))) / (2.0 * A2)
    return pd, cyc["alpha"] + cyc["beta"] * pd


def _tc_efficiency(params: Mapping[str, Any], p1: np.ndarray) -> np.ndarray:
    pb = p1 / C.BAR
    eta = _p(params, "eta_tc0") + _p(params, "eta_tc1") * pb + _p(params, "eta_tc2") * pb * pb
    return np.clip(eta, 0.05, 0.95)


def _balance(params: Mapping[str, Any], speed: np.ndarray, fuel: np.ndarray, p1: np.ndarray):
    """Residual of the Buechi power balance: charge pressure it yields minus the one assumed."""
    cyc = _cycle(params, speed, fuel, p1)
    pd, td = _receiver(params, cyc)
    xa = (_p(params, "kappa_air") - 1.0) / _p(params, "kappa_air")
    xg = (_p(params, "kappa_gas") - 1.0) / _p(params, "kappa_gas")
    ratio = (cyc["m_turb"] * _p(params, "cp_gas") * td) / (cyc["m_air"] * _p(params, "cp_air") * _p(params, "t_amb_k"))
    rhs = _tc_efficiency(params, p1) * ratio * (1.0 - (_p(params, "p_turbine_out_pa") / pd) ** xg)
    p_new = _p(params, "p_amb_pa") * (1.0 + np.maximum(rhs, 0.0)) ** (1.0 / xa)
    return p_new - p1, cyc, pd, td


def solve_charge_pressure(params: Mapping[str, Any], speed: np.ndarray, fuel: np.ndarray,
                          iters: int = 40, tol_pa: float = 1e-3) -> np.ndarray:
    """Steady charge pressure (Pa) for every sample at once: bracketed secant (Illinois).

    The bracket is [p_amb, P_CHARGE_MAX_PA]; the residual is positive at p_amb (the
    turbine always delivers some work) and the solution saturates at the upper end if
    the balance asks for more.
    """
    speed = np.maximum(np.asarray(speed, dtype=float), 1.0)
    fuel = np.maximum(np.asarray(fuel, dtype=float), 0.0)
    a = np.full(speed.shape, _p(params, "p_amb_pa"))
    b = np.full(speed.shape, P_CHARGE_MAX_PA)
    fa = _balance(params, speed, fuel, a)[0]
    fb = _balance(params, speed, fuel, b)[0]
    saturated = fb >= 0.0
    fa = np.where(fa > 0.0, fa, 1e-9)
    fb = np.where(saturated, -1e-9, fb)
    x = b
    for _ in range(iters):
        x = b - fb * (b - a) / (fb - fa)
        fx = _balance(params, speed, fuel, x)[0]
        flip = fx * fb < 0.0                      # root between b and x: b moves to a
        a = np.where(flip, b, a)
        fa = np.where(flip, fb, fa * 0.5)         # Illinois: halve the stale end
        b, fb = x, fx
        if np.max(np.abs(fx)) < tol_pa:
            break
    return np.where(saturated, P_CHARGE_MAX_PA, x)


def steady_outputs(params: Mapping[str, Any], speed: np.ndarray, fuel: np.ndarray,
                   p1: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Quasi-steady engine state at given speed (rpm) and fuel (kg/cyl/cycle).

    With ``p1`` given, the charge pressure is taken as is (the dynamic path); otherwise
    it is solved from the turbocharger balance. Returns pressures in Pa, temperatures
    in K, powers in W, sfc in g/kWh and the air excess ratio.
    """
    speed = np.maximum(np.asarray(speed, dtype=float), 1.0)
    fuel = np.maximum(np.asarray(fuel, dtype=float), 0.0)
    if p1 is None:
        p1 = solve_charge_pressure(params, speed, fuel)
    cyc = _cycle(params, speed, fuel, p1)
    pd, td = _receiver(params, cyc)
    xg = (_p(params, "kappa_gas") - 1.0) / _p(params, "kappa_gas")
    eta_tp = np.maximum(_p(params, "eta_tp0") + _p(params, "eta_tp1") * p1 / C.BAR, 0.05)
    ta = td * (_p(params, "p_turbine_out_pa") / pd) ** (eta_tp * xg)
    cps = _p(params, "n_cyl") * speed / 120.0
    v_d = _p(params, "v_d_m3")
    fmep = (_p(params, "fmep0_bar") + _p(params, "fmep2_bar") * (speed / _p(params, "n_mcr_rpm")) ** 2) * C.BAR
    brake = (cyc["w"] + (p1 - pd) * v_d - fmep * v_d) * cps
    fuel_flow = fuel * cps
    with np.errstate(divide="ignore", invalid="ignore"):
        sfc = np.where(brake > 0.0, fuel_flow / brake * 3.6e9, np.nan)
    return dict(p_charge_pa=p1, p_receiver_pa=pd, p_max_pa=cyc["p3"], t_inlet_k=td, t_outlet_k=ta,
                brake_power_w=brake, fuel_flow_kg_s=fuel_flow, sfc_g_per_kwh=sfc, air_excess=cyc["lam"])


def simulate_runs(params: Mapping[str, Any], speed_rpm: np.ndarray, rack_pct: np.ndarray, dt: float,
                  starts: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The PM over many samples at once; ``starts`` marks where independent segments begin.

    Returns the two outputs in degC (keys ``T_INLET`` and ``T_OUTLET``).
    """
    if not dt > 0:
        raise DataError(f"{PM_NAME}: sample period must be positive, got {dt}")
    speed = np.asarray(speed_rpm, dtype=float)
    rack = np.asarray(rack_pct, dtype=float)
    if speed.shape != rack.shape or speed.ndim != 1:
        raise DataError(f"{PM_NAME}: {SPEED} and {RACK} must be 1-D arrays of equal length, "
                        f"got shapes {speed.shape} and {rack.shape}")
    if not (np.all(np.isfinite(speed)) and np.all(np.isfinite(rack))):
        raise DataError(f"{PM_NAME}: {SPEED} or {RACK} holds NaN or inf; clean the segment first")
    if speed.size == 0:
        return {T_INLET: np.zeros(0), T_OUTLET: np.zeros(0)}
    starts = np.array([0]) if starts is None else np.asarray(starts, dtype=np.int64)
    fuel = first_order_lag(fuel_per_cycle(params, rack), _p(params, "tau_fuel_s"), dt, starts)   # module A
    p1_steady = np.empty_like(speed)
    for a in range(0, speed.size, BLOCK):                  # blocks keep the temporaries in cache
        p1_steady[a:a + BLOCK] = solve_charge_pressure(params, speed[a:a + BLOCK], fuel[a:a + BLOCK])
    p1 = first_order_lag(p1_steady, _p(params, "tau_tc_s"), dt, starts)                       # TC inertia
    out = steady_outputs(params, speed, fuel, p1)
    t_in = first_order_lag(out["t_inlet_k"] - _p(params, "bias_inlet_k"), _p(params, "tau_thermo_inlet_s"), dt, starts)
    t_out = first_order_lag(out["t_outlet_k"] - _p(params, "bias_outlet_k"), _p(params, "tau_thermo_outlet_s"),
                            dt, starts)
    return {T_INLET: t_in - C.KELVIN, T_OUTLET: t_out - C.KELVIN}


def simulate_frame(params: Mapping[str, Any], frame, dt: float,
                   segment_column: str = "segment") -> dict[str, np.ndarray]:
    """The PM over a whole dataset frame (rows grouped by segment), one vectorised pass."""
    starts = run_starts(frame[segment_column].to_numpy())
    return simulate_runs(params, frame[SPEED].to_numpy(dtype=float), frame[RACK].to_numpy(dtype=float), dt, starts)


__all__ = ["DEFAULT_PARAMS", "BOUNDS", "FAT_FREE", "PM_NAME", "steady_outputs",
           "solve_charge_pressure", "simulate_runs", "simulate_frame", "fuel_per_cycle"]
