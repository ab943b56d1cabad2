"""The TOML import spec: its keys, their checks, and the checked :class:`ImportSpec`.

Every key is described in :mod:`enginebench.datasets.importer` (the module users read);
this module only parses and checks them. A spec comes from a TOML file
(:func:`load_spec`) or from a dictionary built in code (:func:`spec_from_dict`, what the
built-in importers of published records use), so both go through the same checks. Every
mistake is one :class:`SpecError` line starting with the spec's path.
"""

from __future__ import annotations

import codecs
import difflib
import glob
import json
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from enginebench.datasets.dataset import SEGMENT, TIME
from enginebench.datasets.fmu_spec import parse_physical_model
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.validate import DATETIME, TIME_UNITS
from enginebench.declare import (Declaration, Invalid, anything, choice, did_you_mean, flag, number, positive, table,
                                 text, whole)
from enginebench.errors import DataError, SpecError

REQUIRED_KEYS = ("name", "dt", "columns")


WHITESPACE = "whitespace"
"""``delimiter = "whitespace"``: fields separated by any run of spaces or tabs (loggers' .dat and .txt files)."""


def _delimiter(value: Any) -> Any:
    if value == WHITESPACE:
        return value
    if not isinstance(value, str) or len(value) != 1 or value in "\"\r\n":
        raise Invalid(DELIMITER)
    return value


def _any_text(value: Any) -> str:
    if not isinstance(value, str):
        raise Invalid("{name} must be a string, got {value}")
    return value


DECIMALS = (".", ",")
DELIMITER = '{name} must be one character such as "," ";" or "\\t", or "whitespace", got {value}'
SECONDS = "{name} must be a positive number of seconds, got {value}"
MAX_DT = 1e7
"""The longest sample period accepted (about 116 days): beyond it time stamps lose their meaning."""
SECONDS_DT = "{name} must be a positive number of seconds, got {value} (at most 1e7 s, about 116 days)"
KEYS = Declaration(
    text("name", None, "the dataset's name"),
    positive("dt", None, "sample period", unit="s", high=MAX_DT, message=SECONDS_DT),
    table("columns", None, 'column = { role = "input" | "output" | "internal" | "group", unit = "..." }'),
    anything("files", None, "data files (CSV, TSV or Parquet), relative to the spec's folder; a name with * ? [ ] "
             "is a glob (its matches in sorted order)", type_label="list[str]"),
    flag("header", True, "the CSV files' first line names their fields; false: no header row, the fields are "
         "named in file order by names (default: the [columns] order)"),
    anything("names", None, "with header = false: the files' field names in file order (\"\" for a field not "
             "read); default the [columns] names in declaration order", type_label="list[str]"),
    table("records", None, "[records.NAME] tables: a record read from columns of a file"),
    text("time", None, "the files' time column; absent: time = sample index x dt"),
    choice("time_unit", "s", "unit of the time column", (*TIME_UNITS, DATETIME),
           message="{name} {value} is not one of " + ", ".join((*TIME_UNITS, DATETIME))),
    positive("gap_tolerance", None, "a time step longer than this splits a segment; default 1.5 dt", unit="s",
             message=SECONDS),
    text("segment", None, "column whose value groups rows into segments"),
    text("record", None, "column whose change of value starts a new record"),
    text("rate_column", None, "a sample-rate column checked against dt, never imported", unit="Hz"),
    text("period_column", None, "a sample-period column checked against dt, never imported", unit="s"),
    anything("delimiter", None, "CSV delimiter, one character or \"whitespace\" (runs of spaces or tabs); default a "
             "tab for .tsv files, else a comma (a semicolon with decimal = \",\")",
             check=_delimiter, type_label="str | None"),
    choice("decimal", ".", "the CSV files' decimal mark: \",\" for files written with a decimal comma", DECIMALS,
           message='{name} must be "." or ",", got {value}'),
    text("sheet", None, "with Excel workbooks (.xlsx): the sheet read; default the first"),
    text("encoding", "utf-8", "the CSV files' text encoding (\"cp1252\" or \"latin-1\" for many Windows exports)"),
    whole("skip_lines", 0, "lines above the header (or, with header = false, above the data) that are not read: "
          "a test bench's preamble", low=0, unit="lines"),
    flag("units_row", False, "the line under the CSV files' header holds each field's unit (test-bench exports): "
         "it is not data; a declared column without a unit takes the file's, a different declared unit is an error"),
    anything("provenance", "", "where the data come from", check=_any_text),
    anything("licence", "", "the data's licence", check=_any_text),
    whole("min_segment_rows", 2, "shortest segment accepted", low=1, unit="rows"),
    flag("drop_short_segments", False, "drop segments shorter than min_segment_rows instead of refusing them"),
    number("dt_tolerance", 1e-6, "relative tolerance of a time step against a multiple of dt", low=0, high=0.5,
           high_open=True),
    anything("physical_model", None, "[physical_model] table: an FMU physical model (datasets/fmu_spec.py)",
             type_label="table"),
)
"""Every key of an import spec (the keys' full story is in :mod:`enginebench.datasets.importer`)."""
OPTIONAL_KEYS = tuple(k for k in KEYS.names() if k not in REQUIRED_KEYS)


ALLOWED_KEYS = REQUIRED_KEYS + OPTIONAL_KEYS
COLUMN_KEYS = ("role", "unit")
RECORD_KEYS = ("file", "columns", "time")
NEEDS = "an import spec needs name, dt, files (or [records.NAME] tables) and a [columns] table"


@dataclass(frozen=True)
class RecordSpec:
    """One ``[records.NAME]`` table: the record ``name`` read from columns of ``file``.

    ``columns`` maps every declared column to the file's column holding it (a declared
    column the table does not map is read from the file column of the same name);
    ``time`` is the file's time column for this record, or None for time = index x dt.
    """

    name: str
    file: Path
    columns: Mapping[str, str]
    time: str | None = None


GLOB_CHARS = frozenset("*?[")
POSITIONAL = "field {}"
"""How a field of a headerless file that ``names`` leaves unnamed is called (1-based)."""


@dataclass(frozen=True)
class ImportSpec:
    """A checked import spec; ``files`` and record files are resolved against the spec's folder."""

    path: Path
    name: str
    files: tuple[Path, ...]
    time: str | None
    dt: float
    schema: Schema
    gap_tolerance: float
    time_unit: str = "s"
    segment: str | None = None
    record: str | None = None
    delimiter: str | None = None
    provenance: str = ""
    licence: str = ""
    min_segment_rows: int = 2
    drop_short_segments: bool = False
    dt_tolerance: float = 1e-6
    records: tuple[RecordSpec, ...] = field(default=())
    rate_column: str | None = None
    period_column: str | None = None
    physical_model: Mapping[str, Any] | None = None  # the [physical_model] FMU table (datasets/fmu_spec.py)
    header: bool = True
    names: tuple[str, ...] = ()
    """With ``header`` false: the field names of every file, in file order ("" for a field not read)."""
    decimal: str = "."
    units_row: bool = False
    encoding: str = "utf-8"
    skip_lines: int = 0
    sheet: str | None = None

    def field_name(self, position: int) -> str:
        """The name of a headerless file's field at 0-based ``position``."""
        if position < len(self.names) and self.names[position]:
            return self.names[position]
        return POSITIONAL.format(position + 1)

    def delimiter_for(self, file: Path) -> str:
        """The declared delimiter, else a tab for .tsv files, a semicolon with a decimal comma, a comma otherwise."""
        if self.delimiter is not None:
            return self.delimiter
        if file.suffix.lower() == ".tsv":
            return "\t"
        return ";" if self.decimal == "," else ","

    @property
    def group_key(self) -> str | None:
        """The column that names records inside a file (``segment`` or ``record``), if any."""
        return self.segment if self.segment is not None else self.record


# -- small checks --------------------------------------------------------------------------
def one_line(text: str) -> str:
    return " ".join(str(text).split())


def _unknown(where: Path, kind: str, key: str, allowed: tuple[str, ...]) -> SpecError:
    return SpecError(f"{where}: unknown {kind} {key!r}{did_you_mean(key, allowed)}; allowed: {', '.join(allowed)}")


def _text(path: Path, doc: Mapping[str, Any], key: str, default: str | None = None, *, empty_ok: bool = False) -> str:
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
        if not str(name).strip():
            raise SpecError(f"{path}: [columns] has a column with an empty name; name it as the file's header does")
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


def _files(path: Path, doc: Mapping[str, Any]) -> tuple[Path, ...]:
    if "files" not in doc:
        return ()
    files = doc["files"]
    if not isinstance(files, list) or not files or not all(isinstance(f, str) and f.strip() for f in files):
        raise SpecError(
            f'{path}: files must be a non-empty list of file names, e.g. files = ["run1.csv"]; got {files!r}'
        )
    plain = [path.parent / f for f in files if GLOB_CHARS.isdisjoint(f)]
    for i, f in enumerate(plain):
        if f in plain[:i]:
            raise SpecError(f"{path}: file {os.path.relpath(f, path.parent)!r} is listed twice in files")
    resolved: list[Path] = []
    for f in files:
        if GLOB_CHARS.isdisjoint(f):
            resolved.append(path.parent / f)
            continue
        matches = sorted(Path(p) for p in glob.glob(str(path.parent / f)) if Path(p).is_file())
        if not matches:
            raise SpecError(
                f"{path}: files pattern {f!r} matches no file in {path.parent}; patterns are relative to the spec's "
                "folder (e.g. files = [\"raw_*.csv\"])"
            )
        resolved += [m for m in matches if m not in resolved and m not in plain]
    return tuple(resolved)


def _field_list(path: Path, where: str, fields: Any, schema: Schema, field_name: Any) -> dict[str, str]:
    """A headerless record's ``columns = ["speed", "", ...]``: declared column -> the file field holding it."""
    if not fields or not all(isinstance(f, str) for f in fields):
        raise SpecError(f'{path}: {where} columns must list the file\'s fields in order, e.g. ["speed", "", "NOx"] '
                        f'("" for a field not read); got {fields!r}')
    out: dict[str, str] = {}
    for i, logical in enumerate(fields):
        if not logical:
            continue
        if logical not in schema:
            raise SpecError(f"{path}: {where} columns: field {i + 1} {logical!r} is not declared in [columns]"
                            f"{did_you_mean(logical, schema.names())}")
        if logical in out:
            raise SpecError(f"{path}: {where} columns: {logical!r} names two fields; name each field once")
        out[logical] = field_name(i)
    return out


def _record(path: Path, name: str, table: Any, schema: Schema, time: str | None,
            header: bool = True, field_name: Any = None) -> RecordSpec:
    """One ``[records.NAME]`` table, checked against the declared columns."""
    where = f"[records.{name}]"
    if not name.strip():
        raise SpecError(f"{path}: a [records] table has an empty name; name each record, e.g. [records.estimation]")
    if not isinstance(table, dict):
        raise SpecError(
            f'{path}: {where} must be a table such as {{ file = "data.csv", columns = {{ u = "uEst", y = "yEst" }} }}'
        )
    for k in table:
        if k not in RECORD_KEYS:
            raise _unknown(path, f"key of {where}:", k, RECORD_KEYS)
    file = table.get("file")
    if not isinstance(file, str) or not file.strip():
        raise SpecError(f'{path}: {where} needs file = "..." (the file holding its columns), got {file!r}')
    mapping = table.get("columns", {})
    if isinstance(mapping, list):
        if header:
            raise SpecError(f"{path}: {where} columns is a list of fields in file order, which needs header = false "
                            "(a file without a header row); with a header, map columns = { u = \"uEst\" }")
        mapping = _field_list(path, where, mapping, schema, field_name)
        missing = [c for c in schema.names() if c not in mapping]
        if missing:
            raise SpecError(f"{path}: {where} columns names no field for declared column(s) {', '.join(map(repr, missing))}; "
                            "every record of a headerless file reads every declared column")
    if not isinstance(mapping, dict):
        raise SpecError(f'{path}: {where} columns must be a table such as {{ u = "uEst", y = "yEst" }}, got {mapping!r}')
    declared = schema.names()
    for logical, column in mapping.items():
        if logical not in schema:
            close = difflib.get_close_matches(logical, declared, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise SpecError(
                f"{path}: {where} columns: {logical!r} is not declared in [columns]; {hint}the keys are the spec's "
                f"column names ({', '.join(map(repr, declared))}), the values the file's columns"
            )
        if not isinstance(column, str) or not column.strip():
            raise SpecError(f"{path}: {where} columns: {logical!r} must name a column of the file, got {column!r}")
    rec_time = time
    if "time" in table:
        rec_time = _text(path, table, "time")
    full = {c: mapping.get(c, c) for c in declared}
    by_file: dict[str, list[str]] = {}
    for logical, column in full.items():
        by_file.setdefault(column, []).append(logical)
    for column, logicals in by_file.items():
        roles = {schema[c].role for c in logicals}
        if len(logicals) > 1 and "output" in roles:
            raise SpecError(
                f"{path}: {where}: file column {column!r} is read as {', '.join(map(repr, logicals))}; a target read "
                "from the same column as another signal leaks it into the inputs: map each to its own column"
            )
    if rec_time is not None and rec_time in schema:
        raise SpecError(
            f"{path}: {where}: time = {rec_time!r} is a column declared in [columns]; name the file's time column"
        )
    if rec_time is not None:
        clash = [c for c, col in full.items() if col == rec_time]
        if clash:
            raise SpecError(
                f"{path}: {where}: the time column {rec_time!r} is also read as column {clash[0]!r}; they must differ"
            )
    return RecordSpec(name=name, file=path.parent / file, columns=full, time=rec_time)


def _records(path: Path, doc: Mapping[str, Any], schema: Schema, time: str | None,
             header: bool = True, field_name: Any = None) -> tuple[RecordSpec, ...]:
    if "records" not in doc:
        return ()
    tables = doc["records"]
    if not isinstance(tables, dict) or not tables:
        raise SpecError(
            f'{path}: records must hold [records.NAME] tables, e.g. [records.estimation] with file = "data.csv" '
            'and columns = { u = "uEst", y = "yEst" }'
        )
    return tuple(_record(path, str(name), table, schema, time, header, field_name) for name, table in tables.items())


def _names(path: Path, doc: Mapping[str, Any], schema: Schema, time: str | None, header: bool) -> tuple[str, ...]:
    """The field names of headerless files: ``names``, else the [columns] names in declaration order."""
    if "names" not in doc:
        if header:
            return ()
        if time is not None:
            raise SpecError(
                f"{path}: header = false with time = {time!r}: give names = [...] with every field of the files in "
                f"order, the time column among them, e.g. names = [{json.dumps(time)}, "
                f"{', '.join(json.dumps(n) for n in schema.names()[:2])}, ...]"
            )
        return tuple(schema.names())
    names = doc["names"]
    if header:
        raise SpecError(f"{path}: names applies to files without a header row; add header = false, or remove names "
                        "(a header line names the fields)")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise SpecError(f'{path}: names must list the files\' fields in order, e.g. names = ["speed", "load", "NOx"] '
                        f'("" for a field not read); got {names!r}')
    seen = [n for n in names if n]
    twice = next((n for i, n in enumerate(seen) if n in seen[:i]), None)
    if twice is not None:
        raise SpecError(f"{path}: names lists {twice!r} twice; each field has its own name")
    return tuple(names)


# -- the whole spec ----------------------------------------------------------------------------
def load_spec(spec_path: str | Path) -> ImportSpec:
    """Read and check an import spec file (see :mod:`enginebench.datasets.importer` for its keys)."""
    path = Path(spec_path)
    if not path.is_file():
        raise SpecError(f"{path}: import spec not found; give the path of a .toml file")
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {one_line(str(exc))}; fix the spec") from exc
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start}); save the spec as UTF-8") from exc
    return spec_from_dict(doc, path)


def spec_from_dict(doc: Mapping[str, Any], path: Path) -> ImportSpec:
    """Check a spec document; ``path`` names it in messages and its folder anchors the file paths."""
    for key in doc:
        if key not in KEYS:
            raise _unknown(path, "key", key, ALLOWED_KEYS)
    present = set(doc) | ({"files"} if "records" in doc else set())
    missing = [k for k in ("name", "files", "dt", "columns") if k not in present]
    if missing == ["dt"] and "time" not in doc:
        raise SpecError(
            f"{path}: no time column and no dt; give dt = the sample period in seconds (without time = \"COL\", "
            "time is the sample index x dt, from 0 in each record)"
        )
    if missing:
        raise SpecError(f"{path}: missing required key(s) {', '.join(missing)}; {NEEDS}")
    v = KEYS.validate(doc, str(path), SpecError, name="{key}")
    files = _files(path, doc)
    time = v["time"]
    if time is None:
        for key in ("time_unit", "gap_tolerance"):
            if key in doc:
                raise SpecError(
                    f"{path}: {key} applies to a time column but the spec has no time key; remove {key} "
                    '(time is the sample index x dt) or name the column with time = "COL"'
                )
    time_unit = v["time_unit"]
    dt = float(v["dt"])
    gap = float(v["gap_tolerance"]) if v["gap_tolerance"] is not None else 1.5 * dt
    if gap < dt:
        raise SpecError(f"{path}: gap_tolerance = {gap:g} s is shorter than dt = {dt:g} s; make it at least dt")
    min_rows, drop, tol, delimiter = v["min_segment_rows"], v["drop_short_segments"], v["dt_tolerance"], v["delimiter"]
    segment, record = v["segment"], v["record"]
    if segment is not None and record is not None:
        raise SpecError(
            f"{path}: segment and record are both given; use record = \"COL\" (a new record where the value "
            "changes) or segment = \"COL\" (rows grouped by value), not both"
        )
    schema = _schema(path, doc["columns"])
    if time is not None and time in schema:
        raise SpecError(f"{path}: the time column {time!r} must not be declared in [columns]; time = names it")
    for reserved in (SEGMENT, TIME):
        if reserved in schema:
            raise SpecError(
                f"{path}: column name {reserved!r} in [columns] is reserved for the dataset's {reserved} column; "
                "rename that column in the file and the spec"
            )
    key, group = ("segment", segment) if segment is not None else ("record", record)
    if group is not None:
        if group in schema and schema[group].role != "group":
            raise SpecError(
                f"{path}: the {key} column {group!r} is declared with role {schema[group].role!r}; "
                f"a {key} column may only also be a group column"
            )
        if group == time:
            raise SpecError(f"{path}: the {key} column and the time column are both {time!r}; they must differ")
        if not files:
            raise SpecError(f"{path}: {key} = {group!r} names records inside the files of files = [...], but there are none")
    rate_column, period_column = v["rate_column"], v["period_column"]
    for k, col in (("rate_column", rate_column), ("period_column", period_column)):
        if col is not None and (col in schema or col in (time, group)):
            raise SpecError(
                f"{path}: {k} {col!r} is also a column the import reads; a rate or period column is only "
                "checked against dt, never imported: remove it from [columns] (or from time/segment/record)"
            )
    if rate_column is not None and rate_column == period_column:
        raise SpecError(f"{path}: rate_column and period_column are both {rate_column!r}; a column is one or the other")
    if not schema.outputs:
        raise SpecError(f'{path}: no column has role = "output"; declare at least one target in [columns]')
    header = v["header"]
    decimal, units_row = v["decimal"], v["units_row"]
    encoding = v["encoding"]
    try:
        codecs.lookup(encoding)
    except LookupError:
        raise SpecError(f'{path}: encoding = {json.dumps(encoding)} is not a text encoding Python knows; use e.g. '
                        '"utf-8" (the default), "cp1252" or "latin-1"') from None
    if units_row and not header:
        raise SpecError(f"{path}: units_row = true with header = false; a units row follows a header row: "
                        "set header = true, or remove units_row (declare the units in [columns])")
    names = _names(path, doc, schema, time, header)
    if decimal == "," and delimiter == ",":
        raise SpecError(f'{path}: decimal = "," with delimiter = ","; a decimal comma needs another delimiter: '
                        'set delimiter = ";" (the default with decimal = ","), "\\t" or "whitespace"')
    if not header and files:
        absent = [c for c in (*schema.names(), *([time] if time else []), *([group] if group else [])) if c not in names]
        if absent:
            raise SpecError(f"{path}: names has no field {absent[0]!r}; with header = false, names lists every field "
                            "of the files in order: the declared columns, the time and record columns")

    def field_name(i: int) -> str:
        return names[i] if i < len(names) and names[i] else POSITIONAL.format(i + 1)

    records = _records(path, doc, schema, time, header, field_name)
    taken = {f.stem: f for f in files} if group is None else {}
    for rec in records:
        if rec.file in files:
            raise SpecError(
                f"{path}: [records.{rec.name}] reads {rec.file.name!r}, which files also lists as a record of its "
                "own; list a file in files or name it in [records] tables, not both"
            )
        if rec.name in taken:
            raise SpecError(
                f"{path}: [records.{rec.name}] has the name of the record of file {taken[rec.name].name!r} in files; "
                "rename the [records] table"
            )
    return ImportSpec(
        path=path,
        name=v["name"],
        files=files,
        time=time,
        dt=dt,
        schema=schema,
        gap_tolerance=gap,
        time_unit=time_unit,
        segment=segment,
        record=record,
        delimiter=delimiter,
        provenance=v["provenance"],
        licence=v["licence"],
        min_segment_rows=min_rows,
        drop_short_segments=drop,
        dt_tolerance=float(tol),
        records=records,
        rate_column=rate_column,
        period_column=period_column,
        physical_model=parse_physical_model(doc.get("physical_model"), path),
        header=header,
        names=names,
        decimal=decimal,
        units_row=units_row,
        encoding=encoding,
        skip_lines=int(v["skip_lines"]),
        sheet=v["sheet"],
    )
