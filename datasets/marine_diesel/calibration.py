"""Calibration of the PM to factory-acceptance-test points by weighted least squares.

As in egt-hybrid sec. 5.1 the PM is tuned to the FAT protocol; as in hil-diesel sec. 3.1 the
tuning is a (weighted) least-squares fit, here ``scipy.optimize.least_squares`` with
physical bounds over the free parameters of ``pm.FAT_FREE``. The residuals are the
percentage errors PE = (PM - FAT) / FAT of the six FAT quantities at every speed,
multiplied by per-quantity weights, plus a small pull of every free parameter towards
its default (a Tikhonov term) so that parameters the FAT cannot see stay put.

Inputs of each FAT point: its speed and its fuel. When the table lists rack positions
(``fuel_rack_pct``, as ``simulator_fat`` does) they are the PM's input, the pump law
(fuel_nom_kg, rack_zero_pct) is fitted too and the brake power is an extra residual.
Otherwise (the egt-hybrid paper's table) the fuel per cycle follows from the FAT sfc and the load:
fuel flow = sfc x P, with P on the propeller law (``fat.propeller_law_power_w``) or
from a ``brake_power_kw`` column; the rack is then whatever the pump law makes of it.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.fat import QUANTITIES, load_fat, propeller_law_power_w
from enginebench.datasets.marine_diesel.pm import BOUNDS, DEFAULT_PARAMS, FAT_FREE, fuel_per_cycle, steady_outputs
from enginebench.errors import DataError

PRESSURES = ("absolute", "gauge")
PUMP_PARAMS = ("fuel_nom_kg", "rack_zero_pct")


def _fat_inputs(params: Mapping[str, Any], fat: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed (rpm), fuel per cylinder per cycle (kg) and brake power (W) of each FAT point."""
    speed = fat["speed_rpm"].to_numpy(dtype=float)
    power = (fat["brake_power_kw"].to_numpy(dtype=float) * 1e3 if "brake_power_kw" in fat
             else propeller_law_power_w(speed))
    if "fuel_rack_pct" in fat:
        fuel = fuel_per_cycle(params, fat["fuel_rack_pct"].to_numpy(dtype=float))
    else:
        flow = fat["sfc_g_per_kwh"].to_numpy(dtype=float) * power / 3.6e9
        fuel = flow / (float(params["n_cyl"]) * speed / 120.0)
    return speed, fuel, power


def pm_fat_predictions(params: Mapping[str, Any], fat: pd.DataFrame, pressure: str = "absolute") -> pd.DataFrame:
    """The PM's steady values of the FAT quantities at the FAT points (same column names)."""
    speed, fuel, power = _fat_inputs(params, fat)
    out = steady_outputs(params, speed, fuel)
    p_ref = float(params["p_amb_pa"]) if pressure == "gauge" else 0.0
    return pd.DataFrame({
        "speed_rpm": speed,
        "p_charge_air_bar": (out["p_charge_pa"] - p_ref) / C.BAR,
        "p_exhaust_receiver_bar": (out["p_receiver_pa"] - p_ref) / C.BAR,
        "p_max_bar": (out["p_max_pa"] - p_ref) / C.BAR,
        "sfc_g_per_kwh": out["sfc_g_per_kwh"],
        "t_turbine_inlet_degc": out["t_inlet_k"] - float(params["bias_inlet_k"]) - C.KELVIN,
        "t_turbine_outlet_degc": out["t_outlet_k"] - float(params["bias_outlet_k"]) - C.KELVIN,
        "brake_power_kw": out["brake_power_w"] / 1e3,
        "fat_power_kw": power / 1e3,
    })


def fat_report(params: Mapping[str, Any], fat: pd.DataFrame, pressure: str = "absolute") -> pd.DataFrame:
    """Long table: per speed and quantity, FAT value, our PM and PE %, beside the paper's."""
    pred = pm_fat_predictions(params, fat, pressure)
    rows = []
    for q, unit in QUANTITIES.items():
        for i, speed in enumerate(fat["speed_rpm"].to_numpy(dtype=float)):
            ref = float(fat[q].iloc[i])
            ours = float(pred[q].iloc[i])
            rows.append({
                "speed_rpm": speed, "quantity": q, "unit": unit, "fat": ref, "pm": ours,
                "pe_pct": (ours - ref) / ref * 100.0,
                "paper_pm": float(fat[f"{q}_pm_paper"].iloc[i]) if f"{q}_pm_paper" in fat else np.nan,
                "paper_pe_pct": float(fat[f"{q}_pe_paper_pct"].iloc[i]) if f"{q}_pe_paper_pct" in fat else np.nan,
            })
    return pd.DataFrame(rows)


def calibrate_to_fat(
    fat: pd.DataFrame,
    *,
    params: Mapping[str, Any] | None = None,
    free: Sequence[str] | None = None,
    weights: Mapping[str, float] | None = None,
    pressure: str = "absolute",
    regularisation: float = 1e-3,
    norm_power: float = 2.0,
    max_nfev: int = 400,
) -> tuple[dict[str, float], pd.DataFrame]:
    """Fit the PM's free parameters to FAT points; return (params, report frame).

    ``params`` are the starting values and the fixed ones (default ``pm.DEFAULT_PARAMS``);
    ``free`` the names to fit (default ``pm.FAT_FREE``, plus the pump law when the table
    has ``fuel_rack_pct``); ``weights`` per FAT quantity (default 1, sfc 2: the fuel
    balance anchors the cycle); ``pressure`` says how the table's pressures read
    ("absolute" or "gauge", i.e. above the PM's ambient pressure); ``norm_power`` p > 2
    minimises the sum of |PE|^p instead of squares (closer to minimising the worst
    error); ``regularisation`` weighs the pull towards the starting values. The report
    (see ``fat_report``) carries ``attrs`` max_abs_pe_pct, cost, nfev, success, free and
    pressure.
    """
    if pressure not in PRESSURES:
        raise DataError(f"calibrate_to_fat: pressure must be one of {', '.join(PRESSURES)}, got {pressure!r}")
    missing = [c for c in ("speed_rpm", *QUANTITIES) if c not in fat.columns]
    if missing:
        raise DataError(f"calibrate_to_fat: FAT table lacks column(s) {', '.join(missing)}")
    if len(fat) < 2:
        raise DataError(f"calibrate_to_fat: need at least 2 FAT points, got {len(fat)}")
    base = {**DEFAULT_PARAMS, **(params or {})}
    has_rack = "fuel_rack_pct" in fat.columns
    free = list(free) if free is not None else list(FAT_FREE) + (list(PUMP_PARAMS) if has_rack else [])
    unknown = [n for n in free if n not in BOUNDS]
    if unknown:
        raise DataError(f"calibrate_to_fat: cannot fit {', '.join(unknown)}; free parameters are {', '.join(BOUNDS)}")
    w = {q: 1.0 for q in QUANTITIES}
    w["sfc_g_per_kwh"] = 2.0
    w.update(weights or {})
    targets = {q: fat[q].to_numpy(dtype=float) for q in QUANTITIES}
    lo = np.array([BOUNDS[n][0] for n in free])
    hi = np.array([BOUNDS[n][1] for n in free])
    x0 = np.clip(np.array([float(base[n]) for n in free]), lo, hi)
    scale = np.maximum(np.abs(x0), 0.05 * (hi - lo))

    def unpack(x: np.ndarray) -> dict[str, float]:
        return {**base, **{n: float(v) for n, v in zip(free, x)}}

    def residuals(x: np.ndarray) -> np.ndarray:
        pred = pm_fat_predictions(unpack(x), fat, pressure)
        parts = [w[q] * (pred[q].to_numpy() - targets[q]) / targets[q] for q in QUANTITIES]
        if has_rack:
            parts.append((pred["brake_power_kw"].to_numpy() - pred["fat_power_kw"].to_numpy())
                         / pred["fat_power_kw"].to_numpy())
        r = np.concatenate(parts)
        if norm_power != 2.0:
            r = np.sign(r) * np.abs(r) ** (norm_power / 2.0)
        r = np.r_[r, regularisation * (x - x0) / scale]
        return np.nan_to_num(r, nan=10.0, posinf=10.0, neginf=-10.0)

    sol = least_squares(residuals, x0, bounds=(lo, hi), x_scale=scale, max_nfev=max_nfev)
    fitted = unpack(sol.x)
    report = fat_report(fitted, fat, pressure)
    report.attrs.update(max_abs_pe_pct=float(report["pe_pct"].abs().max()), cost=float(sol.cost),
                        nfev=int(sol.nfev), success=bool(sol.success), free=list(free), pressure=pressure)
    return fitted, report


@lru_cache(maxsize=1)
def _seed_fat_params_cached() -> tuple[tuple[str, float], ...]:
    params, _ = calibrate_to_fat(load_fat())
    return tuple(sorted(params.items()))


def seed_fat_params() -> dict[str, float]:
    """PM parameters calibrated on the egt-hybrid paper's FAT fixture (computed once per process)."""
    return dict(_seed_fat_params_cached())


@lru_cache(maxsize=8)
def _simulator_fat_params_cached(seed: int) -> tuple[tuple[str, float], ...]:
    from enginebench.datasets.marine_diesel.fat import simulator_fat

    params, _ = calibrate_to_fat(simulator_fat(seed))
    return tuple(sorted(params.items()))


def simulator_fat_params(seed: int = 0) -> dict[str, float]:
    """PM parameters calibrated on the shop-test (FAT) points of the true engine of ``generate(seed=seed)``.

    This is the calibration the ``marine-diesel`` experiments use: the synthetic data
    come from that engine, so its own factory test is the PM's calibration, as the
    egt-hybrid paper's PM was calibrated on its engine's FAT. Computed once per process and seed.
    """
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise DataError(f"simulator_fat_params: seed must be a non-negative integer, got {seed!r}")
    return dict(_simulator_fat_params_cached(int(seed)))
