"""Thermal blocks of the true engine: cooling water, lube oil, bearings, splash oil, fuel.

In the pattern of hil-diesel sec. 2.5 (the cooling block integrates heat flows with a
thermal capacity; thermostats hold set-points): each temperature is a steady value set
by the heat flows of the engine loop and by a thermostat, passed through a first-order
lag for the thermal mass (``sensors.first_order_lag``, run by run, so it is linear and
vectorised). Heat flows come from ``engine.simulate_rows``:

* HT (high-temperature) circuit, engine-driven pump: jacket heat (75 % of the wall heat)
  and 30 % of the friction heat; thermostat at the engine inlet ("after cooler");
* lube oil, engine-driven pump: piston cooling (25 % of the wall heat), 70 % of the
  friction heat and the turbocharger bearings; thermostat before the engine;
* LT (low-temperature) circuit, electric pump, in series through the intercooler, the
  oil cooler and the HT cooler; its "after cooler" temperature follows seawater (central
  cooler) with a minimum set-point;
* main bearings 1-7 and crankcase splash oil in compartments 1-6: lube-oil temperature
  plus a rise growing with speed and load (bearings 4 and 5, mid-engine, carry most load,
  cf. egt-hybrid sec. 5.2.4);
* fuel temperature: day tank near engine-room temperature, warmed by return fuel.

Each voyage starts from a pre-heated engine (HT water 60 degC, oil 45 degC), so the first
hour of a voyage shows the warm-up the logged data of a real vessel would show.
"""

from __future__ import annotations

import numpy as np

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.profile import Profile
from enginebench.datasets.marine_diesel.sensors import first_order_lag

HT_SETPOINT_C = 74.0
HT_DROOP_C = 3.0
HT_FLOW_MCR_KG_S = 30.0
LT_SETPOINT_MIN_C = 32.0
LT_APPROACH_C = 4.0
LT_LOAD_RISE_C = 6.0
LT_FLOW_KG_S = 40.0
OIL_SETPOINT_C = 60.0
OIL_DROOP_C = 2.0
OIL_FLOW_MCR_KG_S = 22.0
HT_ABOVE_LT_MIN_C = 6.0
"""The HT cooler cannot cool the HT water below LT water + this, K."""
OIL_ABOVE_LT_MIN_C = 8.0
"""The oil cooler cannot cool the oil below LT water + this, K."""
PREHEAT_HT_C = 60.0
PREHEAT_OIL_C = 45.0
HEAT_HT_MCR_W = 0.9e6
"""Scale of the HT heat flow for the thermostat droop, W."""
HEAT_OIL_MCR_W = 0.65e6
BEARING_RISE_C = (11.0, 13.0, 14.0, 17.0, 18.0, 14.0, 12.0)
"""Bearing temperature rise above the oil inlet at MCR, main bearings 1-7, K."""
SPLASH_RISE_C = (4.0, 5.0, 6.0, 6.0, 5.0, 4.0)
"""Splash-oil temperature rise above the oil outlet at MCR, compartments 1-6, K."""
SPLASH_BASE_LOAD = 0.3
"""Share of the splash-oil rise present at zero load (windage, piston cooling)."""
SPLASH_OFFSET_C = -2.0
"""Crankcase splash oil relative to the oil outlet at zero rise, K."""
SCATTER_C = 0.5
"""Standard deviation of the per-sensor mounting offsets of bearings and splash oil, K."""
FUEL_BASE_C = 38.0
"""Fuel temperature with the engine room at FUEL_ROOM_REF_C and no load, degC."""
FUEL_ROOM_REF_C = 30.0
FUEL_ROOM_GAIN = 0.4
"""Fuel temperature change per K of engine-room air."""
FUEL_LOAD_RISE_C = 5.0
"""Fuel warming by return fuel at MCR, K."""
TAU_S = {
    "ht_in": 300.0, "ht_out": 600.0, "lt_in": 300.0, "lt_out": 300.0, "oil_in": 300.0,
    "oil_out": 400.0, "bearing": 900.0, "splash": 1200.0, "fuel": 1800.0, "comp_in": 60.0,
    "comp_out": 10.0, "charge_air": 20.0,
}
"""Thermal time constants of the blocks and sensor pockets, s."""


def lt_after_cooler_k(profile: Profile) -> np.ndarray:
    """LT water at the intercooler inlet, K: seawater plus a load-dependent approach.

    Computed from the demanded load (before the engine loop, which needs it as input).
    """
    load = np.clip(profile.power_demand_w / C.P_MCR_W, 0.0, 1.2)
    steady = np.maximum(profile.seawater_k + LT_APPROACH_C + LT_LOAD_RISE_C * load, LT_SETPOINT_MIN_C + C.KELVIN)
    return first_order_lag(steady, TAU_S["lt_in"], profile.dt, profile.voyage_starts)


def thermal_blocks(profile: Profile, eng: dict[str, np.ndarray], t_lt_in_k: np.ndarray,
                   rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Temperatures (degC) of the cooling, lubrication, bearing, splash-oil and fuel blocks."""
    dt, starts = profile.dt, profile.voyage_starts
    n_rel = np.maximum(profile.speed_rpm / C.N_MCR_RPM, 0.3)
    load = np.clip(eng["brake_power_w"] / C.P_MCR_W, 0.0, 1.2)
    q_ht = 0.75 * eng["wall_heat_w"] + 0.3 * eng["friction_power_w"]
    q_oil = 0.25 * eng["wall_heat_w"] + 0.7 * eng["friction_power_w"] + eng["tc_friction_w"]
    q_ic = np.maximum(eng["q_intercooler_w"].sum(axis=0), 0.0)
    n_runs = len(starts)

    def lag(x, key, preheat=None):
        y0 = None if preheat is None else np.full(n_runs, preheat)
        return first_order_lag(x, TAU_S[key], dt, starts, y0)

    out: dict[str, np.ndarray] = {}
    lt_in_c = t_lt_in_k - C.KELVIN
    ht_in = lag(np.maximum(HT_SETPOINT_C + HT_DROOP_C * q_ht / HEAT_HT_MCR_W, lt_in_c + HT_ABOVE_LT_MIN_C),
                "ht_in", PREHEAT_HT_C)
    ht_out = lag(ht_in + q_ht / (HT_FLOW_MCR_KG_S * n_rel * C.CP_WATER), "ht_out", PREHEAT_HT_C)
    oil_in = lag(np.maximum(OIL_SETPOINT_C + OIL_DROOP_C * q_oil / HEAT_OIL_MCR_W, lt_in_c + OIL_ABOVE_LT_MIN_C),
                 "oil_in", PREHEAT_OIL_C)
    oil_out = lag(oil_in + q_oil / (OIL_FLOW_MCR_KG_S * n_rel * C.CP_OIL), "oil_out", PREHEAT_OIL_C)
    lt_out = lag(lt_in_c + (q_ic + q_oil + q_ht) / (LT_FLOW_KG_S * C.CP_WATER), "lt_out")
    out.update(t_ht_water_after_cooler=ht_in, t_ht_water_before_cooler=ht_out,
               t_lube_oil_before_engine=oil_in, t_lube_oil_after_engine=oil_out,
               t_lt_water_after_cooler=lt_in_c, t_lt_water_before_cooler=lt_out)
    duty = 0.5 * (profile.speed_rpm / C.N_MCR_RPM) ** 2 + 0.5 * load   # bearing heating: speed and load
    for i, rise in enumerate(BEARING_RISE_C, start=1):
        offset = rng.normal(0.0, SCATTER_C)
        out[f"t_bearing_{i}"] = lag(oil_in + offset + rise * duty, "bearing", PREHEAT_OIL_C)
    for j, rise in enumerate(SPLASH_RISE_C, start=1):
        offset = rng.normal(0.0, SCATTER_C)
        share = SPLASH_BASE_LOAD + (1.0 - SPLASH_BASE_LOAD) * load
        out[f"t_splash_oil_{j}"] = lag(oil_out + offset + rise * share + SPLASH_OFFSET_C, "splash", PREHEAT_OIL_C)
    er_c = profile.engine_room_k - C.KELVIN
    out["t_fuel"] = lag(FUEL_BASE_C + FUEL_ROOM_GAIN * (er_c - FUEL_ROOM_REF_C) + FUEL_LOAD_RISE_C * load, "fuel")
    return out
