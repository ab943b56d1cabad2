"""The helicopter side: power required by a flight condition, rotor load and the pilot's collective.

The flight profile fixes airspeed, climb rate, bank and weight; momentum theory (induced
power), blade profile drag, fuselage parasite drag and climb give the power required.
The pilot sets the collective that makes the rotor absorb that power at the nominal
rotor speed; the rotor's load torque then follows the actual collective and rotor
speed (``load``), which is what closes the NR loop.
"""

from __future__ import annotations

import numpy as np

from enginebench.datasets.turboshaft.atmosphere import KNOT, RHO_SL
from enginebench.datasets.turboshaft.params import P_REF, AirframeParams, RotorParams

G = 9.80665


def load_terms(c: np.ndarray, sigma: np.ndarray, airspeed_kn: np.ndarray, rotor: RotorParams
               ) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) with rotor load torque = n^2 a + b at rotor speed fraction n.

    The load is n^2 sigma (a0 (1 + 4.65 mu^2) + a1 c + a2 c^2) / P_REF (sum over both
    engines, per unit) with advance ratio mu = V / (n Omega R): the profile power's
    forward-flight part does not scale with n^2.
    """
    mu0 = np.asarray(airspeed_kn) * KNOT / rotor.tip_speed
    a = sigma * (rotor.a0 + c * (rotor.a1 + rotor.a2 * c)) / P_REF
    b = sigma * rotor.a0 * 4.65 * mu0 * mu0 / P_REF
    return a, b


def load(c: np.ndarray, n: np.ndarray, sigma: np.ndarray, airspeed_kn: np.ndarray, rotor: RotorParams) -> np.ndarray:
    """Rotor load torque (sum over both engines, per unit) at collective fraction ``c``."""
    a, b = load_terms(c, sigma, airspeed_kn, rotor)
    return n * n * a + b


def collective_for(q_total: np.ndarray, n: np.ndarray, sigma: np.ndarray, airspeed_kn: np.ndarray,
                   rotor: RotorParams) -> np.ndarray:
    """The collective fraction at which ``load`` equals ``q_total`` (inverse of ``load``, unclipped)."""
    a_free, b = load_terms(0.0, sigma, airspeed_kn, rotor)
    rhs = (q_total - b) / (n * n) - a_free  # = sigma (a1 c + a2 c^2) / P_REF
    rhs = rhs * P_REF / sigma
    disc = np.maximum(rotor.a1 * rotor.a1 + 4.0 * rotor.a2 * rhs, 0.0)
    return (-rotor.a1 + np.sqrt(disc)) / (2.0 * rotor.a2)


def power_required(airspeed_kn: np.ndarray, climb_ms: np.ndarray, bank_deg: np.ndarray, mass_kg: np.ndarray,
                   rho: np.ndarray, in_ground_effect: np.ndarray, rotor: RotorParams,
                   air: AirframeParams) -> np.ndarray:
    """Shaft power required from both engines together, as per-unit torque at 100 % NR."""
    v = np.asarray(airspeed_kn) * KNOT
    load_factor = 1.0 / np.cos(np.radians(bank_deg))
    thrust = mass_kg * G * load_factor
    v_hover = np.sqrt(thrust / (2.0 * rho * air.disk_area))
    vbar2 = (v / v_hover) ** 2
    induced_ratio = np.sqrt(0.5 * (np.sqrt(vbar2 * vbar2 + 4.0) - vbar2))  # momentum theory, level flight
    ge = 1.0 - (1.0 - air.ground_effect) * in_ground_effect
    p_induced = air.k_induced * thrust * v_hover * induced_ratio * ge
    mu = v / rotor.tip_speed
    p_profile = air.profile_kw * 1e3 * (rho / RHO_SL) * (1.0 + 4.65 * mu * mu)
    p_parasite = 0.5 * rho * air.flat_plate * v**3
    climb = np.asarray(climb_ms, dtype=np.float64)
    p_climb = mass_kg * G * np.where(climb > 0, climb, air.descent_factor * climb)
    p_shaft = (p_induced + p_profile + p_parasite + p_climb) / air.transmission + air.accessories_kw * 1e3
    return p_shaft / (P_REF * 1e3)
