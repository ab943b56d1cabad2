"""Factory-acceptance-test (FAT) points: the egt-hybrid paper's fixture and FAT on the true engine.

``load_fat`` reads ``fat_seed000.csv``: egt-hybrid's Table 4 with the paper's PM values
and percentage errors, columns named by physics (the paper's labels are in the file's
comment lines: its "after turbine" block is the hotter one, so it is the turbine
inlet). ``simulator_fat`` runs the generator's true engine (the same engine instance
as ``generate(seed=...)``) at the same six speeds on the propeller law, at shop
conditions, and returns the same quantities plus the rack position, brake power and
fuel flow that a shop test logs -- the points for the second calibration of the PM
that the marine experiment uses.

Pressure assumption: the paper calls its pressures "relative"; the fixture's
pressures are read as absolute bar (the project's reading: charge air 1.25-4.48 bar),
``calibrate_to_fat(..., pressure="gauge")`` reads them above ambient instead. Under the
absolute reading the paper's turbine-outlet temperatures at 631 and 795 rpm need more
temperature drop than an adiabatic turbine gives; the PM's polytropic exponent absorbs it.

FAT load assumption: the paper lists speeds, not loads. 631, 795, 910, 947, 1000 and
1031 rpm are (0.25, 0.5, 0.75, 0.85, 1.0, 1.1) ** (1/3) x 1000 rpm, so the test runs
along the propeller law P = P_MCR (N / N_MCR)^3 with MCR = 5.0 MW at 1000 rpm
(``constants.P_MCR_W``, ``constants.N_MCR_RPM``).
"""

from __future__ import annotations

from importlib import resources

import numpy as np
import pandas as pd

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.engine import steady_state
from enginebench.datasets.marine_diesel.engine_config import engine_for_seed
from enginebench.datasets.marine_diesel.sensors import SensorSpec
from enginebench.errors import DataError

FIXTURE = "fat_seed000.csv"
QUANTITIES: dict[str, str] = {
    "p_charge_air_bar": "bar",
    "p_exhaust_receiver_bar": "bar",
    "p_max_bar": "bar",
    "sfc_g_per_kwh": "g/kWh",
    "t_turbine_inlet_degc": "degC",
    "t_turbine_outlet_degc": "degC",
}
"""The FAT quantities compared with the PM, and their units."""

SHOP_AMBIENT_K = 298.15
SHOP_PRESSURE_PA = 1.0e5
SHOP_COOLANT_K = 305.15
STREAM_FAT = 5
"""Random stream of the shop-test measurement noise (see ``engine.engine_for_seed``)."""
SHOP_SENSORS = {
    "p_charge_air_bar": SensorSpec(0.005, 0.001), "p_exhaust_receiver_bar": SensorSpec(0.005, 0.001),
    "p_max_bar": SensorSpec(0.5, 0.1), "t_turbine_inlet_degc": SensorSpec(1.0, 0.1),
    "t_turbine_outlet_degc": SensorSpec(1.0, 0.1), "brake_power_kw": SensorSpec(0.0, 0.1, 0.002),
    "fuel_flow_kg_s": SensorSpec(0.0, 1e-5, 0.002), "fuel_rack_pct": SensorSpec(0.05, 0.01),
}
"""Shop-test instrumentation: noise and resolution per quantity."""


def propeller_law_power_w(speed_rpm: np.ndarray) -> np.ndarray:
    """FAT load: brake power on the propeller law through MCR, W."""
    return C.P_MCR_W * (np.asarray(speed_rpm, dtype=float) / C.N_MCR_RPM) ** 3


def load_fat(path: str | None = None) -> pd.DataFrame:
    """The FAT table: the shipped seed fixture, or a CSV with the same columns at ``path``.

    Required columns: ``speed_rpm`` and every name of ``QUANTITIES``; optional: the
    paper's ``<quantity>_pm_paper`` and ``<quantity>_pe_paper_pct``, and the shop-log
    columns ``brake_power_kw``, ``fuel_rack_pct``, ``fuel_flow_kg_s``. Lines starting
    with ``#`` are comments. A missing or unreadable file, a missing column, a
    non-numeric, non-finite or non-positive value, a repeated speed or fewer than two
    points raise ``DataError`` naming the file, column and row.
    """
    if path is None:
        with resources.files("enginebench.datasets.marine_diesel").joinpath(FIXTURE).open("r") as fh:
            fat = pd.read_csv(fh, comment="#")
        return check_fat(fat, FIXTURE)
    where = str(path)
    try:
        fat = pd.read_csv(path, comment="#")
    except FileNotFoundError:
        raise DataError(f"FAT table {where}: file not found") from None
    except IsADirectoryError:
        raise DataError(f"FAT table {where}: is a folder, not a CSV file") from None
    except pd.errors.EmptyDataError:
        raise DataError(f"FAT table {where}: the file is empty; expected a CSV header with speed_rpm and "
                        f"{', '.join(QUANTITIES)}") from None
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataError(f"FAT table {where}: not a readable CSV file ({first})") from None
    return check_fat(fat, where)


OPTIONAL_COLUMNS = ("brake_power_kw", "fuel_rack_pct", "fuel_flow_kg_s")
"""Shop-log columns a FAT table may carry (``simulator_fat`` writes them)."""


def check_fat(fat: pd.DataFrame, where: str) -> pd.DataFrame:
    """Validate a FAT table (see ``load_fat``); returns it with numeric columns as floats."""
    fat = fat.rename(columns=lambda c: str(c).strip())
    missing = [c for c in ("speed_rpm", *QUANTITIES) if c not in fat.columns]
    if missing:
        raise DataError(f"FAT table {where}: missing column(s) {', '.join(missing)}; "
                        f"expected speed_rpm and {', '.join(QUANTITIES)}")
    if len(fat) < 2:
        raise DataError(f"FAT table {where}: {len(fat)} data row(s); the calibration needs at least 2 FAT points")
    paper = [f"{q}_{suffix}" for q in QUANTITIES for suffix in ("pm_paper", "pe_paper_pct")]
    positive = ["speed_rpm", *QUANTITIES, *OPTIONAL_COLUMNS]
    out = fat.copy()
    for col in [c for c in (*positive, *paper) if c in fat.columns]:
        values = pd.to_numeric(fat[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raw = fat[col].iloc[bad[0]]
            raise DataError(f"FAT table {where}, column {col}, data row {bad[0] + 1}: value {raw!r} is not a finite "
                            "number; fill in every FAT value")
        if col in positive:
            low = np.flatnonzero(values <= 0)
            if low.size:
                raise DataError(f"FAT table {where}, column {col}, data row {low[0] + 1}: value {values[low[0]]:g} "
                                "must be positive (pressures absolute in bar, temperatures in degC, sfc in g/kWh)")
        out[col] = values
    dup = out["speed_rpm"].duplicated()
    if dup.any():
        row = int(np.flatnonzero(dup.to_numpy())[0])
        raise DataError(f"FAT table {where}, column speed_rpm, data row {row + 1}: speed {out['speed_rpm'].iloc[row]:g} "
                        "rpm appears twice; give one row per FAT point")
    return out


def simulator_fat(seed: int = 0) -> pd.DataFrame:
    """Steady shop-test points measured on the true engine of ``generate(seed=seed)``.

    Same speeds and load law as the egt-hybrid paper's FAT; shop conditions 25 degC, 1.0 bar,
    LT water 32 degC; clean engine (no fouling); measurement noise drawn from the random seed.
    """
    cfg = engine_for_seed(seed)
    speed = np.array(C.FAT_SPEEDS_RPM)
    power = propeller_law_power_w(speed)
    st = steady_state(speed, power, cfg, t_amb_k=SHOP_AMBIENT_K, p_amb_pa=SHOP_PRESSURE_PA,
                      t_coolant_k=SHOP_COOLANT_K)
    true = {
        "brake_power_kw": st["brake_power_w"] / 1e3,
        "fuel_rack_pct": st["rack_pct"],
        "fuel_flow_kg_s": st["fuel_flow_kg_s"],
        "p_charge_air_bar": st["p_im_pa"].mean(axis=0) / C.BAR,
        "p_exhaust_receiver_bar": st["p_em_pa"].mean(axis=0) / C.BAR,
        "p_max_bar": st["p_max_pa"].mean(axis=0) / C.BAR,
        "t_turbine_inlet_degc": st["t_turb_in_k"].mean(axis=0) - C.KELVIN,
        "t_turbine_outlet_degc": st["t_turb_out_k"].mean(axis=0) - C.KELVIN,
    }
    rng = np.random.default_rng([seed, STREAM_FAT])
    meas = {k: SHOP_SENSORS[k].measure(v, rng) for k, v in true.items()}
    meas["sfc_g_per_kwh"] = np.round(meas["fuel_flow_kg_s"] / (meas["brake_power_kw"] * 1e3) * 3.6e9, 1)
    cols = ["speed_rpm", *QUANTITIES, "brake_power_kw", "fuel_rack_pct", "fuel_flow_kg_s"]
    frame = pd.DataFrame({"speed_rpm": speed, **meas})[cols]
    frame.attrs["source"] = f"synthetic: enginebench marine-diesel true engine, seed {seed}, shop test"
    return frame
