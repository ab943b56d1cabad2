"""Notes on the file columns an import does not read, and the check of dt against a written rate.

Published identification records often carry columns that are not signals: a trailing
delimiter on every line gives a last column with no name and no value, and a sampling
rate is often written once, in the first data row (``Fs`` = 400, then empty cells). Such
columns are dropped, each with a one-line note, so that the user sees what happened to
every column of the file. A value written once in a column named ``Fs``/``fs`` (a rate in
Hz) or ``Ts``/``ts`` (a period in s), or in the column a spec names with ``rate_column``
/ ``period_column``, is checked against the spec's ``dt``: they agree when they differ by
no more than half a unit in the last digit written (``400`` allows 399.5-400.5 Hz,
``610.35`` allows +-0.005 Hz) plus ``dt_tolerance`` relative; a larger difference is one
DataError line naming the file, column, value and dt.
"""

from __future__ import annotations

from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

import numpy as np
import pandas as pd

from enginebench.errors import DataError

RATE_NAMES = ("Fs", "fs")
"""Column names read as a sampling rate in Hz."""
PERIOD_NAMES = ("Ts", "ts")
"""Column names read as a sample period in seconds."""


@dataclass(frozen=True)
class SideColumn:
    """A file column the import does not read: position (from 0), header name and cells."""

    position: int
    name: str
    cells: pd.Series
    first_text: str | None = None  # the first data row's cell as written in the file, if known


def _num(x: float) -> str:
    return f"{float(x):.10g}"


def _half_unit(text: str) -> float:
    """Half a unit in the last digit of a number as written ("400" -> 0.5, "0.0025" -> 5e-5)."""
    try:
        exp = Decimal(text.strip()).as_tuple().exponent
    except (InvalidOperation, ValueError):
        return 0.0
    return 0.5 * 10.0 ** int(exp) if isinstance(exp, int) else 0.0


def _label(col: SideColumn, last: bool) -> str:
    if col.name.strip():
        return f"column {col.name!r}"
    where = "no name, after the delimiter that ends every line" if last else "no name"
    return f"column {col.position + 1} ({where})"


def _kind(name: str, rate_column: str | None, period_column: str | None) -> str | None:
    """"rate", "period" or None: what a column's value says about dt."""
    if name == rate_column or (name in RATE_NAMES and name != period_column):
        return "rate"
    if name == period_column or name in PERIOD_NAMES:
        return "period"
    return None


def check_dt(
    kind: str, text: str, *, dt: float, dt_tolerance: float, file: str, column: str, where: str, strict: bool
) -> str | None:
    """Compare a written rate (Hz) or period (s) with ``dt``; the agreement as a phrase, or None if not a number.

    ``strict`` (a column the spec named) makes a value that is not a positive number an error.
    """
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not np.isfinite(value) or value <= 0:
        if strict:
            raise DataError(
                f"{file}, column {column!r}, {where}: {text!r} is not a positive number; a {kind} column holds "
                f"the {'sampling rate in Hz' if kind == 'rate' else 'sample period in s'}"
            )
        return None
    implied = 1.0 / dt if kind == "rate" else dt
    slack = _half_unit(text) + dt_tolerance * value + 1e-12 * value
    unit = "Hz" if kind == "rate" else "s"
    if abs(implied - value) > slack:
        means = f"a sampling rate: dt = {_num(1.0 / value)} s" if kind == "rate" else "a sample period"
        raise DataError(
            f"{file}, column {column!r}, {where}: {text} {unit} ({means}) disagrees with dt = {_num(dt)} s in the "
            "spec; fix dt (or the value in the file)"
        )
    return f"{column} = {text} {unit} agrees with dt = {_num(dt)} s"


def side_column_notes(
    columns: list[SideColumn],
    *,
    file: str,
    label: str,
    n_fields: int,
    dt: float,
    dt_tolerance: float,
    rate_column: str | None = None,
    period_column: str | None = None,
    lines: np.ndarray | None = None,
    word: str = "line",
) -> list[str]:
    """One note per dropped column (empty everywhere, or a value in the first row only).

    ``file`` names the file in errors, ``label`` in notes (a path relative to the spec);
    ``n_fields`` is the number of header fields (a nameless last field is the trailing
    delimiter). Columns holding data on several rows are ignored silently, except a
    named ``rate_column``/``period_column``, which must then hold one value throughout.
    """
    notes: list[str] = []
    for col in columns:
        ln = np.arange(len(col.cells)) + (2 if word == "line" else 1) if lines is None else np.asarray(lines)
        missing = col.cells.isna().to_numpy()
        filled = np.flatnonzero(~missing)
        what = _label(col, col.position == n_fields - 1)
        kind = _kind(col.name, rate_column, period_column)
        strict = col.name in (rate_column, period_column)
        if len(filled) == 0:
            if strict:
                key = "rate_column" if col.name == rate_column else "period_column"
                raise DataError(f"{file}, column {col.name!r}: {key} is empty on every {word}; it must hold the value")
            notes.append(f"{label}: {what} is empty on every {word}; dropped")
            continue
        if filled[0] == 0 and len(filled) == 1 and len(missing) > 1:
            text = col.first_text if col.first_text is not None else _cell_text(col.cells.iloc[0])
            checked = None
            if kind is not None:
                checked = check_dt(kind, text, dt=dt, dt_tolerance=dt_tolerance, file=file, column=col.name,
                                   where=f"{word} {ln[0]}", strict=strict)
            tail = f" ({checked})" if checked else ""
            notes.append(f"{label}: {what} holds a value only in its first row ({text}, {word} {ln[0]}); "
                         f"dropped{tail}")
            continue
        if strict:
            values = pd.unique(col.cells.iloc[filled].astype(str).str.strip())
            if len(values) > 1:
                raise DataError(
                    f"{file}, column {col.name!r}: holds {len(values)} different values ({values[0]}, {values[1]}, ...); "
                    f"the {'rate' if kind == 'rate' else 'period'} column must hold one value"
                )
            checked = check_dt(kind or "rate", str(values[0]), dt=dt, dt_tolerance=dt_tolerance, file=file,
                               column=col.name, where=f"{word} {ln[filled[0]]}", strict=True)
            notes.append(f"{label}: {what} holds {values[0]} on every filled {word}; not imported ({checked})")
    return notes


def _cell_text(value: object) -> str:
    if isinstance(value, (float, np.floating)):
        return _num(float(value))
    return str(value).strip()
