"""Read the five yearly CSVs of the UCI "Gas Turbine CO and NOx Emission Data Set".

The records are hourly averages in chronological order within each year, without time
stamps. Each year becomes one segment; time counts hours from the first record of 2011
with the years placed back to back (the gap between years is unknown and never bridged,
since each year is its own segment). The published protocol trains and validates on
2011-2013 and tests on 2014-2015.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from enginebench.datasets.catalog import Builtin
from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import DataError

NAME = "gas-turbine-emissions"
YEARS = (2011, 2012, 2013, 2014, 2015)
DT = 3600.0

COLUMNS = (
    Column("AT", "input", "degC"),     # ambient temperature
    Column("AP", "input", "mbar"),     # ambient pressure
    Column("AH", "input", "%"),        # ambient relative humidity
    Column("AFDP", "input", "mbar"),   # air filter difference pressure
    Column("GTEP", "input", "mbar"),   # gas turbine exhaust pressure
    Column("TIT", "input", "degC"),    # turbine inlet temperature
    Column("TAT", "output", "degC"),   # turbine after temperature
    Column("TEY", "input", "MWh"),     # turbine energy yield
    Column("CDP", "input", "bar"),     # compressor discharge pressure: bar (see CDP_UNIT_NOTE)
    Column("CO", "output", "mg/m3"),   # carbon monoxide
    Column("NOX", "output", "mg/m3"),  # nitrogen oxides
)
TARGETS = ("NOX", "CO", "TAT")
CDP_UNIT_NOTE = ("CDP is in bar: the UCI description (and its copies) label it mbar, but its values, 9.9-15.2, are a "
                 "compressor discharge pressure of about 12 times the ambient 1013 mbar, i.e. bar")
"""Why CDP's unit differs from the source's label (``datasets show`` prints it; docs/data.md says the same)."""

META = {
    "description": "Hourly records 2011-2015 of a gas turbine in north-western Turkey (ambient conditions, process variables, CO and NOx).",
    "provenance": "UCI Machine Learning Repository, 'Gas Turbine CO and NOx Emission Data Set'; "
                  "H. Kaya, P. Tufekci, E. Uzun, Turkish J. Electrical Eng. & Comp. Sci. 27 (2019) 4783-4796, doi:10.3906/elk-1807-87",
    "licence": "CC BY 4.0",
    "synthetic": False,
    "published_split": {"train": ["2011", "2012", "2013"], "test": ["2014", "2015"]},
    "physical_model": "gas-turbine-tat",
    "notes": [CDP_UNIT_NOTE],
}


def read_year(path: Path) -> pd.DataFrame:
    """One yearly CSV, checked for the expected columns and finite numbers."""
    try:
        frame = pd.read_csv(path)
    except (OSError, pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot be read as CSV ({type(exc).__name__}: {str(exc).splitlines()[0]})") from None
    frame.columns = [str(c).strip().upper() for c in frame.columns]
    missing = [c.name for c in COLUMNS if c.name not in frame.columns]
    if missing:
        raise DataError(f"{path}: missing column(s) {', '.join(missing)}; expected {', '.join(c.name for c in COLUMNS)}")
    for c in COLUMNS:
        values = pd.to_numeric(frame[c.name], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = int(bad[0])
            raise DataError(f"{path}, column {c.name!r}, line {row + 2}: {frame[c.name].iloc[row]!r} is not a finite number")
        frame[c.name] = values
    if len(frame) < 2:
        raise DataError(f"{path}: {len(frame)} data row(s); a year needs at least 2")
    return frame[[c.name for c in COLUMNS]]


def import_directory(directory: str | Path) -> Dataset:
    """Build the dataset from ``gt_2011.csv`` ... ``gt_2015.csv`` in ``directory``."""
    directory = Path(directory)
    if not directory.is_dir():
        raise DataError(f"{directory}: not a directory; pass the folder holding gt_2011.csv ... gt_2015.csv")
    parts = []
    offset = 0
    for year in YEARS:
        path = directory / f"gt_{year}.csv"
        if not path.is_file():
            raise DataError(f"{path}: file not found; the folder must hold gt_2011.csv ... gt_2015.csv")
        year_frame = read_year(path)
        n = len(year_frame)
        year_frame.insert(0, TIME, (offset + np.arange(n)) * DT)
        year_frame.insert(0, SEGMENT, str(year))
        parts.append(year_frame)
        offset += n
    frame = pd.concat(parts, ignore_index=True)
    return Dataset(NAME, frame, Schema(COLUMNS), DT, dict(META))


DATASETS = (
    Builtin(
        name=NAME,
        kind="real",
        description="36,733 hourly records 2011-2015 of an industrial gas turbine (UCI); targets NOX, CO, TAT; "
                    "published split 2011-2013 / 2014-2015",
        licence="CC BY 4.0",
        importer=import_directory,
        targets=TARGETS,
        notes={"import": "enginebench datasets import gas-turbine-emissions --from DIR (the folder with gt_2011.csv ... gt_2015.csv)"},
        order=0,
    ),
)
"""The catalog's entry (``datasets/catalog.py`` finds it here)."""
