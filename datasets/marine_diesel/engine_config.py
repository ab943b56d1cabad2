"""Constants of the marine engine's "true engine" (``engine.py``): maps, volumes, efficiencies,
sensor lags, the integration step; the seed-dependent scatter between the two banks; the rack law."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from enginebench.datasets.marine_diesel import constants as C


@dataclass(frozen=True)
class EngineConfig:
    """Constants of the true engine. Tuples are per bank (A, B).

    Units are SI and in the names (``_m``, ``_m2``, ``_kg_s``, ``_pa``, ``_w_k``, ``_s``...);
    names without a unit are dimensionless (efficiencies, exponents, fractions, and
    ``*_scale`` loads as fractions of the MCR fuel per cycle). Values were chosen so
    that the shop test (``fat.simulator_fat``) resembles the egt-hybrid paper's Table 4 with
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
