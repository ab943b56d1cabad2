"""``generate``: the synthetic ``marine-diesel`` data set (the egt-hybrid paper's case, labelled synthetic).

Pipeline: operational profile (``profile``) -> true engine, batched over lanes of the
voyages (``engine.simulate_rows``) -> thermal blocks (``thermal``) -> sensors
(thermocouple lags inside the engine loop, then noise and logger resolution,
``sensors``) -> the rows the logger kept, cut into segments at logging gaps.

The channels are the ~45 of the egt-hybrid paper's Table 1 (names ours, units in the schema).
Roles: run-time measurements are ``input``; the two targets, the bank-averaged exhaust
temperatures at turbine inlet and outlet (egt-hybrid Table 3, eq. 6: the mean of the two
per-bank thermocouples), are ``output``; the per-bank exhaust temperatures (before and
after the turbine, and the cylinder-outlet averages) are ``internal``: they are the
targets' components, so using them as inputs would leak the answer.

Pressures are absolute (bar abs) except the peak cylinder pressure (bar).

The meta names the physical model (``marine-diesel-pm``) and its calibration,
``pm_calibration = "simulator"``: the PM is calibrated on the factory-test points of
this random seed's true engine (``fat.simulator_fat``), as the egt-hybrid paper's PM was calibrated on its
own engine's FAT; ``MarineDieselPM.for_dataset(meta)`` reads it.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.engine import simulate_rows
from enginebench.datasets.marine_diesel.engine_config import STREAM_ENGINE, EngineConfig, engine_for_seed, fuel_to_rack
from enginebench.datasets.marine_diesel.pm import PM_NAME
from enginebench.datasets.marine_diesel.profile import Profile, make_profile
from enginebench.datasets.marine_diesel.sensors import SensorSpec, first_order_lag
from enginebench.datasets.marine_diesel.thermal import TAU_S, lt_after_cooler_k, thermal_blocks
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import DataError

GENERATOR_VERSION = "1.0"
NAME = "marine-diesel"
SIZES = {"small": (C.SMALL_HOURS, (14.0, 30.0)), "full": (C.FULL_HOURS, (12.0, 60.0))}
"""size -> (logged hours, range of voyage durations in hours)."""
MIN_SEGMENT_ROWS = 100
"""Segments shorter than this (5 min) are dropped."""
TRAIN_SHARE = 2.0 / 3.0
"""Published split: the earliest voyages holding this share of the rows train, the rest test."""
STREAM_PROFILE, STREAM_THERMAL, STREAM_SENSORS = 1, 4, 3
"""Random streams: ``default_rng([seed, stream])`` (engine: ``engine.STREAM_ENGINE``)."""

T_INLET = "t_exhaust_turbine_inlet"
T_OUTLET = "t_exhaust_turbine_outlet"

_T = SensorSpec(0.2, 0.1)
_EXH = SensorSpec(1.0, 0.5)
CHANNELS: tuple[tuple[str, str, str, SensorSpec | None], ...] = (
    ("engine_speed", "input", "rpm", SensorSpec(0.5, 0.1)),
    ("engine_speed_ref", "input", "rpm", SensorSpec(0.0, 0.1)),
    ("shaft_torque", "input", "kN m", SensorSpec(0.2, 0.1, 0.005)),
    ("fuel_flow", "input", "kg/s", SensorSpec(0.0005, 0.0001, 0.01)),
    ("fuel_rack", "input", "%", SensorSpec(0.2, 0.1)),
    ("tc_speed_a", "input", "rpm", SensorSpec(30.0, 10.0)),
    ("tc_speed_b", "input", "rpm", SensorSpec(30.0, 10.0)),
    ("power_margin", "input", "%", SensorSpec(0.2, 0.1)),
    ("p_charge_air", "input", "bar abs", SensorSpec(0.01, 0.01)),
    ("p_max", "input", "bar", SensorSpec(1.5, 0.5)),
    ("p_exhaust_receiver", "input", "bar abs", SensorSpec(0.01, 0.01)),
    ("sfc", "input", "g/kWh", None),
    ("t_charge_air", "input", "degC", SensorSpec(0.3, 0.1)),
    *((f"t_bearing_{i}", "input", "degC", _T) for i in range(1, 8)),
    ("t_fuel", "input", "degC", _T),
    ("t_ht_water_after_cooler", "input", "degC", _T),
    ("t_ht_water_before_cooler", "input", "degC", _T),
    ("t_lube_oil_before_engine", "input", "degC", _T),
    ("t_lube_oil_after_engine", "input", "degC", _T),
    ("t_lt_water_after_cooler", "input", "degC", _T),
    ("t_lt_water_before_cooler", "input", "degC", _T),
    *((f"t_splash_oil_{j}", "input", "degC", _T) for j in range(1, 7)),
    ("t_air_after_compressor_a", "input", "degC", SensorSpec(0.5, 0.1)),
    ("t_air_after_compressor_b", "input", "degC", SensorSpec(0.5, 0.1)),
    ("t_air_before_compressor_a", "input", "degC", _T),
    ("t_air_before_compressor_b", "input", "degC", _T),
    ("t_exhaust_cylinders_a", "internal", "degC", SensorSpec(1.5, 1.0)),
    ("t_exhaust_cylinders_b", "internal", "degC", SensorSpec(1.5, 1.0)),
    ("t_exhaust_before_turbine_a", "internal", "degC", _EXH),
    ("t_exhaust_before_turbine_b", "internal", "degC", _EXH),
    ("t_exhaust_after_turbine_a", "internal", "degC", _EXH),
    ("t_exhaust_after_turbine_b", "internal", "degC", _EXH),
    (T_INLET, "output", "degC", None),
    (T_OUTLET, "output", "degC", None),
)
"""(name, role, unit, sensor) of every channel, in schema order; ``None``: derived from others."""

SFC_RANGE = (150.0, 999.0)
"""The logger's sfc display range, g/kWh (it is fuel flow over power: huge near idle)."""
COMPRESSOR_INLET_OFFSET_K = (0.8, -0.3)
"""Engine-room air at the A and B compressor inlets relative to the room average, K."""


def schema() -> Schema:
    """Columns, roles and units of the data set."""
    return Schema(tuple(Column(n, r, u) for n, r, u, _ in CHANNELS))


ENVELOPE_OVERLOAD = 1.1
"""Highest load of the engine envelope, fraction of MCR (the 110 % FAT point)."""
ENVELOPE_SPEED_RPM = 1031.0
ENVELOPE_EXP = 1.5
"""The envelope falls as (speed / ENVELOPE_SPEED_RPM)^ENVELOPE_EXP below full speed."""


def power_envelope_w(speed_rpm: np.ndarray) -> np.ndarray:
    """Highest brake power the governor allows at a speed, W (for the power-margin channel)."""
    rel = np.clip(np.asarray(speed_rpm) / ENVELOPE_SPEED_RPM, 0.0, 1.0)
    return ENVELOPE_OVERLOAD * C.P_MCR_W * rel**ENVELOPE_EXP


def _true_channels(prof: Profile, eng: dict, therm: dict, cfg: EngineConfig) -> dict[str, np.ndarray]:
    """Noise-free channel values (the thermocouples already lagged) over all rows."""
    dt, starts = prof.dt, prof.voyage_starts
    omega_prop = np.maximum(prof.speed_rpm, 1.0) * C.RPM_TO_RAD_S / C.GEAR_RATIO
    room_c = prof.engine_room_k - C.KELVIN
    out = {
        "engine_speed": prof.speed_rpm,
        "engine_speed_ref": prof.speed_ref_rpm,
        "shaft_torque": eng["brake_power_w"] * C.ETA_GEARBOX / omega_prop / 1e3,
        "fuel_flow": eng["fuel_flow_kg_s"],
        "fuel_rack": fuel_to_rack(cfg, eng["fuel_kg_cyc"], prof.speed_rpm),
        "tc_speed_a": eng["tc_speed_rpm"][0],
        "tc_speed_b": eng["tc_speed_rpm"][1],
        "power_margin": 100.0 * (1.0 - eng["brake_power_w"] / power_envelope_w(prof.speed_rpm)),
        "p_charge_air": eng["p_im_pa"].mean(axis=0) / C.BAR,
        "p_max": eng["p_max_pa"].mean(axis=0) / C.BAR,
        "p_exhaust_receiver": eng["p_em_pa"].mean(axis=0) / C.BAR,
        "t_charge_air": first_order_lag(eng["t_im_k"].mean(axis=0) - C.KELVIN, TAU_S["charge_air"], dt, starts),
        **therm,
    }
    for b, bank in enumerate("ab"):
        out[f"t_air_after_compressor_{bank}"] = first_order_lag(
            eng["t_comp_out_k"][b] - C.KELVIN, TAU_S["comp_out"], dt, starts)
        out[f"t_air_before_compressor_{bank}"] = first_order_lag(
            room_c + COMPRESSOR_INLET_OFFSET_K[b], TAU_S["comp_in"], dt, starts)
        out[f"t_exhaust_cylinders_{bank}"] = eng["tc_meas_cyl_k"][b] - C.KELVIN
        out[f"t_exhaust_before_turbine_{bank}"] = eng["tc_meas_in_k"][b] - C.KELVIN
        out[f"t_exhaust_after_turbine_{bank}"] = eng["tc_meas_out_k"][b] - C.KELVIN
    return out


def _segments(prof: Profile) -> tuple[np.ndarray, np.ndarray]:
    """Segment id per row ('' where not kept): logged runs within a voyage, long enough."""
    n = len(prof)
    new = np.ones(n, dtype=bool)
    new[1:] = (prof.voyage[1:] != prof.voyage[:-1]) | (prof.logged[1:] != prof.logged[:-1])
    run = np.cumsum(new) - 1
    run_len = np.bincount(run)
    keep = prof.logged & (run_len[run] >= MIN_SEGMENT_ROWS)
    ids = np.full(n, "", dtype=object)
    for v in np.unique(prof.voyage[keep]):
        sel = keep & (prof.voyage == v)
        runs = run[sel]
        _, local = np.unique(runs, return_inverse=True)
        ids[sel] = np.array([f"V{v + 1:03d}-S{k + 1:02d}" for k in range(local.max() + 1)], dtype=object)[local]
    return ids, keep


def _published_split(seg: np.ndarray, voyage: np.ndarray, manoeuvre: np.ndarray) -> dict[str, list[str]]:
    """Temporal split at a voyage boundary: earlier voyages train, later test, both modes on both sides."""
    table = pd.DataFrame({"seg": seg, "voyage": voyage, "man": manoeuvre})
    per_seg = table.groupby("seg", sort=False).agg(voyage=("voyage", "first"), rows=("voyage", "size"))
    per_voyage = per_seg.groupby("voyage", sort=True)["rows"].sum()
    cum = per_voyage.cumsum().to_numpy() / per_voyage.sum()
    cut = int(np.clip(np.searchsorted(cum, TRAIN_SHARE) + 1, 1, max(len(per_voyage) - 1, 1)))
    train_v = set(per_voyage.index[:cut].tolist())
    is_train = per_seg["voyage"].isin(train_v)
    split = {"train": per_seg.index[is_train].tolist(), "test": per_seg.index[~is_train].tolist()}
    for part, members in split.items():
        modes = set(table["man"][table["seg"].isin(members)].unique().tolist())
        if not members or modes != {True, False}:
            raise DataError(f"{NAME}: the published {part} part lacks a mode (has {sorted(modes)}); "
                            "use a larger size or another seed")
    return split


def generate(size: str = "small", seed: int = 0, progress: Callable[[float], None] | None = None) -> Dataset:
    """The synthetic ``marine-diesel`` data set of ``size`` ("small": 72 h, "full": 3347 h)."""
    if size not in SIZES:
        raise DataError(f"{NAME}: unknown size {size!r}; use one of {', '.join(SIZES)}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise DataError(f"{NAME}: seed must be a non-negative integer, got {seed!r}")
    report = progress or (lambda fraction: None)
    hours, voyage_hours = SIZES[size]
    prof = make_profile(hours, np.random.default_rng([seed, STREAM_PROFILE]), voyage_hours=voyage_hours)
    cfg = engine_for_seed(seed)
    report(0.05)
    t_lt = lt_after_cooler_k(prof)
    inputs = {
        "speed_rpm": prof.speed_rpm, "power_demand_w": prof.power_demand_w, "t_amb_k": prof.engine_room_k,
        "p_amb_pa": prof.p_amb_pa, "t_coolant_k": t_lt, "foul_comp": prof.foul_comp,
        "foul_turb": prof.foul_turb, "foul_ic": prof.foul_ic,
    }
    lane_len = int(np.clip(len(prof) // 256, 200, 1200))
    eng = simulate_rows(inputs, prof.voyage_starts, prof.voyage_stops, cfg, lane_len=lane_len,
                        progress=lambda f: report(0.05 + 0.8 * f))
    therm = thermal_blocks(prof, eng, t_lt, np.random.default_rng([seed, STREAM_THERMAL]))
    true = _true_channels(prof, eng, therm, cfg)
    report(0.9)

    del eng, therm, inputs
    seg, keep = _segments(prof)
    rng = np.random.default_rng([seed, STREAM_SENSORS])
    data: dict[str, np.ndarray] = {SEGMENT: seg[keep].astype(str), TIME: prof.time_s[keep]}
    for name, _, _, sensor in CHANNELS:
        if sensor is not None:
            data[name] = sensor.measure(true.pop(name)[keep], rng)
    del true
    power_meas = data["shaft_torque"] * 1e3 * data["engine_speed"] * C.RPM_TO_RAD_S / (C.GEAR_RATIO * C.ETA_GEARBOX)
    with np.errstate(divide="ignore", invalid="ignore"):
        sfc = data["fuel_flow"] / np.maximum(power_meas, 1.0) * 3.6e9
    data["sfc"] = np.round(np.clip(sfc, *SFC_RANGE), 1)
    data[T_INLET] = 0.5 * (data["t_exhaust_before_turbine_a"] + data["t_exhaust_before_turbine_b"])
    data[T_OUTLET] = 0.5 * (data["t_exhaust_after_turbine_a"] + data["t_exhaust_after_turbine_b"])
    sch = schema()
    frame = pd.DataFrame({k: data.pop(k) for k in (SEGMENT, TIME, *sch.names())}, copy=False)
    report(0.97)

    seg_kept = seg[keep]
    split = _published_split(seg_kept, prof.voyage[keep], prof.manoeuvre[keep])
    man = pd.Series(prof.manoeuvre[keep]).groupby(seg_kept).mean()
    meta = {
        "provenance": f"synthetic: enginebench marine-diesel generator v{GENERATOR_VERSION}, seed {seed}",
        "license": "CC0-1.0 (synthetic data generated by enginebench; no real vessel data)",
        "synthetic": True,
        "description": ("Synthetic four-stroke medium-speed propulsion diesel (12 cylinders, two banks) of a "
                        "twin-shaft patrol vessel with controllable-pitch propellers, logged at 1/3 Hz; "
                        "after the egt-hybrid paper (its Table 1 channels). Not real data."),
        "size": size,
        "seed": int(seed),
        "published_split": split,
        "physical_model": PM_NAME,
        "pm_calibration": "simulator",
        "segment_manoeuvre_fraction": {str(k): round(float(v), 4) for k, v in man.items()},
        "thermocouple_time_constants_s": {
            "t_exhaust_before_turbine_a": cfg.tau_tc_in_s[0], "t_exhaust_before_turbine_b": cfg.tau_tc_in_s[1],
            "t_exhaust_after_turbine_a": cfg.tau_tc_out_s[0], "t_exhaust_after_turbine_b": cfg.tau_tc_out_s[1],
        },
        "pressures": "absolute, bar (p_max: bar)",
        "time_origin": "seconds from the start of the synthetic log",
        "random_streams": {"profile": STREAM_PROFILE, "engine": STREAM_ENGINE, "thermal": STREAM_THERMAL,
                           "sensors": STREAM_SENSORS},
    }
    ds = Dataset(name=NAME, frame=frame, schema=sch, dt=C.DT_LOG_S, meta=meta)
    report(1.0)
    return ds
