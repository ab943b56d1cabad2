"""Components of the marine engine's mean-value model, one function or map each (used by ``engine._step``).

Every array is per bank (2, n) unless said otherwise; ``k`` is the engine's constants
(``engine._Consts``: per-bank values as (2, 1) arrays). The compressor, gas exchange and
turbine are evaluated at the step's rotor speed and inputs, then solved against the
receivers' implicit-Euler filling equations by safeguarded Newton; the rotor, the
manifold wall, the thermocouples and the governor advance after them. The expressions
are the model's equations written once, in the order that fixes the engine's numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from enginebench.datasets.marine_diesel import constants as C

P_RECEIVER_MAX_PA = 8.0e5
"""Upper bracket of the receiver pressure solves, Pa."""
NEWTON_ITERS = 12
NEWTON_TOL_PA = 1.0
"""Receiver solves stop when every Newton step is below this, Pa."""
X_AIR = (C.KAPPA_AIR - 1.0) / C.KAPPA_AIR
X_GAS = (C.KAPPA_GAS - 1.0) / C.KAPPA_GAS


def safe_newton(fun: Callable, lo: np.ndarray, hi: np.ndarray, x: np.ndarray, iters: int, tol: float) -> np.ndarray:
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


# -- compressor and intercooler ------------------------------------------------------------
@dataclass(frozen=True)
class Compressor:
    """The compressor's speed line at this step's rotor speed and inlet state (after hil-diesel eqs. 3-7).

    Speed lines m = m_max(U) (1 - (H / H_max(U))^2) in corrected flow, H = pi^((k-1)/k) - 1
    the isentropic head; the filter and intercooler pressure losses follow the previous
    step's flow.
    """

    p_in: np.ndarray
    dp_ic: np.ndarray
    u_rel: np.ndarray
    h_max: np.ndarray
    m_max: np.ndarray

    @classmethod
    def at(cls, k: Any, omega: np.ndarray, m_comp: np.ndarray, t_amb: np.ndarray, p_amb: np.ndarray) -> "Compressor":
        flow2 = (m_comp / k.flow_ref_kg_s) ** 2
        p_in = p_amb - k.filter_dp_ref_pa * flow2
        dp_ic = k.ic_dp_ref_pa * flow2
        sq_theta = np.sqrt(t_amb / C.T_REF_K)
        u_c = omega * k.comp_radius_m / sq_theta                       # corrected tip speed, m/s
        u_rel = u_c / k.comp_tip_speed_ref_m_s
        h_max = k.comp_psi_max * u_c**2 / (C.CP_AIR * C.T_REF_K)       # largest isentropic head
        m_max = k.comp_flow_max_kg_s * u_rel**k.comp_flow_speed_exp * (p_in / C.P_REF_PA) / sq_theta
        return cls(p_in, dp_ic, u_rel, h_max, m_max)

    def flow(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(flow, its slope in the intake pressure ``p``, head fraction H / H_max)."""
        pi_c = (p + self.dp_ic) / self.p_in
        head1 = pi_c**X_AIR
        ratio = np.minimum(np.maximum(head1 - 1.0, 0.0) / self.h_max, 1.0)
        slope = 2.0 * self.m_max * ratio / self.h_max * X_AIR * head1 / (p + self.dp_ic)
        return self.m_max * (1.0 - ratio * ratio), -slope, ratio

    def outlet(self, k: Any, m_c: np.ndarray, ratio: np.ndarray, t_amb: np.ndarray,
               foul_comp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(outlet temperature, shaft power): efficiency a quadratic hill in flow fraction and tip speed, fouled."""
        head = ratio * self.h_max
        frac = m_c / self.m_max
        eta_c = (k.comp_eta_max - k.comp_eta_flow_q * (frac - k.comp_eta_flow_opt) ** 2
                 - k.comp_eta_speed_q * (self.u_rel - k.comp_eta_speed_opt) ** 2)
        eta_c = np.maximum(eta_c, k.comp_eta_min) * (1.0 - foul_comp)
        t_c_out = t_amb * (1.0 + head / eta_c)
        return t_c_out, m_c * C.CP_AIR * (t_c_out - t_amb)


def intercooler(k: Any, m_c: np.ndarray, t_c_out: np.ndarray, t_coolant: np.ndarray,
                foul_ic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(intake temperature, heat to the LT water): effectiveness 1 - exp(-NTU), NTU falling with flow and fouling."""
    ntu = k.ic_ntu_ref * (1.0 - foul_ic) * np.maximum(m_c / k.flow_ref_kg_s, 0.05) ** k.ic_ntu_flow_exp
    t_im = t_c_out - (1.0 - np.exp(-ntu)) * (t_c_out - t_coolant)
    return t_im, m_c * C.CP_AIR * (t_c_out - t_im)


# -- gas exchange and receivers ------------------------------------------------------------
@dataclass(frozen=True)
class GasExchange:
    """Trapped and scavenge flows (hil-diesel eqs. 13-14) at this step's engine speed."""

    k: Any
    ev_speed: np.ndarray
    """Volumetric efficiency's speed part."""
    vdn: np.ndarray
    """Swept volume flow of a bank, m^3/s."""
    s2: float
    """Square of the scavenge pressure-difference smoothing, Pa^2."""

    @classmethod
    def at(cls, k: Any, n_rel: np.ndarray, vdn: np.ndarray) -> "GasExchange":
        ev_speed = k.eta_vol_0 - k.eta_vol_speed_q * (n_rel - k.eta_vol_speed_opt) ** 2
        return cls(k, ev_speed, vdn, k.scavenge_dp_smooth_pa**2)

    def flows(self, p_i: np.ndarray, p_e: np.ndarray, t_im: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(trapped flow, scavenge flow, d scavenge / d(p_i - p_e)) between intake ``p_i`` and exhaust ``p_e``."""
        k = self.k
        rho = p_i / (C.R_AIR * t_im)
        rel = np.minimum(np.maximum(p_e / p_i - 1.0, -0.5), 1.0)
        m_tr = np.minimum(np.maximum(self.ev_speed - k.eta_vol_dp * rel, 0.6), 1.0) * rho * self.vdn
        dp = p_i - p_e
        r = np.sqrt(dp * dp + self.s2)
        dps = 0.5 * (dp + r)
        coef = k.scavenge_area_m2 * np.sqrt(2.0 * rho)
        sq = np.sqrt(dps)
        m_sc = coef * sq
        dmsc = coef * 0.5 * (1.0 + dp / r) / (2.0 * np.maximum(sq, 1.0))   # d m_sc / d(p_i - p_e)
        return m_tr, m_sc, dmsc


def intake_receiver(k: Any, h: float, comp: Compressor, gx: GasExchange, p_im_old: np.ndarray, t_im_old: np.ndarray,
                    p_em_old: np.ndarray, p_amb: np.ndarray) -> np.ndarray:
    """New intake pressure: p - p_old = h R T / V (m_compressor - m_engine), implicit, at the old exhaust pressure."""
    k_im = h * C.R_AIR * t_im_old / k.v_im_m3

    def g_im(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m_c, dm_c, _ = comp.flow(p)
        m_tr, m_sc, dmsc = gx.flows(p, p_em_old, t_im_old)
        return p - p_im_old - k_im * (m_c - m_tr - m_sc), 1.0 - k_im * (dm_c - m_tr / p - dmsc)

    return safe_newton(g_im, 0.3 * p_amb, P_RECEIVER_MAX_PA, p_im_old, NEWTON_ITERS, NEWTON_TOL_PA)


# -- cylinders and exhaust manifold --------------------------------------------------------
@dataclass(frozen=True)
class Cylinders:
    """A bank's cylinders at this step's intake state and fuel (hil-diesel eqs. 17-21): combustion and
    indicated efficiencies, pumping work, wall heat and the cylinder energy balance."""

    k: Any
    gx: GasExchange
    p_im: np.ndarray
    t_im: np.ndarray
    fuel: np.ndarray
    """(n,) fuel per cylinder per cycle, kg."""
    n_cps: np.ndarray
    m_f: np.ndarray
    """(2, n) fuel flow per bank, kg/s."""
    q_fuel: np.ndarray
    eta_ig_n: np.ndarray
    eta_comb_l: np.ndarray
    x_wall: np.ndarray
    cpa_im: np.ndarray
    """Air enthalpy per kg from T_REF, J/kg."""

    @classmethod
    def at(cls, k: Any, gx: GasExchange, p_im: np.ndarray, t_im: np.ndarray, fuel: np.ndarray, n_rel: np.ndarray,
           n_cps: np.ndarray) -> "Cylinders":
        m_f = np.broadcast_to(C.N_CYL_BANK * fuel * n_cps, p_im.shape)   # (2, n) kg/s per bank
        load = fuel / k.fuel_mcr_kg_cyc
        q_fuel = m_f * C.LHV_J_PER_KG
        eta_ig_n = (k.eta_ig_base * (1.0 - k.eta_ig_speed_q * (n_rel - k.eta_ig_speed_opt) ** 2)
                    * (1.0 - k.eta_ig_low_load * np.exp(-load / k.eta_ig_low_load_scale)))
        eta_comb_l = k.eta_comb_max - k.eta_comb_low_load * np.exp(-load / k.eta_comb_low_load_scale)
        x_wall = (k.wall_heat_frac * n_rel ** (-k.wall_heat_speed_exp)
                  * (1.0 + k.wall_heat_low_load * np.exp(-load / k.wall_heat_low_load_scale)))
        cpa_im = C.CP_AIR * (t_im - C.T_REF_K)
        return cls(k, gx, p_im, t_im, fuel, n_cps, m_f, q_fuel, eta_ig_n, eta_comb_l, x_wall, cpa_im)

    def against(self, p_em: np.ndarray) -> dict[str, np.ndarray]:
        """Flows, efficiencies, powers and temperatures with the exhaust receiver at ``p_em``."""
        k, fuel = self.k, self.fuel
        m_tr, m_sc, _ = self.gx.flows(self.p_im, p_em, self.t_im)
        air_cyc = m_tr / (C.N_CYL_BANK * self.n_cps)
        lam = air_cyc / (C.AFR_STOICH * np.maximum(fuel, 1e-7))
        eta_comb = np.maximum(self.eta_comb_l - k.eta_comb_smoke * np.maximum(k.lambda_smoke - lam, 0.0) ** 2, 0.6)
        eta_ig = self.eta_ig_n * (1.0 - k.eta_ig_lambda / np.maximum(lam, 1.0))
        q_burnt = eta_comb * self.q_fuel
        p_ig = eta_ig * q_burnt
        p_pump = (p_em - self.p_im) * self.gx.vdn                  # gas-exchange loss, W
        q_wall = self.x_wall * q_burnt
        m_gas = m_tr + self.m_f
        # cylinder energy balance: enthalpies from T_REF, fuel entering with its LHV
        h_gas = m_tr * self.cpa_im + q_burnt - (p_ig - p_pump) - q_wall
        m_ex = m_gas + m_sc
        t_cyl = C.T_REF_K + h_gas / (m_gas * C.CP_GAS)
        t_mix = C.T_REF_K + (h_gas + m_sc * self.cpa_im) / (m_ex * C.CP_GAS)
        ha = k.em_wall_ha_ref_w_k * np.maximum(m_ex / k.exhaust_flow_ref_kg_s, 0.02) ** 0.8
        g_w = -np.expm1(-ha / (m_ex * C.CP_GAS)) * m_ex * C.CP_GAS     # gas -> wall, W/K
        return dict(m_tr=m_tr, m_sc=m_sc, air_cyc=air_cyc, lam=lam, eta_comb=eta_comb, eta_ig=eta_ig,
                    q_burnt=q_burnt, p_ig=p_ig, p_pump=p_pump, q_wall=q_wall, t_cyl=t_cyl, m_ex=m_ex,
                    t_mix=t_mix, g_w=g_w)


def manifold(k: Any, cy: dict[str, np.ndarray], t_wall: np.ndarray, t_amb: np.ndarray,
             steady: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(wall temperature, gas-to-wall heat, turbine-inlet temperature) of the exhaust manifold.

    The wall is the state ``t_wall`` (or, ``steady``, its equilibrium between the gas and the
    insulated engine room).
    """
    ua = k.em_wall_ua_ins_w_k
    t_wall = (cy["g_w"] * cy["t_mix"] + ua * t_amb) / (cy["g_w"] + ua) if steady else t_wall
    q_gw = cy["g_w"] * (cy["t_mix"] - t_wall)
    return t_wall, q_gw, cy["t_mix"] - q_gw / (cy["m_ex"] * C.CP_GAS)


def back_pressure(k: Any, p_amb: np.ndarray, m_ex: np.ndarray) -> np.ndarray:
    """Pressure after the turbine: ambient plus the exhaust line's loss, quadratic in flow."""
    return p_amb + k.exhaust_dp_ref_pa * (m_ex / k.exhaust_flow_ref_kg_s) ** 2


# -- turbine -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Turbine:
    """Turbine and waste gate at this step's rotor speed and charge pressure.

    Flow law m = A p / sqrt(R T) sqrt(1 - pi^-k_t) with a mild speed effect; the waste gate
    opens with charge pressure and bypasses gas by the same law; efficiency a parabola in
    the blade-speed ratio.
    """

    area: np.ndarray
    wg_share: np.ndarray
    """Bypass flow over turbine flow."""
    k_t: float

    @classmethod
    def at(cls, k: Any, omega: np.ndarray, p_im: np.ndarray, foul_turb: np.ndarray) -> "Turbine":
        area = (k.turb_area_m2 * (1.0 - foul_turb)
                * (1.0 + k.turb_area_speed * (omega * k.turb_radius_m / k.turb_tip_speed_ref_m_s - 1.0)))
        wg = np.clip((p_im - k.wastegate_open_pa) / k.wastegate_span_pa, 0.0, 1.0)
        return cls(area, k.wastegate_area_m2 * wg * wg * (3.0 - 2.0 * wg) / area, k.turb_flow_exp)

    def flow(self, p_em: np.ndarray, t_em: np.ndarray, p_ta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flow through turbine and waste gate (same flow law), its slope in p_em, pressure ratio."""
        k_t = self.k_t
        pi_t = np.maximum(p_em / p_ta, 1.0 + 1e-9)
        pk = pi_t ** (-k_t)
        psi = np.sqrt(1.0 - pk)
        coef = self.area * (1.0 + self.wg_share) / np.sqrt(C.R_GAS * t_em)
        dpsi = 0.5 * k_t * pk / (pi_t * np.maximum(psi, 1e-4))
        return coef * p_em * psi, coef * (psi + pi_t * dpsi), pi_t

    def power(self, k: Any, omega: np.ndarray, p_em: np.ndarray, t_em: np.ndarray,
              p_ta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(total flow, flow through the wheel, shaft power, temperature after the waste-gate junction)."""
        m_out, _, pi_t = self.flow(p_em, t_em, p_ta)
        m_t = m_out / (1.0 + self.wg_share)                                  # through the turbine wheel
        expn = 1.0 - pi_t ** (-X_GAS)
        c_s = np.sqrt(2.0 * C.CP_GAS * t_em * expn)
        bsr = omega * k.turb_radius_m / np.maximum(c_s, 1.0)
        eta_t = np.maximum(k.turb_eta_max * (1.0 - k.turb_eta_bsr_q * (bsr / k.turb_bsr_opt - 1.0) ** 2), k.turb_eta_min)
        p_turb = m_t * C.CP_GAS * t_em * expn * eta_t
        return m_out, m_t, p_turb, t_em * (1.0 - expn * eta_t * m_t / m_out)


def exhaust_receiver(k: Any, h: float, gx: GasExchange, turb: Turbine, p_im: np.ndarray, t_im: np.ndarray,
                     m_f: np.ndarray, p_em_old: np.ndarray, t_em0: np.ndarray, p_ta0: np.ndarray) -> np.ndarray:
    """New exhaust pressure: p - p_old = h R T / V (m_cylinders + m_scavenge - m_turbine), implicit,
    at the new intake pressure, with the gas temperature and back pressure of the old exhaust pressure."""
    k_em = h * C.R_GAS * t_em0 / k.v_em_m3
    rho_im = p_im / (C.R_AIR * t_im)
    tr_scale = rho_im * gx.vdn
    sc_coef = k.scavenge_area_m2 * np.sqrt(2.0 * rho_im)

    def g_em(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rel = np.minimum(np.maximum(p / p_im - 1.0, -0.5), 1.0)
        m_tr = np.minimum(np.maximum(gx.ev_speed - k.eta_vol_dp * rel, 0.6), 1.0) * tr_scale
        dp = p_im - p
        r = np.sqrt(dp * dp + gx.s2)
        sq = np.sqrt(0.5 * (dp + r))
        dmsc = sc_coef * 0.5 * (1.0 + dp / r) / (2.0 * np.maximum(sq, 1.0))
        m_t, dm_t, _ = turb.flow(p, t_em0, p_ta0)
        return p - p_em_old - k_em * (m_tr + sc_coef * sq + m_f - m_t), 1.0 + k_em * (dmsc + dm_t)

    return safe_newton(g_em, p_ta0 * (1.0 + 1e-6), P_RECEIVER_MAX_PA, np.maximum(p_em_old, p_ta0 * 1.001),
                       NEWTON_ITERS, NEWTON_TOL_PA)


# -- rotor, thermal states, peak pressure, governor ----------------------------------------
def rotor_step(k: Any, h: float, omega: np.ndarray, p_turb: np.ndarray, p_tcf: np.ndarray,
               p_comp: np.ndarray) -> np.ndarray:
    """Turbocharger speed after one linearly implicit step of J w dw/dt = P_turbine - P_friction - P_compressor."""
    inertia = k.tc_inertia_kg_m2
    f_w = (p_turb - p_tcf - p_comp) / (inertia * omega)
    j_w = -(3.0 * p_comp + 2.0 * p_tcf + p_turb) / (inertia * omega**2)
    return np.maximum(omega + h * f_w / (1.0 - h * j_w), k.tc_speed_min_rad_s)


def wall_step(k: Any, h: float, t_wall: np.ndarray, q_gw: np.ndarray, q_loss: np.ndarray, g_w: np.ndarray) -> np.ndarray:
    """Manifold wall temperature after one (semi-implicit) step of its heat balance."""
    return t_wall + h * (q_gw - q_loss) / (k.em_wall_capacity_j_k + h * (g_w + k.em_wall_ua_ins_w_k))


def lag_step(value: np.ndarray, target: np.ndarray, h: float, tau: float) -> np.ndarray:
    """Exact step of a first-order lag (a thermocouple, an actuator) towards ``target``."""
    return target + (value - target) * np.exp(-h / tau)


def peak_pressure(k: Any, p_im: np.ndarray, t_im: np.ndarray, cy: dict[str, np.ndarray], fuel: np.ndarray,
                  n_rel: np.ndarray) -> np.ndarray:
    """Peak cylinder pressure: polytropic compression plus an isochoric-like rise from the fuel."""
    t_comp = (t_im + k.p_max_heat_k) * C.COMPRESSION_RATIO ** (k.p_max_poly - 1.0)
    q_ratio = cy["eta_comb"] * fuel * C.LHV_J_PER_KG / (cy["air_cyc"] * k.cv_cyl * t_comp)
    rise = k.p_max_rise * q_ratio * n_rel ** (-k.p_max_speed_exp)
    return p_im * C.COMPRESSION_RATIO**k.p_max_poly * (1.0 + rise)


def governor(k: Any, h: float, cy: dict[str, np.ndarray], p_fric: np.ndarray, p_aux: np.ndarray, n_cps: np.ndarray,
             demand_w: np.ndarray, fuel: np.ndarray, rack_limit: np.ndarray) -> np.ndarray:
    """Next fuel per cylinder per cycle: what delivers the demanded brake power, within the rack
    (``rack_limit``, kg) and boost (smoke) limits, through the fuel actuator's lag."""
    losses = (cy["p_pump"] + p_fric).sum(axis=0) + 2.0 * p_aux
    gain = (cy["eta_ig"] * cy["eta_comb"]).sum(axis=0) * C.N_CYL_BANK * n_cps * C.LHV_J_PER_KG
    limit = np.minimum(rack_limit, cy["air_cyc"].min(axis=0) / (C.AFR_STOICH * k.lambda_limit))
    cmd = np.minimum(np.maximum((demand_w + losses) / gain, 0.0), limit)
    return cmd + (fuel - cmd) * np.exp(-h / k.fuel_actuator_tau_s)
