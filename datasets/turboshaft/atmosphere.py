"""Ambient and intake conditions of the synthetic turboshaft flights.

The International Standard Atmosphere (troposphere) gives static pressure and
temperature from pressure altitude; a per-flight temperature offset (ISA + dT) and
sea-level pressure offset make each flight's day different. The engine intake adds
the ram rise of a moving helicopter: total temperature and partially recovered total
pressure. Everything is vectorised over arbitrary array shapes.
"""

from __future__ import annotations

import numpy as np

P_SL = 101.325
"""ISA sea-level pressure, kPa."""
T_SL = 288.15
"""ISA sea-level temperature, K."""
LAPSE = 0.0065
"""ISA tropospheric lapse rate, K/m."""
G0 = 9.80665
R_AIR = 287.053
"""Specific gas constant of dry air, J/(kg K)."""
CP_AIR = 1004.5
RHO_SL = P_SL * 1e3 / (R_AIR * T_SL)
KNOT = 0.514444
"""m/s per knot."""
_EXPONENT = G0 / (R_AIR * LAPSE)


def isa(altitude_m: np.ndarray, dT: np.ndarray | float = 0.0, dp_kpa: np.ndarray | float = 0.0
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Static pressure (kPa), temperature (K) and density (kg/m^3) at ``altitude_m``.

    ``altitude_m`` is pressure altitude; ``dT`` shifts the temperature (ISA + dT day)
    and ``dp_kpa`` the sea-level pressure (weather), scaling the whole column.
    """
    h = np.asarray(altitude_m, dtype=np.float64)
    ratio = 1.0 - LAPSE * h / T_SL
    p = (P_SL + np.asarray(dp_kpa, dtype=np.float64)) * ratio**_EXPONENT
    t = T_SL - LAPSE * h + np.asarray(dT, dtype=np.float64)
    rho = p * 1e3 / (R_AIR * t)
    return p, t, rho


def intake(p_kpa: np.ndarray, t_k: np.ndarray, rho: np.ndarray, airspeed_kn: np.ndarray,
           recovery: float = 0.8, heating_k: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Engine intake pressure P0 (kPa) and temperature T1 (K) at a given airspeed.

    The intake recovers a fraction ``recovery`` of the dynamic pressure and sees the
    full stagnation temperature rise V^2 / (2 cp) plus a small installation heating.
    """
    v = np.asarray(airspeed_kn, dtype=np.float64) * KNOT
    p0 = p_kpa + recovery * 0.5 * rho * v * v * 1e-3
    t1 = t_k + v * v / (2.0 * CP_AIR) + heating_k
    return p0, t1
