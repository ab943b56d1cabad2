"""Import the user's own CSV or Parquet tables through a small TOML spec.

A spec names the files, the time column and every column's role and unit. Paths are
relative to the spec file::

    name = "my-engine"
    files = ["run1.csv", "run2.csv"]   # CSV (.csv .txt .tsv .dat) or Parquet (.parquet .pq)
    time = "t"                         # the time column
    time_unit = "s"                    # s | ms | min | h, or "datetime" for ISO 8601 stamps
    dt = 1.0                           # sample period, seconds
    gap_tolerance = 3.0                # seconds; a longer step splits a segment (default 1.5 * dt)
    segment = "voyage"                 # optional column of segment ids (default: one segment per file,
                                       # named after the file)
    delimiter = ","                    # optional (default ",", or tab for .tsv files)
    provenance = "test bench B, 2024"  # optional, free text
    licence = "CC BY 4.0"              # optional
    min_segment_rows = 2               # optional: shorter segments are an error ...
    drop_short_segments = false        # ... or, when true, dropped with a warning
    dt_tolerance = 1e-6                # optional: relative tolerance on steps being multiples of dt

    [columns]
    speed = { role = "input", unit = "rpm" }
    T_exh = { role = "output", unit = "degC" }
    engine = { role = "group" }

Roles are ``input``, ``output``, ``internal`` and ``group`` (see
:mod:`enginebench.datasets.schema`); at least one output is needed. Group columns may
hold text. Undeclared file columns are ignored. ``datetime`` stamps must all carry one
UTC offset (or none, read as UTC); the dataset's time is then seconds since
1970-01-01 UTC. A unit left out of the spec is taken from a Parquet file that records
one (enginebench metadata or an Arrow field's ``unit`` metadata); a declared unit that
differs from a recorded one is an error.

Every error is a one-line :class:`SpecError` (the spec) or :class:`DataError` (a data
file) whose message starts with the path of the file at fault; see
:mod:`enginebench.datasets.validate` for the checks on values and time stamps.
"""

from __future__ import annotations

import csv
import difflib
import json
import math
import os
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.validate import DATETIME, TIME_UNITS, check_columns, check_not_constant, validate_frame
from enginebench.errors import DataError, SpecError

REQUIRED_KEYS = ("name", "files", "time", "dt", "columns")
OPTIONAL_KEYS = (
    "time_unit",
    "gap_tolerance",
    "segment",
    "delimiter",
    "provenance",
    "licence",
    "min_segment_rows",
    "drop_short_segments",
    "dt_tolerance",
)
ALLOWED_KEYS = REQUIRED_KEYS + OPTIONAL_KEYS
COLUMN_KEYS = ("role", "unit")
CSV_SUFFIXES = (".csv", ".txt", ".tsv", ".dat")
PARQUET_SUFFIXES = (".parquet", ".pq")


@dataclass(frozen=True)
class ImportSpec:
    """A checked import spec; ``files`` are resolved against the spec's folder."""

    path: Path
    name: str
    files: tuple[Path, ...]
    time: str
    dt: float
    schema: Schema
    gap_tolerance: float
    time_unit: str = "s"
    segment: str | None = None
    delimiter: str | None = None
    provenance: str = ""
    licence: str = ""
    min_segment_rows: int = 2
    drop_short_segments: bool = False
    dt_tolerance: float = 1e-6

    def delimiter_for(self, file: Path) -> str:
        """The declared delimiter, else a tab for .tsv files and a comma otherwise."""
        if self.delimiter is not None:
            return self.delimiter
        return "\t" if file.suffix.lower() == ".tsv" else ","


# -- the spec ------------------------------------------------------------------------------
def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _unknown(where: Path, kind: str, key: str, allowed: tuple[str, ...]) -> SpecError:
    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return SpecError(f"{where}: unknown {kind} {key!r}{hint}; allowed: {', '.join(allowed)}")


def _number(path: Path, doc: dict[str, Any], key: str, default: float | None = None) -> float:
    v = doc.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise SpecError(f"{path}: {key} must be a positive number of seconds, got {v!r}")
    return float(v)


def _text(path: Path, doc: dict[str, Any], key: str, default: str | None = None, *, empty_ok: bool = False) -> str:
    v = doc.get(key, default)
    if not isinstance(v, str) or (not v.strip() and not empty_ok):
        raise SpecError(f"{path}: {key} must be a {'' if empty_ok else 'non-empty '}string, got {v!r}")
    return v


def _schema(path: Path, table: Any) -> Schema:
    if not isinstance(table, dict) or not table:
        raise SpecError(
            f'{path}: [columns] must declare at least one column, e.g. T_exh = {{ role = "output", unit = "degC" }}'
        )
    cols = []
    for name, entry in table.items():
        if isinstance(entry, str):
            entry = {"role": entry}
        if not isinstance(entry, dict):
            raise SpecError(f'{path}: [columns] {name!r} must be a table such as {{ role = "input", unit = "rpm" }}')
        for k in entry:
            if k not in COLUMN_KEYS:
                raise _unknown(path, f"key of column {name!r}:", k, COLUMN_KEYS)
        if "role" not in entry:
            raise SpecError(f"{path}: column {name!r} has no role; add role = one of input, output, internal, group")
        unit = entry.get("unit", "")
        if not isinstance(entry["role"], str) or not isinstance(unit, str):
            raise SpecError(f"{path}: column {name!r}: role and unit must be strings")
        try:
            cols.append(Column(str(name), entry["role"], unit))
        except DataError as exc:
            raise SpecError(f"{path}: {exc}") from exc
    return Schema(tuple(cols))


def load_spec(spec_path: str | Path) -> ImportSpec:
    """Read and check an import spec (see the module docstring for its keys)."""
    path = Path(spec_path)
    if not path.is_file():
        raise SpecError(f"{path}: import spec not found; give the path of a .toml file")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {_one_line(str(exc))}; fix the spec") from exc
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the spec as UTF-8") from exc
    for key in doc:
        if key not in ALLOWED_KEYS:
            raise _unknown(path, "key", key, ALLOWED_KEYS)
    missing = [k for k in REQUIRED_KEYS if k not in doc]
    if missing:
        raise SpecError(
            f"{path}: missing required key(s) {', '.join(missing)}; an import spec needs "
            f"{', '.join(REQUIRED_KEYS[:-1])} and a [columns] table"
        )
    files = doc["files"]
    if not isinstance(files, list) or not files or not all(isinstance(f, str) and f.strip() for f in files):
        raise SpecError(
            f'{path}: files must be a non-empty list of file names, e.g. files = ["run1.csv"]; got {files!r}'
        )
    resolved = tuple(path.parent / f for f in files)
    if len(set(resolved)) < len(resolved):
        twice = next(f for i, f in enumerate(files) if resolved[i] in resolved[:i])
        raise SpecError(f"{path}: file {twice!r} is listed twice in files")
    time_unit = _text(path, doc, "time_unit", "s")
    if time_unit not in (*TIME_UNITS, DATETIME):
        raise SpecError(f"{path}: time_unit {time_unit!r} is not one of {', '.join(TIME_UNITS)}, {DATETIME}")
    dt = _number(path, doc, "dt")
    gap = _number(path, doc, "gap_tolerance", 1.5 * dt)
    if gap < dt:
        raise SpecError(f"{path}: gap_tolerance = {gap:g} s is shorter than dt = {dt:g} s; make it at least dt")
    min_rows = doc.get("min_segment_rows", 2)
    if isinstance(min_rows, bool) or not isinstance(min_rows, int) or min_rows < 1:
        raise SpecError(f"{path}: min_segment_rows must be a whole number >= 1, got {min_rows!r}")
    drop = doc.get("drop_short_segments", False)
    if not isinstance(drop, bool):
        raise SpecError(f"{path}: drop_short_segments must be true or false, got {drop!r}")
    tol = doc.get("dt_tolerance", 1e-6)
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 <= tol < 0.5:
        raise SpecError(f"{path}: dt_tolerance must be a number in [0, 0.5), got {tol!r}")
    delimiter = doc.get("delimiter")
    if delimiter is not None and (not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in "\"\r\n"):
        raise SpecError(f'{path}: delimiter must be one character such as "," ";" or "\\t", got {delimiter!r}')
    time = _text(path, doc, "time")
    segment = _text(path, doc, "segment") if "segment" in doc else None
    schema = _schema(path, doc["columns"])
    if time in schema:
        raise SpecError(f"{path}: the time column {time!r} must not be declared in [columns]; time = names it")
    for reserved in (SEGMENT, TIME):
        if reserved in schema:
            raise SpecError(
                f"{path}: column name {reserved!r} in [columns] is reserved for the dataset's {reserved} column; "
                "rename that column in the file and the spec"
            )
    if segment is not None and segment in schema and schema[segment].role != "group":
        raise SpecError(
            f"{path}: the segment column {segment!r} is declared with role {schema[segment].role!r}; "
            "a segment column may only also be a group column"
        )
    if segment == time:
        raise SpecError(f"{path}: the segment column and the time column are both {time!r}; they must differ")
    if not schema.outputs:
        raise SpecError(f'{path}: no column has role = "output"; declare at least one target in [columns]')
    return ImportSpec(
        path=path,
        name=_text(path, doc, "name"),
        files=resolved,
        time=time,
        dt=dt,
        schema=schema,
        gap_tolerance=gap,
        time_unit=time_unit,
        segment=segment,
        delimiter=delimiter,
        provenance=_text(path, doc, "provenance", "", empty_ok=True),
        licence=_text(path, doc, "licence", "", empty_ok=True),
        min_segment_rows=min_rows,
        drop_short_segments=drop,
        dt_tolerance=float(tol),
    )


# -- reading one file -----------------------------------------------------------------------
@dataclass(frozen=True)
class _Table:
    frame: pd.DataFrame
    lines: np.ndarray
    word: str
    units: dict[str, str]


def _required(spec: ImportSpec) -> dict[str, str]:
    req = {spec.time: "time column"}
    if spec.segment is not None:
        req[spec.segment] = "segment column"
    for c in spec.schema.names():
        req.setdefault(c, "declared column")
    return req


def _too_few_rows(file: Path, n: int, word: str) -> None:
    if n == 0:
        what = "has a header but no data rows" if word == "line" else "has no data rows"
        raise DataError(f"{file}: the file {what}; a file needs at least 2 data rows")
    if n == 1:
        first = 2 if word == "line" else 1
        raise DataError(
            f"{file}: only 1 data row ({word} {first}); a file needs at least 2 data rows to form a segment"
        )


def _read_csv(file: Path, spec: ImportSpec) -> _Table:
    delim = spec.delimiter_for(file)
    try:
        with open(file, encoding="utf-8-sig", newline="") as fh:
            first = fh.readline()
            rest_blank = not first.strip() and not fh.read(1 << 16).strip()
    except UnicodeDecodeError as exc:
        raise DataError(f"{file}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the file as UTF-8") from exc
    if not first.strip():
        if rest_blank:
            raise DataError(f"{file}: the file is empty; it needs a header line and at least 2 data rows")
        raise DataError(f"{file}, line 1: blank; the header must be on line 1")
    header = [h.strip() for h in next(csv.reader([first.rstrip("\r\n")], delimiter=delim))]
    required = _required(spec)
    check_columns(header, required, source=str(file), delimiter=delim)
    for name in required:
        at = [i + 1 for i, h in enumerate(header) if h == name]
        if len(at) > 1:
            raise DataError(
                f"{file}, line 1: column {name!r} appears {len(at)} times in the header (fields {at}); "
                "rename all but one"
            )
    pos = {h: i for i, h in reversed(list(enumerate(header)))}
    text_cols = [spec.time] if spec.time_unit == DATETIME else []
    text_cols += [c.name for c in spec.schema.columns if c.role == "group"]
    text_cols += [spec.segment] if spec.segment is not None else []
    frame = _parse_csv(file, delim, header, pos, required, text_cols)
    # A float column that overflowed holds inf where the file holds text such as 1e309: re-read it
    # as text so that the error quotes the value as written.
    overflow = [
        c
        for c in required
        if c not in text_cols and pd.api.types.is_float_dtype(frame[c].dtype) and np.isinf(frame[c].to_numpy()).any()
    ]
    if overflow:
        frame = _parse_csv(file, delim, header, pos, required, text_cols + overflow)
    # Blank lines at the end of the file carry nothing; a blank line inside is reported by line.
    filled = np.flatnonzero(frame.notna().any(axis=1).to_numpy())
    frame = frame.iloc[: (filled[-1] + 1 if len(filled) else 0)].reset_index(drop=True)
    _too_few_rows(file, len(frame), "line")
    return _Table(frame, np.arange(len(frame)) + 2, "line", {})


def _parse_csv(
    file: Path, delim: str, header: list[str], pos: dict[str, int], required: dict[str, str], text_cols: list[str]
) -> pd.DataFrame:
    """The required columns; ``text_cols`` kept as text, the others parsed as numbers where they can be.

    Columns holding anything that is not a number come back as text, which
    :func:`validate.parse_numbers` then reports with its line.
    """
    try:
        raw = pd.read_csv(
            file,
            sep=delim,
            header=0,
            names=[f"c{i}" for i in range(len(header))],
            index_col=False,
            dtype={f"c{pos[c]}": str for c in text_cols},
            skip_blank_lines=False,
            encoding="utf-8-sig",
        )
    except pd.errors.ParserError as exc:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:
            raise DataError(
                f"{file}, line {m.group(2)}: {m.group(3)} fields where the header has {m.group(1)} "
                "(a stray delimiter or a decimal comma?); fix the row"
            ) from exc
        raise DataError(f"{file}: cannot parse the CSV ({_one_line(str(exc))}); check delimiter and quoting") from exc
    except UnicodeDecodeError as exc:
        raise DataError(f"{file}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the file as UTF-8") from exc
    return pd.DataFrame({name: raw[f"c{pos[name]}"] for name in required})


def _recorded_units(schema: pa.Schema) -> dict[str, str]:
    """Units a Parquet file records: enginebench metadata, else an Arrow field's unit metadata."""
    units: dict[str, str] = {}
    raw = (schema.metadata or {}).get(b"enginebench")
    if raw is not None:
        try:
            units = {k: v.get("unit", "") for k, v in json.loads(raw).get("schema", {}).items()}
        except (ValueError, AttributeError):
            units = {}
    for field in schema:
        meta = field.metadata or {}
        for key in (b"unit", b"units"):
            if key in meta:
                units[field.name] = meta[key].decode("utf-8", "replace")
    return {k: v for k, v in units.items() if v}


def _read_parquet(file: Path, spec: ImportSpec) -> _Table:
    try:
        schema = pq.read_schema(file)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DataError(f"{file}: not a Parquet file ({_one_line(str(exc))}); give CSV or Parquet files") from exc
    required = _required(spec)
    check_columns(schema.names, required, source=str(file))
    try:
        frame = pq.read_table(file, columns=list(required)).to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise DataError(
            f"{file}: cannot read the Parquet data ({_one_line(str(exc))}); the file may be damaged"
        ) from exc
    _too_few_rows(file, len(frame), "row")
    if spec.time_unit != DATETIME and pd.api.types.is_datetime64_any_dtype(frame[spec.time].dtype):
        raise DataError(
            f"{file}, column {spec.time!r}: holds timestamps but time_unit = {spec.time_unit!r}; "
            'set time_unit = "datetime"'
        )
    return _Table(frame, np.arange(len(frame)) + 1, "row", _recorded_units(schema))


def _read(file: Path, spec: ImportSpec) -> _Table:
    if not file.exists():
        raise DataError(f"{file}: file not found (listed in files of {spec.path}; paths are relative to the spec)")
    if file.is_dir():
        raise DataError(f"{file}: is a folder; list data files in files")
    suffix = file.suffix.lower()
    if suffix in PARQUET_SUFFIXES:
        return _read_parquet(file, spec)
    if suffix in CSV_SUFFIXES:
        if file.stat().st_size == 0:
            raise DataError(f"{file}: the file is empty; it needs a header line and at least 2 data rows")
        return _read_csv(file, spec)
    raise DataError(
        f"{file}: unsupported file type {suffix or '(none)'!r}; give CSV ({', '.join(CSV_SUFFIXES)}) "
        f"or Parquet ({', '.join(PARQUET_SUFFIXES)}) files"
    )


def _zone_name(zone: str) -> str:
    return "no UTC offset" if zone == "none" else f"offset {zone}"


# -- the whole import ------------------------------------------------------------------------
def import_table(spec_path: str | Path) -> Dataset:
    """Import the files of an import spec as one Dataset (what ``datasets import --spec`` calls)."""
    spec = load_spec(spec_path)
    units = {c.name: c.unit for c in spec.schema.columns}
    unit_from = {c.name: "the spec" for c in spec.schema.columns if c.unit}
    seen: dict[str, Path] = {}
    zones: dict[str, Path] = {}
    frames: list[pd.DataFrame] = []
    dropped: list[tuple[str, int]] = []
    for file in spec.files:
        table = _read(file, spec)
        for name, rec in table.units.items():
            if name not in units or units[name] == rec:
                continue
            if units[name]:
                raise DataError(
                    f"{file}, column {name!r}: unit mismatch: {unit_from[name]} says {units[name]!r} but the file "
                    f"records {rec!r}; fix the unit in [columns] or convert the column"
                )
            units[name], unit_from[name] = rec, str(file)
        frame = table.frame
        if spec.segment is not None:
            ids = frame[spec.segment]
            if ids.isna().any():
                i = int(np.flatnonzero(ids.isna().to_numpy())[0])
                raise DataError(
                    f"{file}, column {spec.segment!r}, {table.word} {table.lines[i]}: missing segment id; "
                    "fill it or remove the row"
                )
            frame = frame.assign(**{SEGMENT: ids.astype(str).str.strip()})
        else:
            frame = frame.assign(**{SEGMENT: file.stem})
        out = validate_frame(
            frame,
            spec.schema,
            spec.dt,
            source=str(file),
            time_col=spec.time,
            gap_tolerance=spec.gap_tolerance,
            min_segment_rows=spec.min_segment_rows,
            time_unit=spec.time_unit,
            dt_tolerance=spec.dt_tolerance,
            drop_short_segments=spec.drop_short_segments,
            check_constant=len(spec.files) == 1,
            lines=table.lines,
            row_word=table.word,
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
                    f"{file}, column {spec.time!r}: mixed time zones: this file has {_zone_name(zone)}, "
                    f"{f0} has {_zone_name(z0)}; "
                    "write every stamp with one UTC offset (e.g. all in UTC)"
                )
        dropped += out.attrs.get("dropped_segments", [])
        frames.append(out)
    frame = pd.concat(frames, ignore_index=True)
    schema = Schema(tuple(Column(c.name, c.role, units[c.name]) for c in spec.schema.columns))
    if len(spec.files) > 1:
        check_not_constant(frame, schema, source=str(spec.path), scope=f"all {len(spec.files)} files")
    meta: dict[str, Any] = {
        "provenance": spec.provenance,
        "licence": spec.licence,
        "files": [os.path.relpath(p, spec.path.parent) for p in spec.files],
        "time_unit": spec.time_unit,
    }
    if zones:
        meta["time_zone"] = next(iter(zones))
    if dropped:
        meta["dropped_segments"] = len(dropped)
    return Dataset(name=spec.name, frame=frame, schema=schema, dt=spec.dt, meta=meta)
