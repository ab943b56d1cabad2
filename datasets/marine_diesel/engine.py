"""The "true engine" of the marine-diesel generator: a mean-value model with maps.

It is deliberately richer than the physical model of seed 000 (sec. 4.2, our ``pm``),
in the pattern of the hardware-in-the-loop model of seed 001 (sec. 2.1-2.3):

* compressor (after seed 001 eqs. 3-7, our own parameterisation): speed lines
  m = m_max(U) (1 - (H / H_max(U))^2) in corrected flow, H = pi^((k-1)/k) - 1 the
  isentropic head, H_max proportional to the tip speed squared, m_max growing with it;
  efficiency a quadratic hill in (flow fraction, tip speed); fouling lowers it;
* air filter and intercooler pressure losses; intercooler effectiveness
  1 - exp(-NTU), NTU falling with air flow and with fouling (seed 001 eq. 11);
* intake and exhaust receivers with filling dynamics dp/dt = R T / V (m_in - m_out)
  (seed 001 eq. 12);
* volumetric efficiency depending on speed and on the scavenge pressure difference,
  plus valve-overlap scavenge air blown through to the exhaust (seed 001 eq. 13-14);
* combustion efficiency falling at low load and at low air excess; gross indicated
  efficiency depending on air excess, speed and load; pumping work; friction mean
  effective pressure quadratic in speed (seed 001 eqs. 17-21); attached pumps;
* heat to the cylinder walls; cylinder-outlet temperature from the cylinder energy
  balance; mixing with scavenge air; heat exchange with the exhaust-manifold wall, a
  thermal mass with its own state (minutes), insulated towards the engine room;
* turbine: flow law m = A p / sqrt(R T) sqrt(1 - pi^-k_t) with a mild speed effect,
  efficiency a parabola in the blade-speed ratio (a turbine map, unlike the PM); an
  exhaust waste gate opening with charge pressure bypasses gas around the turbine
  (more boost at part load, limited boost at full load);
* turbocharger rotor inertia, J w dw/dt = P_turbine - P_friction - P_compressor
  (seed 001 eq. 10);
* a governor that meters fuel to deliver the demanded brake power, with rack and
  boost (smoke) limits, and a fast fuel actuator;
* first-order thermocouples on the exhaust temperatures (seed 000 eqs. 4-5 pattern).

Each bank (A, B) has its own turbocharger, receivers and thermocouples, with slightly
different constants. The integration uses a 1.5 s step (two steps per logged sample):
the receivers (time constants ~0.05 s, implicit Euler solved exactly) then act as
quasi-steady balances; the rotor (~2-5 s, linearly implicit), the manifold wall
(~100 s) and the thermocouples (~25-40 s) are true dynamics. The loop runs over time with numpy vectors over many
independent *lanes* (pieces of voyages, see ``simulate_rows``), so the cost is set by
the lane length, not by the size of the data set.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from enginebench.datasets.marine_diesel import constants as C

BANKS = ("a", "b")

INPUT_NAMES = (
    "speed_rpm",        # engine speed, rpm
    "power_demand_w",   # brake power demanded by propeller and shaft, W
    "t_amb_k",          # compressor inlet (engine-room air) temperature, K
    "p_amb_pa",         # ambient pressure, Pa
    "t_coolant_k",      # LT water temperature at the intercooler inlet, K
    "foul_comp",        # compressor efficiency loss, fraction
    "foul_turb",        # turbine flow-area loss, fraction
    "foul_ic",          # intercooler NTU loss, fraction
)
"""Per-sample inputs of the engine loop."""

BANK_OUTPUTS = (
    "tc_speed_rpm", "p_im_pa", "t_im_k", "t_comp_out_k", "p_em_pa", "t_cyl_out_k",
    "t_turb_in_k", "t_turb_out_k", "tc_meas_in_k", "tc_meas_out_k", "tc_meas_cyl_k",
    "p_max_pa", "q_intercooler_w", "m_air_kg_s",
)
"""Per-bank outputs recorded at every logged sample (arrays of shape (2, n))."""

ENGINE_OUTPUTS = (
    "fuel_kg_cyc", "fuel_flow_kg_s", "brake_power_w", "friction_power_w", "aux_power_w",
    "wall_heat_w", "tc_friction_w", "manifold_loss_w", "unburnt_w", "lambda_trapped",
)
"""Engine-level outputs recorded at every logged sample (arrays of shape (n,))."""


@dataclass(frozen=True)
class EngineConfig:
    """Constants of the true engine. Tuples are per bank (A, B).

    Units are SI and in the names (``_m``, ``_m2``, ``_kg_s``, ``_pa``, ``_w_k``, ``_s``...);
    names without a unit are dimensionless (efficiencies, exponents, fractions, and
    ``*_scale`` loads as fractions of the MCR fuel per cycle). Values were chosen so
    that the shop test (``fat.simulator_fat``) resembles seed 000's Table 4 with
    realistic air excess, and the energy balance closes.
    """

    # compressor map (per bank)
    comp_radius_m: float = 0.165
    comp_tip_speed_ref_m_s: float = 520.0
    comp_psi_max: tuple[float, float] = (0.70, 0.70)
    comp_flow_max_kg_s: tuple[float, float] = (7.6, 7.6)
    comp_flow_speed_exp: float = 0.9
    comp_eta_max: tuple[float, float] = (0.818, 0.82)
    comp_eta_flow_q: float = 0.9
    comp_eta_flow_opt: float = 0.55
    comp_eta_speed_q: float = 0.25
    comp_eta_speed_opt: float = 0.95
    comp_eta_min: float = 0.45
    filter_dp_ref_pa: float = 1500.0
    flow_ref_kg_s: float = 4.0
    # intercooler and receivers
    ic_ntu_ref: tuple[float, float] = (2.55, 2.5)
    ic_ntu_flow_exp: float = -0.25
    ic_dp_ref_pa: float = 4000.0
    v_im_m3: float = 0.6
    v_em_m3: float = 0.35
    # gas exchange
    eta_vol_0: float = 0.85
    eta_vol_speed_q: float = 0.15
    eta_vol_speed_opt: float = 0.75
    eta_vol_dp: float = 0.06
    scavenge_area_m2: tuple[float, float] = (2.55e-4, 2.5e-4)
    scavenge_dp_smooth_pa: float = 5000.0
    # combustion and work
    fuel_mcr_kg_cyc: float = 2.75e-3
    eta_ig_base: float = 0.50
    eta_ig_lambda: float = 0.16
    eta_ig_speed_q: float = 0.35
    eta_ig_speed_opt: float = 0.85
    eta_ig_low_load: float = 0.08
    eta_ig_low_load_scale: float = 0.3
    eta_comb_max: float = 0.995
    eta_comb_low_load: float = 0.05
    eta_comb_low_load_scale: float = 0.12
    eta_comb_smoke: float = 0.10
    lambda_smoke: float = 1.6
    fmep_0_pa: float = 0.9e5
    fmep_2_pa: float = 0.8e5
    fmep_imep: float = 0.03
    aux_power_mcr_w: float = 40e3
    wall_heat_frac: float = 0.075
    wall_heat_speed_exp: float = 1.0
    wall_heat_low_load: float = 0.6
    wall_heat_low_load_scale: float = 0.25
    p_max_poly: float = 1.37
    p_max_heat_k: float = 25.0
    p_max_rise: float = 0.145
    p_max_speed_exp: float = 0.3
    cv_cyl: float = 800.0
    # exhaust manifold wall (per bank)
    em_wall_capacity_j_k: float = 150e3
    em_wall_ha_ref_w_k: float = 1500.0
    em_wall_ua_ins_w_k: float = 50.0
    # turbine map (per bank)
    turb_radius_m: float = 0.14
    turb_area_m2: tuple[float, float] = (6.05e-3, 6.0e-3)
    turb_flow_exp: float = 1.6
    turb_area_speed: float = 0.05
    turb_tip_speed_ref_m_s: float = 440.0
    turb_eta_max: tuple[float, float] = (0.76, 0.757)
    turb_bsr_opt: float = 0.68
    turb_eta_bsr_q: float = 1.2
    turb_eta_min: float = 0.35
    wastegate_area_m2: tuple[float, float] = (1.5e-3, 1.5e-3)
    wastegate_open_pa: float = 4.0e5
    wastegate_span_pa: float = 1.5e5
    exhaust_dp_ref_pa: float = 3500.0
    exhaust_flow_ref_kg_s: float = 4.3
    tc_inertia_kg_m2: tuple[float, float] = (0.35, 0.36)
    tc_friction_w_s2: float = 8.0e-4
    tc_speed_min_rad_s: float = 400.0
    # fuel system and governor
    rack_zero_pct: float = 8.0
    fuel_rack100_kg_cyc: float = 3.3e-3
    rack_speed_gain: float = 0.06
    fuel_actuator_tau_s: float = 0.2
    lambda_limit: float = 1.55
    # sensors (thermocouple time constants per bank)
    tau_tc_in_s: tuple[float, float] = (25.0, 28.0)
    tau_tc_out_s: tuple[float, float] = (35.0, 32.0)
    tau_tc_cyl_s: tuple[float, float] = (20.0, 22.0)
    # integration
    step_s: float = 1.5
    substeps: int = 2

    def bank(self, name: str) -> np.ndarray:
        """A per-bank constant as a (2, 1) array for broadcasting over lanes."""
        return np.asarray(getattr(self, name), dtype=float).reshape(2, 1)


def engine_config(rng: np.random.Generator | None = None) -> EngineConfig:
    """The engine's constants; with ``rng``, the banks get small seed-dependent differences.

    The draws (up to +-0.5 % on maps and areas, +-3 % on scavenge area and intercooler
    NTU, +-2 s on thermocouple time constants)
    model manufacturing scatter between the two turbochargers and sensor mountings.
    """
    cfg = EngineConfig()
    if rng is None:
        return cfg

    def jitter(name: str, rel: float) -> tuple[float, float]:
        v = np.asarray(getattr(cfg, name), dtype=float)
        return tuple(float(x) for x in v * (1.0 + rel * rng.uniform(-1.0, 1.0, 2)))

    def shift(name: str, amount: float) -> tuple[float, float]:
        v = np.asarray(getattr(cfg, name), dtype=float)
        return tuple(float(x) for x in v + amount * rng.uniform(-1.0, 1.0, 2))

    return replace(
        cfg,
        comp_psi_max=jitter("comp_psi_max", 0.005),
        comp_flow_max_kg_s=jitter("comp_flow_max_kg_s", 0.005),
        comp_eta_max=jitter("comp_eta_max", 0.004),
        ic_ntu_ref=jitter("ic_ntu_ref", 0.02),
        scavenge_area_m2=jitter("scavenge_area_m2", 0.03),
        turb_area_m2=jitter("turb_area_m2", 0.005),
        turb_eta_max=jitter("turb_eta_max", 0.004),
        tau_tc_in_s=shift("tau_tc_in_s", 2.0),
        tau_tc_out_s=shift("tau_tc_out_s", 2.0),
        tau_tc_cyl_s=shift("tau_tc_cyl_s", 2.0),
    )


STREAM_ENGINE = 2
"""Random stream (``default_rng([seed, STREAM_ENGINE])``) of the engine's bank scatter."""


def engine_for_seed(seed: int) -> EngineConfig:
    """The engine instance of data set ``seed`` (the same in ``generate`` and ``simulator_fat``)."""
    return engine_config(np.random.default_rng([seed, STREAM_ENGINE]))


# -- rack law --------------------------------------------------------------------------
def rack_to_fuel(cfg: EngineConfig, rack_pct: np.ndarray, speed_rpm: np.ndarray) -> np.ndarray:
    """Fuel per cylinder per cycle (kg) delivered by the injection pumps at a rack position."""
    gain = 1.0 + cfg.rack_speed_gain * (np.asarray(speed_rpm) / C.N_MCR_RPM - 1.0)
    frac = (np.asarray(rack_pct) - cfg.rack_zero_pct) / (100.0 - cfg.rack_zero_pct)
    return cfg.fuel_rack100_kg_cyc * np.maximum(frac, 0.0) * gain


def fuel_to_rack(cfg: EngineConfig, fuel_kg_cyc: np.ndarray, speed_rpm: np.ndarray) -> np.ndarray:
    """Rack position (%) that meters ``fuel_kg_cyc``: the inverse of ``rack_to_fuel``."""
    gain = 1.0 + cfg.rack_speed_gain * (np.asarray(speed_rpm) / C.N_MCR_RPM - 1.0)
    frac = np.asarray(fuel_kg_cyc) / (cfg.fuel_rack100_kg_cyc * gain)
    return cfg.rack_zero_pct + (100.0 - cfg.rack_zero_pct) * frac


# -- state and one integration step ----------------------------------------------------
class _Consts:
    """Per-bank constants as (2, 1) arrays, built once per run (cheap attribute access)."""

    def __init__(self, cfg: EngineConfig) -> None:
        for name, value in vars(cfg).items():
            setattr(self, name, np.asarray(value, dtype=float).reshape(2, 1) if isinstance(value, tuple) else value)
        self.vd_bank = C.N_CYL_BANK * C.V_D_CYL_M3


@dataclass
class _State:
    omega: np.ndarray      # (2, n) turbocharger speed, rad/s
    p_im: np.ndarray       # (2, n) intake receiver pressure, Pa
    p_em: np.ndarray       # (2, n) exhaust receiver pressure, Pa
    t_wall: np.ndarray     # (2, n) exhaust-manifold wall temperature, K
    m_comp: np.ndarray     # (2, n) compressor flow of the previous step, kg/s
    t_im: np.ndarray       # (2, n) intake temperature of the previous step, K
    fuel: np.ndarray       # (n,) fuel per cylinder per cycle, kg
    tc_in: np.ndarray      # (2, n) thermocouple temperatures, K
    tc_out: np.ndarray
    tc_cyl: np.ndarray
    diag: dict = field(default_factory=dict)


def _initial_state(u: dict[str, np.ndarray]) -> _State:
    """A rough start from the demanded load; the settling steps do the rest."""
    load = np.minimum(np.maximum(u["power_demand_w"] / C.P_MCR_W, 0.0), 1.15)
    ones = np.ones((2, load.shape[0]))
    p_amb = u["p_amb_pa"]
    speed = np.maximum(u["speed_rpm"], 50.0)
    fuel = (u["power_demand_w"] + 0.1 * C.P_MCR_W * speed / C.N_MCR_RPM) / (
        0.45 * C.LHV_J_PER_KG * C.N_CYL * speed / 120.0)
    t_wall = ones * (420.0 + 380.0 * load**0.3)
    return _State(omega=ones * (900.0 + 2300.0 * np.sqrt(load)), p_im=ones * (p_amb + 3.1e5 * load**0.9),
                  p_em=ones * (p_amb + 2.0e5 * load**0.9), t_wall=t_wall, m_comp=ones * (4.0 * load + 0.3),
                  t_im=ones * (u["t_coolant_k"] + 10.0), fuel=fuel, tc_in=t_wall + 50.0,
                  tc_out=t_wall - 50.0, tc_cyl=t_wall + 80.0)


def _safe_newton(fun: Callable, lo: np.ndarray, hi: np.ndarray, x: np.ndarray, iters: int,
                 tol: float) -> np.ndarray:
    """Root of an increasing function: Newton steps kept inside a shrinking bracket.

    Stops once every Newton step is smaller than ``tol`` (and stays in its bracket).
    """
    lo, hi = np.broadcast_to(lo, x.shape), np.broadcast_to(hi, x.shape)
    x = np.minimum(np.maximum(x, lo), hi)
    for _ in range(iters):
        g, dg = fun(x)
        pos = g > 0.0
        hi = np.where(pos, x, hi)
        lo = np.where(pos, lo, x)
        xn = x - g / dg
        inside = (xn >= lo) & (xn <= hi)
        if inside.all() and np.max(np.abs(xn - x)) < tol:
            return xn
        x = np.where(inside, xn, 0.5 * (lo + hi))
    return x


P_RECEIVER_MAX_PA = 8.0e5
"""Upper bracket of the receiver pressure solves, Pa."""
NEWTON_ITERS = 12
NEWTON_TOL_PA = 1.0
"""Receiver solves stop when every Newton step is below this, Pa."""
X_AIR = (C.KAPPA_AIR - 1.0) / C.KAPPA_AIR
X_GAS = (C.KAPPA_GAS - 1.0) / C.KAPPA_GAS


def _step(st: _State, u: dict[str, np.ndarray], k: _Consts, steady: bool, record: bool) -> None:
    """Advance the state by one step of ``step_s`` seconds (in place).

    The receivers are integrated by implicit Euler, solved exactly by safeguarded
    Newton: first the intake receiver at the old exhaust pressure, then the exhaust
    receiver at the new intake pressure. The rotor (linearly implicit), the manifold
    wall and the thermocouples (exact first-order steps) follow with the flows and
    temperatures at the new pressures; the governor then sets the next fuel quantity.
    """
    h = k.step_s
    N = np.maximum(u["speed_rpm"], 50.0)
    n_rel = N / C.N_MCR_RPM
    n_cps = N / 120.0                                   # cycles per second per cylinder
    vdn = k.vd_bank * n_cps                             # swept volume flow of a bank, m^3/s
    t_amb, p_amb = u["t_amb_k"], u["p_amb_pa"]
    omega, p_em_old = st.omega, st.p_em

    # -- compressor map at this rotor speed ------------------------------------------------
    flow2 = (st.m_comp / k.flow_ref_kg_s) ** 2
    p_in = p_amb - k.filter_dp_ref_pa * flow2
    dp_ic = k.ic_dp_ref_pa * flow2
    sq_theta = np.sqrt(t_amb / C.T_REF_K)
    u_c = omega * k.comp_radius_m / sq_theta                       # corrected tip speed, m/s
    u_rel = u_c / k.comp_tip_speed_ref_m_s
    h_max = k.comp_psi_max * u_c**2 / (C.CP_AIR * C.T_REF_K)       # largest isentropic head
    m_max = k.comp_flow_max_kg_s * u_rel**k.comp_flow_speed_exp * (p_in / C.P_REF_PA) / sq_theta

    def compressor(p):
        pi_c = (p + dp_ic) / p_in
        head1 = pi_c**X_AIR
        ratio = np.minimum(np.maximum(head1 - 1.0, 0.0) / h_max, 1.0)
        slope = 2.0 * m_max * ratio / h_max * X_AIR * head1 / (p + dp_ic)
        return m_max * (1.0 - ratio * ratio), -slope, ratio

    # -- gas exchange pieces that do not depend on the receiver pressures -----------------------
    ev_speed = k.eta_vol_0 - k.eta_vol_speed_q * (n_rel - k.eta_vol_speed_opt) ** 2
    s2 = k.scavenge_dp_smooth_pa**2

    def gas_exchange(p_i, p_e, t_im):
        rho = p_i / (C.R_AIR * t_im)
        rel = np.minimum(np.maximum(p_e / p_i - 1.0, -0.5), 1.0)
        m_tr = np.minimum(np.maximum(ev_speed - k.eta_vol_dp * rel, 0.6), 1.0) * rho * vdn
        dp = p_i - p_e
        r = np.sqrt(dp * dp + s2)
        dps = 0.5 * (dp + r)
        coef = k.scavenge_area_m2 * np.sqrt(2.0 * rho)
        sq = np.sqrt(dps)
        m_sc = coef * sq
        dmsc = coef * 0.5 * (1.0 + dp / r) / (2.0 * np.maximum(sq, 1.0))   # d m_sc / d(p_i - p_e)
        return m_tr, m_sc, dmsc

    # -- intake receiver: p - p_old = h R T / V (m_compressor - m_engine) -----------------------
    k_im = h * C.R_AIR * st.t_im / k.v_im_m3

    def g_im(p):
        m_c, dm_c, _ = compressor(p)
        m_tr, m_sc, dmsc = gas_exchange(p, p_em_old, st.t_im)
        return p - st.p_im - k_im * (m_c - m_tr - m_sc), 1.0 - k_im * (dm_c - m_tr / p - dmsc)

    p_im = _safe_newton(g_im, 0.3 * p_amb, P_RECEIVER_MAX_PA, st.p_im, NEWTON_ITERS, NEWTON_TOL_PA)

    # -- compressor and intercooler at the new intake pressure ----------------------------------
    m_c, _, ratio = compressor(p_im)
    head = ratio * h_max
    frac = m_c / m_max
    eta_c = (k.comp_eta_max - k.comp_eta_flow_q * (frac - k.comp_eta_flow_opt) ** 2
             - k.comp_eta_speed_q * (u_rel - k.comp_eta_speed_opt) ** 2)
    eta_c = np.maximum(eta_c, k.comp_eta_min) * (1.0 - u["foul_comp"])
    t_c_out = t_amb * (1.0 + head / eta_c)
    p_comp = m_c * C.CP_AIR * (t_c_out - t_amb)
    ntu = k.ic_ntu_ref * (1.0 - u["foul_ic"]) * np.maximum(m_c / k.flow_ref_kg_s, 0.05) ** k.ic_ntu_flow_exp
    t_im = t_c_out - (1.0 - np.exp(-ntu)) * (t_c_out - u["t_coolant_k"])
    q_ic = m_c * C.CP_AIR * (t_c_out - t_im)

    # -- cylinders ------------------------------------------------------------------------------
    fuel = st.fuel                                                   # (n,) kg per cylinder per cycle
    m_f = np.broadcast_to(C.N_CYL_BANK * fuel * n_cps, p_im.shape)   # (2, n) kg/s per bank
    load = fuel / k.fuel_mcr_kg_cyc
    q_fuel = m_f * C.LHV_J_PER_KG
    p_aux = 0.5 * k.aux_power_mcr_w * n_rel**3
    eta_ig_n = (k.eta_ig_base * (1.0 - k.eta_ig_speed_q * (n_rel - k.eta_ig_speed_opt) ** 2)
                * (1.0 - k.eta_ig_low_load * np.exp(-load / k.eta_ig_low_load_scale)))
    eta_comb_l = k.eta_comb_max - k.eta_comb_low_load * np.exp(-load / k.eta_comb_low_load_scale)
    x_wall = (k.wall_heat_frac * n_rel ** (-k.wall_heat_speed_exp)
              * (1.0 + k.wall_heat_low_load * np.exp(-load / k.wall_heat_low_load_scale)))
    cpa_im = C.CP_AIR * (t_im - C.T_REF_K)                           # air enthalpy per kg, J/kg

    def cylinder(p_em):
        m_tr, m_sc, _ = gas_exchange(p_im, p_em, t_im)
        air_cyc = m_tr / (C.N_CYL_BANK * n_cps)
        lam = air_cyc / (C.AFR_STOICH * np.maximum(fuel, 1e-7))
        eta_comb = np.maximum(eta_comb_l - k.eta_comb_smoke * np.maximum(k.lambda_smoke - lam, 0.0) ** 2, 0.6)
        eta_ig = eta_ig_n * (1.0 - k.eta_ig_lambda / np.maximum(lam, 1.0))
        q_burnt = eta_comb * q_fuel
        p_ig = eta_ig * q_burnt
        p_pump = (p_em - p_im) * vdn                                # gas-exchange loss, W
        q_wall = x_wall * q_burnt
        m_gas = m_tr + m_f
        # cylinder energy balance: enthalpies from T_REF, fuel entering with its LHV
        h_gas = m_tr * cpa_im + q_burnt - (p_ig - p_pump) - q_wall
        m_ex = m_gas + m_sc
        t_cyl = C.T_REF_K + h_gas / (m_gas * C.CP_GAS)
        t_mix = C.T_REF_K + (h_gas + m_sc * cpa_im) / (m_ex * C.CP_GAS)
        ha = k.em_wall_ha_ref_w_k * np.maximum(m_ex / k.exhaust_flow_ref_kg_s, 0.02) ** 0.8
        g_w = -np.expm1(-ha / (m_ex * C.CP_GAS)) * m_ex * C.CP_GAS     # gas -> wall, W/K
        return dict(m_tr=m_tr, m_sc=m_sc, air_cyc=air_cyc, lam=lam, eta_comb=eta_comb, eta_ig=eta_ig,
                    q_burnt=q_burnt, p_ig=p_ig, p_pump=p_pump, q_wall=q_wall, t_cyl=t_cyl, m_ex=m_ex,
                    t_mix=t_mix, g_w=g_w)

    ua = k.em_wall_ua_ins_w_k

    def manifold(cy):
        t_wall = (cy["g_w"] * cy["t_mix"] + ua * t_amb) / (cy["g_w"] + ua) if steady else st.t_wall
        q_gw = cy["g_w"] * (cy["t_mix"] - t_wall)
        return t_wall, q_gw, cy["t_mix"] - q_gw / (cy["m_ex"] * C.CP_GAS)

    area = (k.turb_area_m2 * (1.0 - u["foul_turb"])
            * (1.0 + k.turb_area_speed * (omega * k.turb_radius_m / k.turb_tip_speed_ref_m_s - 1.0)))
    k_t = k.turb_flow_exp

    # exhaust waste gate: opens with charge pressure, bypasses gas around the turbine
    wg = np.clip((p_im - k.wastegate_open_pa) / k.wastegate_span_pa, 0.0, 1.0)
    wg_share = k.wastegate_area_m2 * wg * wg * (3.0 - 2.0 * wg) / area    # bypass / turbine flow

    def turbine_flow(p_em, t_em, p_ta):
        """Flow through turbine and waste gate (same flow law), its slope in p_em, pressure ratio."""
        pi_t = np.maximum(p_em / p_ta, 1.0 + 1e-9)
        pk = pi_t ** (-k_t)
        psi = np.sqrt(1.0 - pk)
        coef = area * (1.0 + wg_share) / np.sqrt(C.R_GAS * t_em)
        dpsi = 0.5 * k_t * pk / (pi_t * np.maximum(psi, 1e-4))
        return coef * p_em * psi, coef * (psi + pi_t * dpsi), pi_t

    # -- exhaust receiver: p - p_old = h R T / V (m_cylinders + m_scavenge - m_turbine) ----------
    cy0 = cylinder(p_em_old)
    t_em0 = manifold(cy0)[2]
    p_ta0 = p_amb + k.exhaust_dp_ref_pa * (cy0["m_ex"] / k.exhaust_flow_ref_kg_s) ** 2
    k_em = h * C.R_GAS * t_em0 / k.v_em_m3

    rho_im = p_im / (C.R_AIR * t_im)
    tr_scale = rho_im * vdn
    sc_coef = k.scavenge_area_m2 * np.sqrt(2.0 * rho_im)

    def g_em(p):
        rel = np.minimum(np.maximum(p / p_im - 1.0, -0.5), 1.0)
        m_tr = np.minimum(np.maximum(ev_speed - k.eta_vol_dp * rel, 0.6), 1.0) * tr_scale
        dp = p_im - p
        r = np.sqrt(dp * dp + s2)
        sq = np.sqrt(0.5 * (dp + r))
        dmsc = sc_coef * 0.5 * (1.0 + dp / r) / (2.0 * np.maximum(sq, 1.0))
        m_t, dm_t, _ = turbine_flow(p, t_em0, p_ta0)
        return p - p_em_old - k_em * (m_tr + sc_coef * sq + m_f - m_t), 1.0 + k_em * (dmsc + dm_t)

    p_em = _safe_newton(g_em, p_ta0 * (1.0 + 1e-6), P_RECEIVER_MAX_PA, np.maximum(p_em_old, p_ta0 * 1.001),
                        NEWTON_ITERS, NEWTON_TOL_PA)

    # -- everything at the new pressures -------------------------------------------------------
    cy = cylinder(p_em)
    t_wall, q_gw, t_em = manifold(cy)
    q_loss = ua * (t_wall - t_amb)
    p_ta = p_amb + k.exhaust_dp_ref_pa * (cy["m_ex"] / k.exhaust_flow_ref_kg_s) ** 2
    m_out, _, pi_t = turbine_flow(p_em, t_em, p_ta)
    m_t = m_out / (1.0 + wg_share)                                   # through the turbine wheel
    expn = 1.0 - pi_t ** (-X_GAS)
    c_s = np.sqrt(2.0 * C.CP_GAS * t_em * expn)
    bsr = omega * k.turb_radius_m / np.maximum(c_s, 1.0)
    eta_t = np.maximum(k.turb_eta_max * (1.0 - k.turb_eta_bsr_q * (bsr / k.turb_bsr_opt - 1.0) ** 2), k.turb_eta_min)
    p_turb = m_t * C.CP_GAS * t_em * expn * eta_t
    t_ta = t_em * (1.0 - expn * eta_t * m_t / m_out)              # after the waste-gate junction
    p_tcf = k.tc_friction_w_s2 * omega**2
    fmep = k.fmep_0_pa + k.fmep_2_pa * n_rel**2 + k.fmep_imep * cy["p_ig"] / vdn
    p_fric = fmep * vdn

    # -- rotor (linearly implicit), wall, thermocouples -----------------------------------------
    inertia = k.tc_inertia_kg_m2
    f_w = (p_turb - p_tcf - p_comp) / (inertia * omega)
    j_w = -(3.0 * p_comp + 2.0 * p_tcf + p_turb) / (inertia * omega**2)
    st.omega = np.maximum(omega + h * f_w / (1.0 - h * j_w), k.tc_speed_min_rad_s)
    st.p_im, st.p_em, st.m_comp, st.t_im = p_im, p_em, m_c, t_im
    if steady:
        st.t_wall = t_wall
        st.tc_in, st.tc_out, st.tc_cyl = t_em, t_ta, cy["t_cyl"]
    else:
        st.t_wall = st.t_wall + h * (q_gw - q_loss) / (k.em_wall_capacity_j_k + h * (cy["g_w"] + ua))
        st.tc_in = t_em + (st.tc_in - t_em) * np.exp(-h / k.tau_tc_in_s)
        st.tc_out = t_ta + (st.tc_out - t_ta) * np.exp(-h / k.tau_tc_out_s)
        st.tc_cyl = cy["t_cyl"] + (st.tc_cyl - cy["t_cyl"]) * np.exp(-h / k.tau_tc_cyl_s)

    if record:
        # peak pressure: polytropic compression plus an isochoric-like rise from the fuel
        t_comp = (t_im + k.p_max_heat_k) * C.COMPRESSION_RATIO ** (k.p_max_poly - 1.0)
        q_ratio = cy["eta_comb"] * fuel * C.LHV_J_PER_KG / (cy["air_cyc"] * k.cv_cyl * t_comp)
        rise = k.p_max_rise * q_ratio * n_rel ** (-k.p_max_speed_exp)
        p_max = p_im * C.COMPRESSION_RATIO**k.p_max_poly * (1.0 + rise)
        p_brake = cy["p_ig"] - cy["p_pump"] - p_fric - p_aux
        st.diag.update(
            tc_speed_rpm=omega / C.RPM_TO_RAD_S, p_im_pa=p_im, t_im_k=t_im, t_comp_out_k=t_c_out,
            p_em_pa=p_em, t_cyl_out_k=cy["t_cyl"], t_turb_in_k=t_em, t_turb_out_k=t_ta, p_max_pa=p_max,
            q_intercooler_w=q_ic, m_air_kg_s=m_c, lambda_trapped=cy["lam"].mean(axis=0),
            fuel_kg_cyc=fuel, fuel_flow_kg_s=m_f.sum(axis=0), brake_power_w=p_brake.sum(axis=0),
            friction_power_w=p_fric.sum(axis=0), aux_power_w=2.0 * p_aux,
            wall_heat_w=cy["q_wall"].sum(axis=0), tc_friction_w=p_tcf.sum(axis=0),
            manifold_loss_w=q_loss.sum(axis=0), unburnt_w=(q_fuel - cy["q_burnt"]).sum(axis=0),
            tc_meas_in_k=st.tc_in, tc_meas_out_k=st.tc_out, tc_meas_cyl_k=st.tc_cyl,
            m_turb_kg_s=m_out, m_wastegate_kg_s=m_out - m_t, m_eng_kg_s=cy["m_tr"] + cy["m_sc"],
            p_turb_w=p_turb, p_comp_w=p_comp,
        )

    # -- governor: fuel for the demanded brake power; rack and boost limits; actuator lag -------
    losses = (cy["p_pump"] + p_fric).sum(axis=0) + 2.0 * p_aux
    gain = (cy["eta_ig"] * cy["eta_comb"]).sum(axis=0) * C.N_CYL_BANK * n_cps * C.LHV_J_PER_KG
    limit = np.minimum(rack_to_fuel(k, 100.0, N), cy["air_cyc"].min(axis=0) / (C.AFR_STOICH * k.lambda_limit))
    cmd = np.minimum(np.maximum((u["power_demand_w"] + losses) / gain, 0.0), limit)
    st.fuel = cmd + (fuel - cmd) * np.exp(-h / k.fuel_actuator_tau_s)


def run_lanes(inputs: dict[str, np.ndarray], cfg: EngineConfig, *, settle_steps: int = 60,
              steady: bool = False) -> dict[str, np.ndarray]:
    """Simulate lanes of per-sample inputs, each (n_lanes, n_samples); outputs at every sample.

    Before the first sample every lane settles ``settle_steps`` steps at its first
    sample's inputs (turbocharger, receivers, governor) and then starts its wall and
    thermocouples at equilibrium. Within a sample the inputs move linearly from the
    previous sample's values (``cfg.substeps`` steps of ``cfg.step_s`` seconds).
    ``steady=True`` holds the wall and thermocouples at equilibrium throughout.
    Bank outputs have shape (2, n_lanes, n_samples), engine outputs (n_lanes, n_samples).
    """
    missing = [k for k in INPUT_NAMES if k not in inputs]
    if missing:
        raise KeyError(f"engine inputs lack {', '.join(missing)}")
    n_lanes, n_samples = inputs["speed_rpm"].shape
    u0 = {k: np.ascontiguousarray(inputs[k][:, 0], dtype=float) for k in INPUT_NAMES}
    consts = _Consts(cfg)
    st = _initial_state(u0)
    for _ in range(settle_steps):
        _step(st, u0, consts, steady=True, record=False)
    out_bank = {k: np.empty((2, n_lanes, n_samples)) for k in BANK_OUTPUTS}
    out_eng = {k: np.empty((n_lanes, n_samples)) for k in ENGINE_OUTPUTS}
    cols = {k: np.ascontiguousarray(inputs[k].T, dtype=float) for k in INPUT_NAMES}  # (n_samples, n_lanes)
    prev = u0
    m = cfg.substeps
    for i in range(n_samples):
        cur = {k: cols[k][i] for k in INPUT_NAMES}
        for j in range(1, m + 1):
            w = j / m
            u = cur if j == m else {k: prev[k] + w * (cur[k] - prev[k]) for k in INPUT_NAMES}
            _step(st, u, consts, steady=steady, record=(j == m))
        d = st.diag
        for k in BANK_OUTPUTS:
            out_bank[k][:, :, i] = d[k]
        for k in ENGINE_OUTPUTS:
            out_eng[k][:, i] = d[k]
        prev = cur
    return {**out_bank, **out_eng}


def steady_state(speed_rpm: np.ndarray, power_w: np.ndarray, cfg: EngineConfig | None = None, *,
                 t_amb_k: float = 298.15, p_amb_pa: float = 1.0e5, t_coolant_k: float = 305.15,
                 steps: int = 240) -> dict[str, np.ndarray]:
    """Steady operating points of the true engine (everything at equilibrium), one per entry.

    Also returns the turbine/compressor powers and flows needed for energy balances.
    """
    cfg = cfg or EngineConfig()
    speed = np.atleast_1d(np.asarray(speed_rpm, dtype=float))
    power = np.broadcast_to(np.asarray(power_w, dtype=float), speed.shape).copy()
    n = speed.size
    u = {
        "speed_rpm": speed, "power_demand_w": power, "t_amb_k": np.full(n, t_amb_k),
        "p_amb_pa": np.full(n, p_amb_pa), "t_coolant_k": np.full(n, t_coolant_k),
        "foul_comp": np.zeros(n), "foul_turb": np.zeros(n), "foul_ic": np.zeros(n),
    }
    consts = _Consts(cfg)
    st = _initial_state(u)
    for _ in range(steps - 1):
        _step(st, u, consts, steady=True, record=False)
    _step(st, u, consts, steady=True, record=True)
    out = dict(st.diag)
    out["rack_pct"] = fuel_to_rack(cfg, st.fuel, speed)
    return out


def lane_plan(starts: np.ndarray, stops: np.ndarray, lane_len: int, warmup: int) -> tuple[np.ndarray, np.ndarray]:
    """Cut runs [start, stop) of rows into lanes of ``lane_len`` kept rows plus ``warmup``.

    Returns ``index`` (n_lanes, warmup + lane_len) of row numbers (clamped to the run,
    so a lane at a run's start repeats its first row: the engine settles there) and
    ``keep`` (n_lanes, lane_len) of booleans marking rows that belong to the lane.
    """
    idx_rows, keep_rows = [], []
    offs = np.arange(-warmup, lane_len)
    for a, b in zip(starts, stops):
        firsts = np.arange(a, b, lane_len)
        if firsts.size == 0:
            continue
        pos = firsts[:, None] + offs[None, :]
        idx_rows.append(np.clip(pos, a, b - 1))
        keep_rows.append(pos[:, warmup:] < b)
    return np.concatenate(idx_rows), np.concatenate(keep_rows)


def simulate_rows(inputs: dict[str, np.ndarray], starts: np.ndarray, stops: np.ndarray,
                  cfg: EngineConfig, *, lane_len: int = 1200, warmup: int = 100,
                  batch_lanes: int = 1024,
                  progress: Callable[[float], None] | None = None) -> dict[str, np.ndarray]:
    """Simulate continuous runs of rows ([start, stop) each) given per-row inputs (n_rows,).

    Runs are cut into lanes simulated side by side; each lane first replays ``warmup``
    samples before its own rows, so that its state (time constants up to ~40 s for the
    thermocouples, ~100 s for the manifold wall) has forgotten the approximate start
    (warm-up of 300 s by default). Returns per-row arrays: bank outputs (2, n_rows),
    engine outputs (n_rows,).
    """
    n_rows = len(inputs["speed_rpm"])
    index, keep = lane_plan(np.asarray(starts), np.asarray(stops), lane_len, warmup)
    out = {k: np.empty((2, n_rows)) for k in BANK_OUTPUTS}
    out.update({k: np.empty(n_rows) for k in ENGINE_OUTPUTS})
    n_lanes = index.shape[0]
    for b0 in range(0, n_lanes, batch_lanes):
        sl = slice(b0, min(b0 + batch_lanes, n_lanes))
        idx = index[sl]
        res = run_lanes({k: np.asarray(inputs[k])[idx] for k in INPUT_NAMES}, cfg)
        rows = idx[:, warmup:][keep[sl]]
        for k in BANK_OUTPUTS:
            out[k][:, rows] = res[k][:, :, warmup:][:, keep[sl]]
        for k in ENGINE_OUTPUTS:
            out[k][rows] = res[k][:, warmup:][keep[sl]]
        if progress is not None:
            progress(sl.stop / n_lanes)
    return out
