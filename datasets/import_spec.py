"""The TOML import spec: its keys, their checks, and the checked :class:`ImportSpec`.

Every key is described in :mod:`enginebench.datasets.importer` (the module users read);
this module only parses and checks them. A spec comes from a TOML file
(:func:`load_spec`) or from a dictionary built in code (:func:`spec_from_dict`, what the
built-in importers of published records use), so both go through the same checks. Every
mistake is one :class:`SpecError` line starting with the spec's path.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from enginebench.datasets.dataset import SEGMENT, TIME
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.validate import DATETIME, TIME_UNITS
from enginebench.errors import DataError, SpecError

REQUIRED_KEYS = ("name", "dt", "columns")
OPTIONAL_KEYS = (
    "files",
    "records",
    "time",
    "time_unit",
    "gap_tolerance",
    "segment",
    "record",
    "rate_column",
    "period_column",
    "delimiter",
    "provenance",
    "licence",
    "min_segment_rows",
    "drop_short_segments",
    "dt_tolerance",
)
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

    def delimiter_for(self, file: Path) -> str:
        """The declared delimiter, else a tab for .tsv files and a comma otherwise."""
        if self.delimiter is not None:
            return self.delimiter
        return "\t" if file.suffix.lower() == ".tsv" else ","

    @property
    def group_key(self) -> str | None:
        """The column that names records inside a file (``segment`` or ``record``), if any."""
        return self.segment if self.segment is not None else self.record


# -- small checks --------------------------------------------------------------------------
def one_line(text: str) -> str:
    return " ".join(str(text).split())


def _unknown(where: Path, kind: str, key: str, allowed: tuple[str, ...]) -> SpecError:
    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return SpecError(f"{where}: unknown {kind} {key!r}{hint}; allowed: {', '.join(allowed)}")


def _number(path: Path, doc: Mapping[str, Any], key: str, default: float | None = None) -> float:
    v = doc.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise SpecError(f"{path}: {key} must be a positive number of seconds, got {v!r}")
    return float(v)


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
    resolved = tuple(path.parent / f for f in files)
    if len(set(resolved)) < len(resolved):
        twice = next(f for i, f in enumerate(files) if resolved[i] in resolved[:i])
        raise SpecError(f"{path}: file {twice!r} is listed twice in files")
    return resolved


def _record(path: Path, name: str, table: Any, schema: Schema, time: str | None) -> RecordSpec:
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


def _records(path: Path, doc: Mapping[str, Any], schema: Schema, time: str | None) -> tuple[RecordSpec, ...]:
    if "records" not in doc:
        return ()
    tables = doc["records"]
    if not isinstance(tables, dict) or not tables:
        raise SpecError(
            f'{path}: records must hold [records.NAME] tables, e.g. [records.estimation] with file = "data.csv" '
            'and columns = { u = "uEst", y = "yEst" }'
        )
    return tuple(_record(path, str(name), table, schema, time) for name, table in tables.items())


def _optional_column(path: Path, doc: Mapping[str, Any], key: str) -> str | None:
    return _text(path, doc, key) if key in doc else None


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
        if key not in ALLOWED_KEYS:
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
    files = _files(path, doc)
    time = _text(path, doc, "time") if "time" in doc else None
    if time is None:
        for key in ("time_unit", "gap_tolerance"):
            if key in doc:
                raise SpecError(
                    f"{path}: {key} applies to a time column but the spec has no time key; remove {key} "
                    '(time is the sample index x dt) or name the column with time = "COL"'
                )
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
    segment = _optional_column(path, doc, "segment")
    record = _optional_column(path, doc, "record")
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
    rate_column = _optional_column(path, doc, "rate_column")
    period_column = _optional_column(path, doc, "period_column")
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
    records = _records(path, doc, schema, time)
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
        name=_text(path, doc, "name"),
        files=files,
        time=time,
        dt=dt,
        schema=schema,
        gap_tolerance=gap,
        time_unit=time_unit,
        segment=segment,
        record=record,
        delimiter=delimiter,
        provenance=_text(path, doc, "provenance", "", empty_ok=True),
        licence=_text(path, doc, "licence", "", empty_ok=True),
        min_segment_rows=min_rows,
        drop_short_segments=drop,
        dt_tolerance=float(tol),
        records=records,
        rate_column=rate_column,
        period_column=period_column,
    )
