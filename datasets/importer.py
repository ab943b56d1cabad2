"""Import the user's own CSV or Parquet records through a small TOML spec.

A spec names the files, how time is given, and every column's role and unit. Paths are
relative to the spec file. Every key::

    name = "my-engine"                 # required: the dataset's name
    dt = 1.0                           # required: sample period, seconds
    files = ["run1.csv", "run2.csv"]   # CSV (.csv .txt .tsv .dat), Parquet (.parquet .pq) or Excel (.xlsx .xlsm,
                                       # datasets/excel.py); each file is a
                                       # record (a segment) named after its stem. Optional when [records] is given.
                                       # A name with * ? [ is a glob: its matches, in sorted order
    header = false                     # optional (default true): the CSV files have no header row; their fields
                                       # are named in file order by names, else by the [columns] order
    names = ["speed", "", "nox"]       # optional, with header = false: every field's name ("" = not read)
    time = "t"                         # optional: the time column. Without it time is the sample index x dt,
                                       # from 0 in every record (dt is then the only timing information)
    time_unit = "s"                    # s | ms | min | h, or "datetime" for ISO 8601 stamps (only with time)
    gap_tolerance = 3.0                # seconds; a longer step splits a record (default 1.5 * dt; only with time)
    record = "run"                     # optional: a column (role group if declared) that cuts each file of files
                                       # into records where its value changes; the records are named by its values
    segment = "voyage"                 # optional, older form: rows grouped by the column's value, in any order
                                       # (record and segment exclude each other)
    rate_column = "SampleRate"         # optional: a column holding the sampling rate (Hz), checked against dt
    period_column = "Period"           # optional: a column holding the sample period (s), checked against dt
    delimiter = ","                    # optional (default ",", or tab for .tsv files); "whitespace": runs of spaces/tabs
    decimal = ","                      # optional (default "."): a decimal comma; the delimiter then defaults to ";"
    encoding = "cp1252"                # optional (default "utf-8"): the CSV files' text encoding
    sheet = "data"                     # optional, Excel workbooks (.xlsx .xlsm): the sheet read (default the first)
    skip_lines = 3                     # optional (default 0): a preamble above the header, not read
    units_row = true                   # optional: the line under the header holds the fields' units (not data); a
                                       # column declared without a unit takes the file's, a different one is an error
    provenance = "test bench B, 2024"  # optional, free text
    licence = "CC BY 4.0"              # optional
    min_segment_rows = 2               # optional: shorter records are an error ...
    drop_short_segments = false        # ... or, when true, dropped with a warning
    dt_tolerance = 1e-6                # optional: relative tolerance on steps being multiples of dt (and on
                                       # a written rate or period)
    [physical_model]                   # optional: an FMU as the dataset's physical model (datasets/fmu_spec.py):
    fmu = "engine.fmu"                 # fmu, inputs = {column = "fmu variable"}, outputs = {target = "fmu variable"},
    inputs = { u = "u" }               # parameters = {name = value}, calibrate = ["name"], weights, fmi_type,
    outputs = { y = "y" }              # tolerance; the FMU's path and sha256 are kept in meta["fmu"]

    [columns]                          # required: the spec's column names, roles and units
    u = { role = "input", unit = "V" }
    y = { role = "output", unit = "V" }
    engine = { role = "group" }

    [records.estimation]               # optional wide form: a record read from some columns of a file
    file = "bench.csv"
    columns = { u = "uEst", y = "yEst" }  # spec column -> file column (a column left out: same name)
    # time = "tEst"                    # optional: this record's time column (default: the spec's time, or none)
    [records.test]
    file = "bench.csv"                 # records of one file may differ in length: a shorter record's
    columns = { u = "uVal", y = "yVal" }  # columns end in blank cells, which are ignored
    # with header = false a record may list the file's fields instead: columns = ["", "", "u", "y"]

Roles are ``input``, ``output``, ``internal`` and ``group`` (see
:mod:`enginebench.datasets.schema`); at least one output is needed. Group columns may
hold text. A record's time may restart at 0: records are separate segments. A value of
the ``record`` column that comes back after another value is an error (its rows would be
two records with one name); ``segment`` groups such rows instead.

File columns the spec does not read are ignored, but two kinds are reported with a
one-line note (stored in the dataset's ``meta["notes"]``, printed by ``datasets import``
and ``datasets show``): a column empty on every line (the nameless column a trailing
delimiter makes) and a column holding a value only in its first row (a sampling rate
written once); the note names it and the value. Such a value in a column named ``Fs`` /
``fs`` (Hz) or ``Ts`` / ``ts`` (s), or in ``rate_column`` / ``period_column``, is
checked against ``dt`` (see :mod:`enginebench.datasets.column_notes`).

``datetime`` stamps must all carry one UTC offset (or none, read as UTC); the dataset's
time is then seconds since 1970-01-01 UTC. A unit left out of the spec is taken from a
Parquet file that records one (enginebench metadata or an Arrow field's ``unit``
metadata) or from the units row of a CSV file with ``units_row = true``; a declared unit that
differs from a recorded one is an error.

Every error is a one-line :class:`SpecError` (the spec, see
:mod:`enginebench.datasets.import_spec`) or :class:`DataError` (a data file) whose message
starts with the path of the file at fault; see :mod:`enginebench.datasets.validate` for
the checks on values and time stamps.

This module assembles the records into a Dataset (units, notes, segment ids, time zones,
metadata); reading and parsing each file (CSV and Parquet readers, header checks) is
:mod:`enginebench.datasets.readers`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from enginebench.datasets.column_notes import SideColumn, side_column_notes
from enginebench.datasets.dataset import SEGMENT, Dataset
from enginebench.datasets.import_spec import ImportSpec, load_spec
from enginebench.datasets.readers import FileTable, FileUse, file_uses, read_file, too_few_rows
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.validate import (
    NUMERIC_ROLES,
    check_not_constant,
    column_hint,
    show_cell,
    validate_frame,
)
from enginebench.errors import DataError

__all__ = [
    "import_spec", "import_table"
]


# -- one record source: a file of files, or a [records] table ---------------------------------------
def _record_ids(file: Path, column: str, ids: pd.Series, lines: np.ndarray, word: str, *, contiguous: bool) -> Any:
    """Record names from a record/segment column; ``contiguous``: a new record where the value changes."""
    what = "record name" if contiguous else "segment id"
    if ids.isna().any():
        i = int(np.flatnonzero(ids.isna().to_numpy())[0])
        raise DataError(f"{file}, column {column!r}, {word} {lines[i]}: missing {what}; fill it or remove the row")
    names = ids.astype(str).str.strip()
    if contiguous:
        v = names.to_numpy(dtype=object)
        start = np.r_[True, v[1:] != v[:-1]]
        runs = pd.Series(v[start])
        again = runs.duplicated().to_numpy()
        if again.any():
            k = int(np.flatnonzero(again)[0])
            i = int(np.flatnonzero(start)[k])
            first = int(np.flatnonzero(v == v[i])[0])
            raise DataError(
                f"{file}, column {column!r}, {word} {lines[i]}: record {v[i]!r} starts again after other records "
                f"(it began on {word} {lines[first]}); give each record its own name, or use segment = "
                f"{json.dumps(column)} to group rows by value"
            )
    return names


def _first_row_only(file: Path, frame: pd.DataFrame, names: list[str], shown: dict[str, str], lines: np.ndarray,
                    word: str) -> None:
    """A declared column holding a value in its first row only (a rate written once) cannot be a signal."""
    if len(frame) < 2:
        return
    for c in names:
        column = frame[c]
        if pd.isna(column.iloc[0]) or column.iloc[1:1025].notna().any():  # the common case, from a prefix alone
            continue
        filled = column.notna().to_numpy()
        if filled[0] and not filled[1:].any():
            col = shown.get(c, c)
            raise DataError(
                f"{file}, column {col!r}: holds a value only in its first row ({show_cell(frame[c].iloc[0])}, "
                f"{word} {lines[0]}), like a sampling "
                "rate written once; remove it from [columns] (an undeclared column is dropped with a note)"
            )


def _filled_rows(frame: pd.DataFrame) -> int:
    """Rows up to the last one holding any value (a frame whose last row holds one is not scanned)."""
    if not len(frame) or frame.iloc[-1].notna().any():
        return len(frame)
    filled = np.flatnonzero(frame.notna().any(axis=1).to_numpy())
    return int(filled[-1]) + 1 if len(filled) else 0


def _source_frame(use: FileUse, table: FileTable, spec: ImportSpec) -> tuple[pd.DataFrame, np.ndarray, dict[str, str]]:
    """The rows of one record source: SEGMENT, the time column if any and the declared columns (logical names)."""
    file, time = use.file, use.time(spec)
    mapping = use.columns(spec)
    cols: dict[str, pd.Series] = {}
    if time is not None:
        cols[time] = table.column(time)
    for logical, col in mapping.items():
        cols[logical] = table.column(col)
    key = spec.group_key if use.record is None else None
    if key is not None and key not in cols:
        cols[key] = table.column(key)
    # side by side, not copied into one block (pd.DataFrame of a dict consolidates: a copy of every value, 2 s and
    # 800 MB at 1e7 rows x 10 columns)
    frame = pd.concat([series.rename(name) for name, series in cols.items()], axis=1)
    # Blank cells at the end carry nothing (blank lines, a shorter record of a wide file);
    # a blank cell inside is reported with its line.
    n = _filled_rows(frame)
    frame = frame.iloc[:n].reset_index(drop=True)
    lines = table.lines[:n]
    if use.record is None:
        too_few_rows(file, n, table.word)
        ids: Any = file.stem
        if key is not None:
            ids = _record_ids(file, key, frame[key], lines, table.word, contiguous=spec.record is not None)
    else:
        too_few_rows(file, n, table.word, record=use.record.name)
        ids = use.record.name
    numeric = [c.name for c in spec.schema.columns if c.role in NUMERIC_ROLES]
    _first_row_only(file, frame, numeric, mapping, lines, table.word)
    if isinstance(ids, str):  # one name for every row: a categorical, not 1e7 copies of the text
        ids = pd.Categorical.from_codes(np.zeros(n, dtype=np.int8), categories=[ids])
    frame = frame.assign(**{SEGMENT: ids})
    shown = {k: v for k, v in mapping.items() if k != v}
    return frame, lines, shown


def _side_notes(file: Path, table: FileTable, uses: list[FileUse], spec: ImportSpec) -> list[str]:
    """Notes on the columns of ``file`` that no record reads."""
    read = {table.pos[c] for use in uses for c in use.required(spec)}
    side = [
        SideColumn(i, name, table.raw[f"c{i}"], table.first_texts[i] if table.first_texts and i < len(table.first_texts)
                   else None)
        for i, name in enumerate(table.header)
        if i not in read
    ]
    return side_column_notes(
        side,
        file=str(file),
        label=_label(file, spec),
        n_fields=len(table.header),
        dt=spec.dt,
        dt_tolerance=spec.dt_tolerance,
        rate_column=spec.rate_column,
        period_column=spec.period_column,
        lines=table.lines,
        word=table.word,
    )


def _label(file: Path, spec: ImportSpec) -> str:
    """A file as notes name it: relative to the spec's folder when inside it, else as given."""
    rel = os.path.relpath(file, spec.path.parent)
    return str(file) if rel.startswith("..") else rel


def _zone_name(zone: str) -> str:
    return "no UTC offset" if zone == "none" else f"offset {zone}"


# -- the whole import ------------------------------------------------------------------------
def import_table(spec_path: str | Path) -> Dataset:
    """Import the records of an import spec file as one Dataset (what ``datasets show|import SPEC`` call)."""
    return import_spec(load_spec(spec_path))


def import_spec(spec: ImportSpec) -> Dataset:
    """Import the records of a checked spec: one segment per record, notes in ``meta["notes"]``."""
    fmu_meta = None
    if spec.physical_model is not None:  # the FMU is checked before the data are read
        from enginebench.datasets.fmu import import_meta

        fmu_meta = import_meta(spec.physical_model, spec.schema.names(), spec.dt, spec.path)
    units = {c.name: c.unit for c in spec.schema.columns}
    unit_from = {c.name: "the spec" for c in spec.schema.columns if c.unit}
    seen: dict[str, Path] = {}
    zones: dict[str, Path] = {}
    frames: list[pd.DataFrame] = []
    dropped: list[tuple[str, int]] = []
    notes: list[str] = []
    plan = file_uses(spec)
    n_sources = sum(len(u) for u in plan.values())
    headers: list[str] = []
    for file, uses in plan.items():
        table = read_file(file, spec, uses)
        for name, rec in table.units.items():
            logical = [c for u in uses for c, col in u.columns(spec).items() if col == name]
            for c in logical:
                if units[c] == rec:
                    continue
                if units[c]:
                    raise DataError(
                        f"{file}, column {name!r}: unit mismatch: {unit_from[c]} says {units[c]!r} but the file "
                        f"records {rec!r}; fix the unit in [columns] or convert the column"
                    )
                units[c], unit_from[c] = rec, str(file)
        notes += _side_notes(file, table, uses, spec)
        headers += [h for h in table.header if h not in headers]
        for use in uses:
            frame, lines, shown = _source_frame(use, table, spec)
            time = use.time(spec)
            out = validate_frame(
                frame,
                spec.schema,
                spec.dt,
                source=str(file),
                time_col=time,
                gap_tolerance=spec.gap_tolerance,
                min_segment_rows=spec.min_segment_rows,
                time_unit=spec.time_unit,
                dt_tolerance=spec.dt_tolerance,
                drop_short_segments=spec.drop_short_segments,
                check_constant=n_sources == 1,
                lines=lines,
                row_word=table.word,
                shown=shown,
            )
            for sid in pd.unique(out[SEGMENT]):
                if sid in seen:
                    raise DataError(
                        f"{file}: segment {sid!r} also comes from {seen[sid]}; segment ids must be unique across "
                        "files - rename the file or the segment ids"
                    )
                seen[sid] = file
            zone = out.attrs.get("time_zone")
            if zone is not None:
                zones.setdefault(zone, file)
                if len(zones) > 1:
                    (z0, f0), *_ = zones.items()
                    raise DataError(
                        f"{file}, column {time!r}: mixed time zones: this file has {_zone_name(zone)}, "
                        f"{f0} has {_zone_name(z0)}; "
                        "write every stamp with one UTC offset (e.g. all in UTC)"
                    )
            dropped += out.attrs.get("dropped_segments", [])
            frames.append(out)
    for key in ("rate_column", "period_column"):
        col = getattr(spec, key)
        if col is not None and col not in headers:
            raise DataError(f"{spec.path}: {key} {col!r} is in none of the files; {column_hint(col, headers)}")
    frame = pd.concat(frames, ignore_index=True)
    schema = Schema(tuple(Column(c.name, c.role, units[c.name]) for c in spec.schema.columns))
    if n_sources > 1:
        scope = f"all {len(spec.files)} files" if not spec.records else f"every record ({len(seen)} in all)"
        check_not_constant(frame, schema, source=str(spec.path), scope=scope)
    meta: dict[str, Any] = {
        "provenance": spec.provenance,
        "licence": spec.licence,
        "files": [os.path.relpath(p, spec.path.parent) for p in plan],
        "time_unit": spec.time_unit if spec.time is not None or any(r.time for r in spec.records) else "index",
    }
    if spec.records:
        meta["records"] = {
            r.name: {"file": os.path.relpath(r.file, spec.path.parent),
                     "columns": {k: v for k, v in r.columns.items() if k != v}, "time": r.time}
            for r in spec.records
        }
    if zones:
        meta["time_zone"] = next(iter(zones))
    if dropped:
        meta["dropped_segments"] = len(dropped)
    if notes:
        meta["notes"] = notes
    if fmu_meta is not None:
        meta["physical_model"], meta["fmu"] = "fmu", fmu_meta
    return Dataset(name=spec.name, frame=frame, schema=schema, dt=spec.dt, meta=meta)
