"""Physical sanity of the marine-diesel "true engine" (the generator's simulator)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.engine import INPUT_NAMES, lane_plan, run_lanes, simulate_rows, steady_state
from enginebench.datasets.marine_diesel.engine_config import engine_for_seed, fuel_to_rack, rack_to_fuel
from enginebench.datasets.marine_diesel.profile import make_profile
from enginebench.datasets.marine_diesel.sensors import first_order_lag
from enginebench.datasets.marine_diesel.thermal import lt_after_cooler_k

CFG = engine_for_seed(0)


def _constant_inputs(n: int, speed: float, power: np.ndarray) -> dict[str, np.ndarray]:
    full = lambda v: np.full((1, n), float(v))  # noqa: E731
    return {"speed_rpm": full(speed), "power_demand_w": np.asarray(power, dtype=float).reshape(1, n),
            "t_amb_k": full(303.15), "p_amb_pa": full(1.0e5), "t_coolant_k": full(308.15),
            "foul_comp": full(0.0), "foul_turb": full(0.0), "foul_ic": full(0.0)}


def test_energy_balance_closes_at_steady_state():
    """Fuel power = brake power + exhaust enthalpy + intercooler + wall + friction + losses.

    Control volume: the engine with its turbochargers and intercoolers; enthalpies from
    T_REF; the exhaust leaves at the turbine outlet, the air enters at the compressor.
    Tolerance 0.1 % of the fuel power (the receivers are solved to 1 Pa).
    """
    speed = np.array([450.0, 631.0, 800.0, 1000.0, 1031.0, 700.0])
    power = np.array([0.03, 0.25, 0.4, 1.0, 1.1, 0.12]) * C.P_MCR_W
    st = steady_state(speed, power, CFG, t_amb_k=305.0)
    fuel = st["fuel_flow_kg_s"] * C.LHV_J_PER_KG
    exhaust = (st["m_turb_kg_s"] * C.CP_GAS * (st["t_turb_out_k"] - C.T_REF_K)).sum(axis=0)
    air_in = (st["m_air_kg_s"] * C.CP_AIR * (305.0 - C.T_REF_K)).sum(axis=0)
    out = (st["brake_power_w"] + exhaust - air_in + st["q_intercooler_w"].sum(axis=0) + st["wall_heat_w"]
           + st["friction_power_w"] + st["aux_power_w"] + st["tc_friction_w"] + st["manifold_loss_w"]
           + st["unburnt_w"])
    np.testing.assert_allclose(out, fuel, rtol=1e-3)
    # at steady state the governor delivers the demanded power, the turbocharger is balanced
    np.testing.assert_allclose(st["brake_power_w"], power, rtol=1e-3)
    np.testing.assert_allclose(st["p_turb_w"].sum(axis=0),
                               st["p_comp_w"].sum(axis=0) + st["tc_friction_w"], rtol=1e-3)
    # the shares are those of a medium-speed diesel
    share = st["brake_power_w"] / fuel
    assert np.all(share[1:5] > 0.36) and np.all(share[1:5] < 0.46)


def test_fat_points_are_physically_plausible():
    speed = np.array(C.FAT_SPEEDS_RPM)
    st = steady_state(speed, C.P_MCR_W * (speed / C.N_MCR_RPM) ** 3, CFG)
    p_im = st["p_im_pa"].mean(axis=0) / C.BAR
    t_in = st["t_turb_in_k"].mean(axis=0) - C.KELVIN
    t_out = st["t_turb_out_k"].mean(axis=0) - C.KELVIN
    sfc = st["fuel_flow_kg_s"] / st["brake_power_w"] * 3.6e9
    assert np.all(np.diff(p_im) > 0) and 1.0 < p_im[0] and p_im[-1] < 4.8
    assert np.all((t_in > 450.0) & (t_in < 650.0)) and np.all((t_out > 330.0) & (t_out < 600.0))
    assert np.all((sfc > 190.0) & (sfc < 235.0))
    assert np.all(st["lambda_trapped"] > 1.6)
    assert np.all(st["p_em_pa"] < st["p_im_pa"])            # positive scavenging on the propeller law


@pytest.mark.parametrize("speed", [600.0, 800.0, 1000.0])
def test_exhaust_temperatures_rise_with_load_at_fixed_speed(speed):
    """From 5 % load to the propeller law at this speed.

    The turbine-inlet temperature rises throughout. The outlet rises at low and medium
    load and then flattens (the growing expansion ratio), as on real constant-speed
    engines: it must rise up to 60 % of the propeller load and never fall below 99 %
    of its running maximum.
    """
    load = np.linspace(0.05, (speed / C.N_MCR_RPM) ** 3, 9)
    st = steady_state(np.full(load.size, speed), load * C.P_MCR_W, CFG)
    t_in = st["t_turb_in_k"].mean(axis=0)
    t_out = st["t_turb_out_k"].mean(axis=0)
    assert np.all(np.diff(t_in) > 0.0)
    mid = load <= 0.6 * load[-1]
    assert np.all(np.diff(t_out[mid]) > 0.0)
    assert np.all(t_out >= 0.99 * np.maximum.accumulate(t_out))
    assert t_in[-1] - t_in[0] > 100.0


def test_turbine_inlet_hotter_than_outlet_over_a_voyage():
    prof = make_profile(6.0, np.random.default_rng(7), voyage_hours=(3.0, 4.0))
    inputs = {"speed_rpm": prof.speed_rpm, "power_demand_w": prof.power_demand_w, "t_amb_k": prof.engine_room_k,
              "p_amb_pa": prof.p_amb_pa, "t_coolant_k": lt_after_cooler_k(prof), "foul_comp": prof.foul_comp,
              "foul_turb": prof.foul_turb, "foul_ic": prof.foul_ic}
    out = simulate_rows(inputs, prof.voyage_starts, prof.voyage_stops, CFG, lane_len=400)
    assert np.all(np.isfinite(out["t_turb_in_k"])) and np.all(np.isfinite(out["tc_speed_rpm"]))
    assert np.all(out["t_turb_in_k"] > out["t_turb_out_k"] + 1.0)          # gas, both banks, every sample
    # (the cylinder-outlet gas may be cooler than the turbine gas for a while after a load
    # drop: the hot manifold wall then heats the gas; on average it is hotter)
    assert np.mean(out["t_cyl_out_k"] - out["t_turb_in_k"]) > 0.0
    # banks A and B are similar but not identical
    diff = np.abs(out["t_turb_in_k"][0] - out["t_turb_in_k"][1])
    assert 0.0 < np.median(diff) < 25.0
    assert out["t_turb_in_k"].min() > 350.0 and out["t_turb_in_k"].max() < 1000.0


def test_thermocouple_lag_is_visible_in_a_load_step():
    """After a 30 -> 45 % load step the thermocouples lag the gas; a first-order fit of
    (gas -> thermocouple) over the step recovers the configured time constants."""
    n = 300
    power = np.full(n, 0.30 * C.P_MCR_W)
    power[100:] = 0.45 * C.P_MCR_W
    out = run_lanes(_constant_inputs(n, 800.0, power), CFG)
    for gas_key, meas_key, taus in (("t_turb_in_k", "tc_meas_in_k", CFG.tau_tc_in_s),
                                    ("t_turb_out_k", "tc_meas_out_k", CFG.tau_tc_out_s)):
        for bank in (0, 1):
            gas, meas = out[gas_key][bank, 0], out[meas_key][bank, 0]
            assert abs(gas[99] - meas[99]) < 0.01                           # steady before the step
            assert abs(gas[100] - meas[100]) > 0.5 * abs(gas[-1] - gas[99])  # lagging right after it
            fit = minimize_scalar(lambda tau: np.sum((first_order_lag(gas, tau, 3.0) - meas) ** 2),
                                  bounds=(1.0, 200.0), method="bounded")
            assert fit.x == pytest.approx(taus[bank], rel=0.1)
    # the measured step: 63 % reached after about the time constant (gas step is fast)
    meas = out["tc_meas_in_k"][0, 0]
    frac = (meas[100:] - meas[99]) / (meas[-1] - meas[99])
    t63 = (np.argmax(frac >= 1.0 - np.exp(-1.0)) + 1) * 3.0
    assert 0.2 * CFG.tau_tc_in_s[0] < t63 < 1.5 * CFG.tau_tc_in_s[0]


def test_big_load_step_hits_the_boost_limiter_and_overshoots():
    """Turbocharger lag: during a fast 20 -> 50 % step the governor is boost-limited,
    the air excess drops to the limit and the turbine-inlet gas overshoots its new level."""
    n = 200
    power = np.full(n, 0.2 * C.P_MCR_W)
    power[100:] = 0.5 * C.P_MCR_W
    out = run_lanes(_constant_inputs(n, 800.0, power), CFG)
    lam = out["lambda_trapped"][0]
    assert lam[101] == pytest.approx(CFG.lambda_limit, abs=0.08)
    assert out["brake_power_w"][0, 101] < 0.9 * 0.5 * C.P_MCR_W
    gas = out["t_turb_in_k"][0, 0]
    assert gas[100:110].max() > gas[-1] + 30.0
    assert out["brake_power_w"][0, -1] == pytest.approx(0.5 * C.P_MCR_W, rel=1e-3)


def test_rack_law_round_trip():
    rack = np.array([10.0, 40.0, 85.0, 100.0])
    speed = np.array([500.0, 700.0, 1000.0, 1030.0])
    np.testing.assert_allclose(fuel_to_rack(CFG, rack_to_fuel(CFG, rack, speed), speed), rack)


def test_lane_plan_covers_every_row_once():
    index, keep = lane_plan(np.array([0, 25, 40]), np.array([25, 40, 107]), lane_len=10, warmup=4)
    kept = index[:, 4:][keep]
    assert sorted(kept.tolist()) == list(range(107))
    assert index[0, :4].tolist() == [0, 0, 0, 0]        # a run's first lane settles at its first row
    assert set(INPUT_NAMES) >= {"speed_rpm", "power_demand_w"}
