"""Reading the files of an import spec: CSV and Parquet readers, header checks, recorded units.

Each data file named by a spec (``files`` or a ``[records]`` table) is read once, with
every column the ways it is read need (``read_file``): its header checked against the
required columns, its cells by position, each row's line number and the units a Parquet
file records. ``importer`` assembles the records into a Dataset; kept apart so that
parsing a file and building the dataset are read and changed separately.

Every error is a one-line :class:`DataError` whose message starts with the path of the
file at fault.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from enginebench.datasets.import_spec import WHITESPACE, ImportSpec, RecordSpec, one_line
from enginebench.datasets.validate import DATETIME, check_columns
from enginebench.errors import DataError

CSV_SUFFIXES = (".csv", ".txt", ".tsv", ".dat")
PARQUET_SUFFIXES = (".parquet", ".pq")
EXCEL_SUFFIXES = (".xlsx", ".xlsm")  # read by datasets/excel.py (openpyxl, imported there on use)


# -- how each file is read ---------------------------------------------------------------------
@dataclass(frozen=True)
class FileUse:
    """One way a file is read: as a whole record of ``files`` (``record`` None) or as one [records] table."""

    file: Path
    record: RecordSpec | None = None

    def time(self, spec: ImportSpec) -> str | None:
        return spec.time if self.record is None else self.record.time

    def columns(self, spec: ImportSpec) -> dict[str, str]:
        """Declared column -> file column."""
        names = spec.schema.names()
        return {c: c for c in names} if self.record is None else dict(self.record.columns)

    def required(self, spec: ImportSpec) -> dict[str, str]:
        """File column -> what it is, for messages about a column the file lacks."""
        time = self.time(spec)
        if self.record is None:
            req = {time: "time column"} if time is not None else {}
            if spec.group_key is not None:
                req[spec.group_key] = "segment column" if spec.segment is not None else "record column"
            for c in spec.schema.names():
                req.setdefault(c, "declared column")
            return req
        what = f"[records.{self.record.name}] column"
        req = {time: f"[records.{self.record.name}] time column"} if time is not None else {}
        for col in self.record.columns.values():
            req.setdefault(col, what)
        return req

    def text_columns(self, spec: ImportSpec) -> list[str]:
        """File columns read as text: datetime stamps, group columns and the record/segment column."""
        cols = self.columns(spec)
        text = [cols[c.name] for c in spec.schema.columns if c.role == "group"]
        time = self.time(spec)
        if spec.time_unit == DATETIME and time is not None:
            text.append(time)
        if self.record is None and spec.group_key is not None:
            text.append(spec.group_key)
        return text


def file_uses(spec: ImportSpec) -> dict[Path, list[FileUse]]:
    """Every file with the ways it is read, in spec order (files first, then [records] tables)."""
    out: dict[Path, list[FileUse]] = {}
    for f in spec.files:
        out.setdefault(f, []).append(FileUse(f))
    for rec in spec.records:
        out.setdefault(rec.file, []).append(FileUse(rec.file, rec))
    return out


# -- reading one file --------------------------------------------------------------------------
@dataclass(frozen=True)
class FileTable:
    """A whole file: cells by position (``c0``, ``c1``, ...), the header, and each row's line number."""

    raw: pd.DataFrame
    header: list[str]
    lines: np.ndarray
    word: str
    units: dict[str, str]
    first_texts: list[str] | None = None
    pos: dict[str, int] = field(default_factory=dict)

    def column(self, name: str) -> pd.Series:
        return self.raw[f"c{self.pos[name]}"]


def too_few_rows(file: Path, n: int, word: str, record: str | None = None) -> None:
    """A file (or a record of a wide file, ``record``) needs at least 2 data rows."""
    if n >= 2:
        return
    if record is not None:
        has = "has no data rows" if n == 0 else f"has only 1 data row ({word} {2 if word == 'line' else 1})"
        raise DataError(f"{file}: record {record!r} {has}; a record needs at least 2 data rows")
    if n == 0:
        what = "has a header but no data rows" if word == "line" else "has no data rows"
        raise DataError(f"{file}: the file {what}; a file needs at least 2 data rows")
    first = 2 if word == "line" else 1
    raise DataError(f"{file}: only 1 data row ({word} {first}); a file needs at least 2 data rows to form a segment")


def _check_header(file: Path, header: list[str], required: dict[str, str], delim: str | None,
                  line: int = 1) -> dict[str, int]:
    """Every required column is in the header (on ``line``), once; returns each name's first position."""
    check_columns(header, required, source=str(file), delimiter=delim)
    where = f"{file}, line {line}:" if delim is not None else f"{file}:"
    for name in required:
        at = [i + 1 for i, h in enumerate(header) if h == name]
        if len(at) > 1:
            raise DataError(f"{where} column {name!r} appears {len(at)} times in the header (fields {at}); rename all but one")
    return {h: i for i, h in reversed(list(enumerate(header)))}


@dataclass(frozen=True)
class CsvLayout:
    """How the spec says its CSV files are written: delimiter, decimal mark, encoding, the lines above the
    header (``top``), a units row, a header at all. Line numbers in messages are the file's own."""

    delim: str
    decimal: str
    encoding: str
    top: int
    header: bool
    units_row: bool

    @classmethod
    def of(cls, spec: ImportSpec, file: Path) -> "CsvLayout":
        encoding = "utf-8-sig" if spec.encoding.lower().replace("_", "-") in ("utf-8", "utf8") else spec.encoding
        return cls(spec.delimiter_for(file), spec.decimal, encoding, spec.skip_lines, spec.header, spec.units_row)

    @property
    def first_line(self) -> int:
        """The file line of the header (or, without one, of the first data row)."""
        return self.top + 1

    @property
    def first_data_line(self) -> int:
        return self.top + 1 + int(self.header) + int(self.units_row)

    def skipped(self) -> list[int]:
        """0-based file lines pandas skips: those above the header and the units row."""
        return [*range(self.top), *([self.top + 1] if self.units_row else [])]

    def undecodable(self, file: Path, exc: UnicodeDecodeError) -> DataError:
        name = "UTF-8" if self.encoding == "utf-8-sig" else self.encoding
        return DataError(
            f"{file}: not {name} text ({exc.reason} at byte {exc.start}); set encoding = \"cp1252\" (Windows "
            "exports; or the file's own encoding) in the spec, or save the file as UTF-8"
        )


def _read_csv(file: Path, spec: ImportSpec, required: dict[str, str], text_cols: list[str]) -> FileTable:
    lay = CsvLayout.of(spec, file)
    delim = lay.delim
    try:
        with open(file, encoding=lay.encoding, newline="") as fh:
            above = [fh.readline() for _ in range(lay.top)]
            first = fh.readline()
            second = fh.readline()
            third = fh.readline()
            rest_blank = not first.strip() and not second.strip() and not third.strip() and not fh.read(1 << 16).strip()
    except UnicodeDecodeError as exc:
        raise lay.undecodable(file, exc) from exc
    if lay.top and not above[-1]:
        n = sum(1 for a in above if a)
        raise DataError(f"{file}: has {n} line{'s' if n != 1 else ''}, but skip_lines = {lay.top} skips the first "
                        f"{lay.top}; set skip_lines to the number of lines above the header")
    if not first.strip():
        if rest_blank:
            what = "the file is empty" if not lay.top else f"nothing after the {lay.top} skipped lines"
            raise DataError(f"{file}: {what}; it needs a header line and at least 2 data rows")
        where = f" (after skip_lines = {lay.top})" if lay.top else ""
        raise DataError(f"{file}, line {lay.first_line}: blank; the header must be on line {lay.first_line}{where}")
    fields = [h.strip() for h in _fields(first, delim)]
    if not spec.header:
        return _read_headerless(file, spec, required, text_cols, fields, lay)
    header = fields
    _no_header_hint(file, header, required, lay)
    _header_below_hint(file, header, required, lay)
    pos = _check_header(file, header, required, delim, lay.first_line)
    units: dict[str, str] = {}
    if lay.units_row:
        units = _units_row(file, header, _fields(second, delim) if second.strip() else [], lay.first_line + 1)
        second = third
    else:
        _units_row_hint(file, pos, required, text_cols, second, third, lay)
    first_texts = None
    if second.strip():
        first_texts = [f.strip() for f in _fields(second, delim)]
    raw = _parse_fields(file, lay, header, pos, required, text_cols)
    start = lay.first_data_line
    return FileTable(raw, header, np.arange(start, len(raw) + start), "line", units, first_texts, pos)


PREAMBLE_LINES = 50
"""How far down a file the header is looked for when line 1 (after ``skip_lines``) is not it."""


def _header_below_hint(file: Path, header: list[str], required: dict[str, str], lay: CsvLayout) -> None:
    """The required columns not on the header line but together on a line below it: a preamble (test-bench
    software writes one); say which line holds the header and what to set."""
    if all(h in header for h in required):
        return
    try:
        with open(file, encoding=lay.encoding, newline="") as fh:
            for k in range(PREAMBLE_LINES + lay.top):
                line = fh.readline()
                if not line:
                    return
                if k <= lay.top:
                    continue
                for delim in (lay.delim, *(d for d in (",", ";", "\t", "|") if d != lay.delim)):
                    if set(required) <= {f.strip() for f in _fields(line, delim)}:
                        also = "" if delim == lay.delim else f" and delimiter = {json.dumps(delim)}"
                        raise DataError(
                            f"{file}, line {k + 1}: holds the header ({', '.join(repr(r) for r in list(required)[:3])}"
                            f"{', ...' if len(required) > 3 else ''}), line {lay.first_line} does not: set "
                            f"skip_lines = {k}{also} in the spec (the lines above the header are not read)"
                        )
    except UnicodeDecodeError:
        return


_BRACKETED = re.compile(r"^\s*[\[(](.*)[\])]\s*$")


def _units_row(file: Path, header: list[str], fields: list[str], line: int) -> dict[str, str]:
    """The units row (file ``line``) of a file with ``units_row``: each named field's unit ("[rpm]" and "(rpm)"
    read as "rpm")."""
    if len(fields) != len(header):
        raise DataError(
            f"{file}, line {line}: the units row has {len(fields)} fields where the header has {len(header)}; "
            f"give every field a unit (blank for none), or remove units_row from the spec if line {line} is data"
        )
    return _units_of(header, fields)


def _units_of(header: list[str], fields: list[str]) -> dict[str, str]:
    """Each named field's unit from a units row's texts ("[rpm]" and "(rpm)" read as "rpm"; blank: none)."""
    units = {}
    for name, raw in zip(header, fields):
        unit = raw.strip()
        m = _BRACKETED.match(unit)
        unit = m.group(1).strip() if m else unit
        if name and unit:
            units[name] = unit
    return units


def _is_number(text: str, decimal: str) -> bool:
    try:
        float(text.strip().replace(decimal, "."))
    except ValueError:
        return False
    return True


def _units_row_hint(file: Path, pos: dict[str, int], required: dict[str, str], text_cols: list[str], second: str,
                    third: str, lay: CsvLayout) -> None:
    """The line under the header holding text in every numeric column the spec reads while the next holds
    numbers: a units row the spec does not declare; say so and what to set (not "'rpm' is not a number")."""
    if not second.strip() or not third.strip():
        return
    line2, line3 = _fields(second, lay.delim), _fields(third, lay.delim)
    numeric = [pos[c] for c in required if c not in text_cols and pos[c] < min(len(line2), len(line3))]
    if not numeric:
        return
    texts = [line2[i].strip() for i in numeric]
    if any(_is_number(t, lay.decimal) for t in texts if t) or not any(texts):
        return
    if not all(_is_number(line3[i], lay.decimal) for i in numeric if line3[i].strip()):
        return
    shown = ", ".join(repr(t) for t in texts[:4]) + (", ..." if len(texts) > 4 else "")
    at = lay.first_line + 1
    raise DataError(
        f"{file}, line {at}: text where the spec reads numbers ({shown}) and numbers on line {at + 1}: a units "
        "row? set units_row = true in the spec (the units are then read from it)"
    )


def _parse_fields(file: Path, lay: CsvLayout, header: list[str], pos: dict[str, int], required: dict[str, str],
                  text_cols: list[str]) -> pd.DataFrame:
    """The file's cells (``_parse_csv``), text columns as text; a float column that overflowed holds inf where
    the file holds text such as 1e309: it is re-read as text so that the error quotes the value as written."""
    text_pos = sorted({pos[c] for c in text_cols})
    raw = _parse_csv(file, lay, len(header), text_pos)
    overflow = [
        pos[c]
        for c in required
        if pos[c] not in text_pos
        and pd.api.types.is_float_dtype(raw[f"c{pos[c]}"].dtype)
        and np.isinf(raw[f"c{pos[c]}"].to_numpy()).any()
    ]
    if overflow:
        raw = _parse_csv(file, lay, len(header), sorted(set(text_pos) | set(overflow)))
    if lay.decimal != ".":  # a column pandas left as text (a bad cell in it) is checked with '.' decimals
        for c in required:
            col = f"c{pos[c]}"
            if pos[c] not in text_pos and not pd.api.types.is_numeric_dtype(raw[col].dtype):
                raw[col] = raw[col].str.replace(lay.decimal, ".", regex=False)
    return raw


def _fields(line: str, delim: str) -> list[str]:
    """One CSV line's fields (a field of any length: the csv module's 128 KiB limit lifted for this line)."""
    if delim == WHITESPACE:
        return line.split()
    limit = csv.field_size_limit()
    csv.field_size_limit(max(limit, len(line) + 1))
    try:
        return next(csv.reader([line.rstrip("\r\n")], delimiter=delim))
    finally:
        csv.field_size_limit(limit)


def _no_header_hint(file: Path, header: list[str], required: dict[str, str], lay: CsvLayout) -> None:
    """A first line of numbers read as a header: the file has no header row; say so and what to set."""
    if all(h in header for h in required) or not header:
        return
    if not all(_is_number(h, lay.decimal) for h in header):
        return
    raise DataError(
        f"{file}, line {lay.first_line}: holds numbers ({', '.join(header[:3])}{', ...' if len(header) > 3 else ''}), "
        f"not column names: the file has no header row; set header = false in the spec (its {len(header)} fields are "
        "then named in file order by names = [...], default the [columns] order)"
    )


def _read_headerless(file: Path, spec: ImportSpec, required: dict[str, str], text_cols: list[str], first: list[str],
                     lay: CsvLayout) -> FileTable:
    """A file without a header row: its fields named by ``spec.names`` (else "field k"), data from its first line."""
    header = [spec.field_name(i) for i in range(len(first))]
    missing = [c for c in required if c not in header]
    if missing:
        named = [n for n in spec.names if n]
        raise DataError(
            f"{file}, line {lay.first_line}: {len(first)} fields, but with header = false {required[missing[0]]} "
            f"{missing[0]!r} is field {_field_position(spec, missing[0])} of the files' names ({len(named)} named); "
            "give every field its name in file order (names = [...], or the [columns] order)"
        )
    pos = {h: i for i, h in enumerate(header)}
    raw = _parse_fields(file, lay, header, pos, required, text_cols)
    start = lay.first_data_line
    return FileTable(raw, header, np.arange(start, len(raw) + start), "line", {}, first, pos)


def _field_position(spec: ImportSpec, name: str) -> str:
    at = [i + 1 for i, n in enumerate(spec.names) if n == name]
    return str(at[0]) if at else "?"


def _parse_csv(file: Path, lay: CsvLayout, n_fields: int, text_pos: list[int]) -> pd.DataFrame:
    """Every field by position; ``text_pos`` kept as text, the others parsed as numbers where they can be.

    Columns holding anything that is not a number come back as text, which
    :func:`validate.parse_numbers` then reports with its line. pandas' C parser reads every file: pyarrow's
    CSV reader, tried for large files, cost 1.4x its CPU on one thread (docs/benchmarks.md, long recordings).
    """
    try:
        return pd.read_csv(
            file,
            sep=r"\s+" if lay.delim == WHITESPACE else lay.delim,
            header=0 if lay.header else None,
            names=[f"c{i}" for i in range(n_fields)],
            index_col=False,
            dtype={f"c{i}": str for i in text_pos},
            skip_blank_lines=False,
            skiprows=lay.skipped() or None,
            decimal=lay.decimal,
            encoding=lay.encoding,
        )
    except pd.errors.ParserError as exc:
        m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
        if m:
            raise DataError(
                f"{file}, line {m.group(2)}: {m.group(3)} fields where the "
                f"{'header' if lay.header else 'first line'} has {m.group(1)} "
                "(a stray delimiter, or decimal commas: then set decimal = \",\" and the file's delimiter); fix the row"
            ) from exc
        raise DataError(f"{file}: cannot parse the CSV ({one_line(str(exc))}); check delimiter and quoting") from exc
    except UnicodeDecodeError as exc:
        raise lay.undecodable(file, exc) from exc


def _recorded_units(schema: pa.Schema) -> dict[str, str]:
    """Units a Parquet file records: enginebench metadata, else an Arrow field's unit metadata."""
    units: dict[str, str] = {}
    raw = (schema.metadata or {}).get(b"enginebench")
    if raw is not None:
        try:
            units = {k: v.get("unit", "") for k, v in json.loads(raw).get("schema", {}).items()}
        except (ValueError, AttributeError):
            units = {}
    for fld in schema:
        meta = fld.metadata or {}
        for key in (b"unit", b"units"):
            if key in meta:
                units[fld.name] = meta[key].decode("utf-8", "replace")
    return {k: v for k, v in units.items() if v}


def _read_parquet(file: Path, spec: ImportSpec, required: dict[str, str], times: list[str]) -> FileTable:
    try:
        schema = pq.read_schema(file)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DataError(f"{file}: not a Parquet file ({one_line(str(exc))}); give CSV or Parquet files") from exc
    header = list(schema.names)
    pos = _check_header(file, header, required, None)
    try:
        frame = pq.read_table(file).to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise DataError(
            f"{file}: cannot read the Parquet data ({one_line(str(exc))}); the file may be damaged"
        ) from exc
    frame.columns = [f"c{i}" for i in range(len(header))]
    too_few_rows(file, len(frame), "row")
    for t in times:
        if spec.time_unit != DATETIME and pd.api.types.is_datetime64_any_dtype(frame[f"c{pos[t]}"].dtype):
            raise DataError(
                f"{file}, column {t!r}: holds timestamps but time_unit = {spec.time_unit!r}; "
                'set time_unit = "datetime"'
            )
    return FileTable(frame, header, np.arange(1, len(frame) + 1), "row", _recorded_units(schema), None, pos)


def _read_excel(file: Path, spec: ImportSpec, required: dict[str, str], text_cols: list[str]) -> FileTable:
    """One sheet of a workbook (``datasets/excel.py``), read as a CSV file is; rows numbered as Excel shows them."""
    from enginebench.datasets.excel import cell_text, read_sheet

    cells, rows = read_sheet(file, spec)
    if spec.header:
        header = [cell_text(v) for v in cells.iloc[0]]
        pos = _check_header(file, header, required, None)
    else:
        header = [spec.field_name(i) for i in range(cells.shape[1])]
        missing = [c for c in required if c not in header]
        if missing:
            raise DataError(f"{file}, row {rows[0]}: {cells.shape[1]} columns, but with header = false "
                            f"{required[missing[0]]} {missing[0]!r} is field {_field_position(spec, missing[0])} "
                            "of the files' names; give every column its name in order (names = [...], or the "
                            "[columns] order)")
        pos = {h: i for i, h in enumerate(header)}
    start = int(spec.header) + int(spec.units_row)
    units = _units_of(header, [cell_text(v) for v in cells.iloc[1]]) if spec.units_row and len(cells) > 1 else {}
    data = cells.iloc[start:].reset_index(drop=True)
    too_few_rows(file, len(data), "row")
    text_pos = {pos[c] for c in text_cols}
    raw = pd.DataFrame({f"c{i}": (data[i].map(lambda v: None if pd.isna(v) else str(v)) if i in text_pos
                                  else data[i]) for i in range(data.shape[1])})
    first_texts = [cell_text(v) for v in data.iloc[0]]
    return FileTable(raw, header, rows[start:], "row", units, first_texts, pos)


def read_file(file: Path, spec: ImportSpec, uses: list[FileUse]) -> FileTable:
    """Read ``file`` once, with every column the ways it is read (``uses``) need."""
    rec = uses[0].record
    if not file.exists():
        named = f"named in [records.{rec.name}]" if rec is not None else "listed in files"
        raise DataError(f"{file}: file not found ({named} of {spec.path}; paths are relative to the spec)")
    if file.is_dir():
        raise DataError(f"{file}: is a folder; {'list data files in files' if rec is None else 'name a data file'}")
    if not file.is_file():  # a named pipe or a device would block the read, or never end
        raise DataError(f"{file}: not a regular file (a named pipe or a device); give the data file itself")
    required: dict[str, str] = {}
    text: list[str] = []
    for use in uses:
        for k, v in use.required(spec).items():
            required.setdefault(k, v)
        text += use.text_columns(spec)
    suffix = file.suffix.lower()
    if suffix in PARQUET_SUFFIXES:
        times = [t for t in (u.time(spec) for u in uses) if t is not None]
        return _read_parquet(file, spec, required, times)
    if suffix in EXCEL_SUFFIXES:
        return _read_excel(file, spec, required, text)
    if suffix in CSV_SUFFIXES:
        if file.stat().st_size == 0:
            raise DataError(f"{file}: the file is empty; it needs a header line and at least 2 data rows")
        return _read_csv(file, spec, required, text)
    raise DataError(
        f"{file}: unsupported file type {suffix or '(none)'!r}; give CSV ({', '.join(CSV_SUFFIXES)}), "
        f"Parquet ({', '.join(PARQUET_SUFFIXES)}) or Excel ({', '.join(EXCEL_SUFFIXES)}) files"
        + ("; save an .xls workbook as .xlsx" if suffix == ".xls" else "")
    )
