"""Checks that turn a raw table into clean segments, or reject it naming file, column and line.

:func:`validate_frame` takes one parsed file (every cell may still be the text read from
the file, plus a ``segment`` column) and returns the frame a :class:`Dataset` holds:
``segment``, ``time`` in seconds and the schema's columns, rows grouped by segment in
order of first appearance. Gaps longer than ``gap_tolerance`` split a segment into
``"{segment}#{k}"`` pieces (k = 1, 2, ...; the first piece keeps its id). Missing
samples shorter than the tolerance are kept as they are (no interpolation).

Line numbers are those a user sees in a CSV file: the header is line 1, the first data
row line 2 (a Parquet file has no lines: there "row N" counts data rows from 1). When a
file breaks several rules, the rule checked first wins, in this order: columns, time
stamps, each declared column in spec order, constant columns, time order, sampling
period, segment length. Within a rule the earliest line is reported.
"""

from __future__ import annotations

import difflib
import json
import re
import warnings
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
import pyarrow as pa

from enginebench.datasets.dataset import SEGMENT, TIME
from enginebench.datasets.schema import Schema
from enginebench.errors import DataError, SpecError

TIME_UNITS: dict[str, float] = {"s": 1.0, "ms": 1e-3, "min": 60.0, "h": 3600.0}
"""Seconds per unit of a numeric time column; ``"datetime"`` means ISO 8601 stamps."""
DATETIME = "datetime"
NUMERIC_ROLES = ("input", "output", "internal")
"""Roles whose columns must be finite numbers on every row."""

_UNIT_IN_NAME = re.compile(r"^(.*?)\s*(?:\[[^\]]*\]|\([^)]*\)|\{[^}]*\})\s*$")
_DECIMAL_COMMA = re.compile(r"^\s*[-+]?\d+,\d+\s*$")
_OFFSET = re.compile(r"[T ]\d{1,2}:\d{2}(?::\d{2}(?:[.,]\d+)?)?\s*(Z|[+-]\d{2}(?::?\d{2})?)\s*$", re.IGNORECASE)
_DELIMITERS = (",", ";", "\t", "|")
_MAX_LISTED = 12


def _num(x: float) -> str:
    return f"{float(x):.10g}"


SHOWN_CHARS = 80
"""A cell longer than this is shown by its start, its length and its end (an error line stays a line)."""


def show_cell(v: Any) -> str:
    """A cell as the user wrote it: text verbatim (a long one cut in the middle), numbers without float noise."""
    if isinstance(v, str):
        if len(v) > SHOWN_CHARS:
            return f"{v[:40]}...({len(v)} characters)...{v[-20:]}"
        return v
    if isinstance(v, (pd.Timestamp, np.datetime64)):
        return pd.Timestamp(v).isoformat()
    if isinstance(v, (int, float, np.number)):
        return _num(v)
    return str(v)


def _rows(n: int) -> str:
    return f"{int(n)} row" if n == 1 else f"{int(n)} rows"


def _names(names: Sequence[str]) -> str:
    shown = ", ".join(repr(str(n)) for n in names[:_MAX_LISTED])
    return shown if len(names) <= _MAX_LISTED else f"{shown}, ... ({len(names)} in all)"


def _first(mask: np.ndarray, lines: np.ndarray) -> int:
    """Position of the true entry of ``mask`` with the smallest line number."""
    pos = np.flatnonzero(mask)
    return int(pos[np.argmin(lines[pos])])


# -- columns ------------------------------------------------------------------------------
def column_hint(name: str, header: Sequence[str]) -> str:
    """Why ``name`` may be missing from ``header``: a unit in a header name, case, a near miss, else the columns."""
    for h in header:
        m = _UNIT_IN_NAME.match(str(h))
        if m and m.group(1) == name:
            return (
                f"the header has {str(h)!r}: units belong in [columns] of the spec, not in the header; "
                f"rename that header to {name!r}"
            )
    lower = {str(h).lower(): str(h) for h in header}
    if name.lower() in lower:
        return f"did you mean {lower[name.lower()]!r}? (names are case-sensitive)"
    close = difflib.get_close_matches(name, [str(h) for h in header], n=1, cutoff=0.75)
    if close:
        return f"did you mean {close[0]!r}?"
    return f"the file's columns are {_names([str(h) for h in header])}"


def check_columns(
    header: Sequence[str],
    required: Mapping[str, str],
    *,
    source: str,
    delimiter: str | None = None,
) -> None:
    """Raise DataError when a required column is absent from ``header``.

    ``required`` maps each name to what it is ("declared column", "time column", ...).
    The message suggests the likely cause: another delimiter in the header line, a unit
    written into a header name, or a near-miss spelling.
    """
    present = {str(h) for h in header}
    missing = [n for n in required if n not in present]
    if not missing:
        return
    first = missing[0]
    what = f"{required[first]} {first!r}"
    more = f" (nor {_names(missing[1:])})" if len(missing) > 1 else ""
    if delimiter is not None:
        text = "".join(str(h) for h in header)
        for cand in _DELIMITERS:
            if cand == delimiter or cand not in text:
                continue
            split = {part.strip() for h in header for part in str(h).split(cand)}
            if first in split or any(_UNIT_IN_NAME.sub(r"\1", p) == first for p in split):
                raise DataError(
                    f"{source}: {what} is not in the header read with delimiter {delimiter!r}{more}; "
                    f"the header contains {cand!r}: set delimiter = {json.dumps(cand)} in the spec"
                )
    raise DataError(f"{source}: {what} is not in the file{more}; {column_hint(first, header)}")


# -- values -------------------------------------------------------------------------------
def parse_numbers(
    values: pd.Series, *, source: str, column: str, lines: np.ndarray, word: str = "line"
) -> np.ndarray:
    """Cells as float64 (missing cells become NaN); text that is not a number raises DataError."""
    if values.dtype == np.float64:  # parsed as numbers already: nothing can be text
        return values.to_numpy(dtype=float, copy=False)
    x = pd.to_numeric(values, errors="coerce")
    x = np.asarray(pd.Series(x).to_numpy(dtype=float, na_value=np.nan), dtype=float)
    bad = np.isnan(x) & values.notna().to_numpy()
    if bad.any():
        i = _first(bad, lines)
        raw = values.iloc[i]
        comma = isinstance(raw, str) and _DECIMAL_COMMA.match(raw)
        hint = ' (a decimal comma? set decimal = "," in the import spec)' if comma else ""
        raise DataError(
            f"{source}, column {column!r}, {word} {lines[i]}: {show_cell(raw)!r} is not a number{hint}; "
            "fix or remove the value"
        )
    return x


def _require_present(
    missing: np.ndarray, *, source: str, column: str, lines: np.ndarray, word: str, what: str
) -> None:
    """No cell ``missing``: a column missing everywhere, else the first missing row (a ``what``), is a DataError."""
    if missing.all():
        raise DataError(
            f"{source}, column {column!r}: every value is missing; remove the column from [columns] or fill it"
        )
    if missing.any():
        i = _first(missing, lines)
        raise DataError(f"{source}, column {column!r}, {word} {lines[i]}: missing {what}; fill it or remove the row")


def _require_finite(
    x: np.ndarray, raw: pd.Series, *, source: str, column: str, lines: np.ndarray, word: str, what: str = "value"
) -> None:
    if np.isfinite(x).all():  # the common case in one pass
        return
    _require_present(np.isnan(x), source=source, column=column, lines=lines, word=word, what=what)
    inf = np.isinf(x)
    if inf.any():
        i = _first(inf, lines)
        raise DataError(
            f"{source}, column {column!r}, {word} {lines[i]}: {show_cell(raw.iloc[i])!r} is infinite "
            "(outside the float64 range); fix the value"
        )


def _factorize_text(raw: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    """Codes (first-appearance order) and stripped text labels of a column without missing cells."""
    if isinstance(raw.dtype, pd.CategoricalDtype) and len(raw.cat.categories) == 1:  # one value: its codes
        return raw.cat.codes.to_numpy(), np.asarray([str(raw.cat.categories[0]).strip()], dtype=object)
    codes, uniq = pd.factorize(raw)
    labels = pd.Index(uniq).astype(str).str.strip()
    lc, lu = pd.factorize(labels)
    return lc[codes], np.asarray(lu, dtype=object)


def _text_array(codes: np.ndarray, labels: Sequence[str]) -> Any:
    """``labels[codes]`` as pandas' default text column, built through Arrow (fast for long columns)."""
    dic = pa.DictionaryArray.from_arrays(pa.array(codes, pa.int64()), pa.array(list(labels), pa.large_string()))
    return dic.cast(pa.large_string()).to_pandas().array


def _run_text(names: Sequence[str], lengths: np.ndarray) -> Any:
    """``names[k]`` repeated ``lengths[k]`` times, one after another, as pandas' default text column: built from
    Arrow buffers (the text and its offsets), no work per row (a segment column of 1e7 rows in 0.1 s)."""
    enc = [str(s).encode("utf-8") for s in names]
    reps = np.asarray(lengths, dtype=np.int64)
    n = int(reps.sum())
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.repeat(np.array([len(e) for e in enc], dtype=np.int64), reps), out=offsets[1:])
    data = b"".join(e * int(m) for e, m in zip(enc, reps))
    return pa.LargeStringArray.from_buffers(n, pa.py_buffer(offsets), pa.py_buffer(data)).to_pandas().array


def _labels(
    raw: pd.Series, *, source: str, column: str, lines: np.ndarray, word: str
) -> tuple[np.ndarray, np.ndarray]:
    """Group keys as (codes, text labels); a missing key raises DataError."""
    _require_present(raw.isna().to_numpy(), source=source, column=column, lines=lines, word=word, what="key")
    return _factorize_text(raw)


# -- time ---------------------------------------------------------------------------------
def _offset_name(off: Any) -> str:
    if not isinstance(off, str):
        return "no UTC offset"
    off = off.upper()
    if off == "Z":
        return "offset +00:00"
    digits = off[1:].replace(":", "")
    return f"offset {off[0]}{digits[:2]}:{digits[2:4] or '00'}"


def parse_time(
    raw: pd.Series, unit: str, *, source: str, column: str, lines: np.ndarray, word: str = "line"
) -> tuple[np.ndarray, float, str | None]:
    """Time stamps as exact ticks and the seconds per tick: ``(ticks, scale, zone)``.

    Numeric units give float ticks in the file's unit. ``"datetime"`` gives int64
    nanoseconds since 1970-01-01 UTC; stamps must all carry the same UTC offset or none
    (``zone`` is that offset, ``"none"`` for naive stamps, taken as UTC), else
    "mixed time zones". Ticks keep steps exact so the sampling check is not fooled by
    rounding of large epoch values.
    """
    if unit != DATETIME:
        if unit not in TIME_UNITS:
            raise SpecError(
                f"{source}: unknown time_unit {unit!r}; use one of {', '.join(TIME_UNITS)} or {DATETIME!r}"
            )
        x = parse_numbers(raw, source=source, column=column, lines=lines, word=word)
        _require_finite(x, raw, source=source, column=column, lines=lines, word=word, what="time stamp")
        return x, TIME_UNITS[unit], None
    missing = raw.isna().to_numpy()
    if missing.any():
        i = _first(missing, lines)
        raise DataError(
            f"{source}, column {column!r}, {word} {lines[i]}: missing time stamp; fill it or remove the row"
        )
    if pd.api.types.is_datetime64_any_dtype(raw.dtype):
        zone = str(raw.dt.tz) if raw.dt.tz is not None else "none"
        stamps = raw.dt.tz_convert("UTC").dt.tz_localize(None) if raw.dt.tz is not None else raw
    else:
        if pd.api.types.is_numeric_dtype(raw.dtype):
            raise DataError(
                f"{source}, column {column!r}, {word} {lines[0]}: {show_cell(raw.iloc[0])!r} is a number but "
                'time_unit = "datetime" expects ISO 8601 stamps; set time_unit to s, ms, min or h'
            )
        text = raw.astype(str)
        parsed = pd.to_datetime(text, format="ISO8601", utc=True, errors="coerce")
        bad = parsed.isna().to_numpy()
        if bad.any():
            i = _first(bad, lines)
            raise DataError(
                f"{source}, column {column!r}, {word} {lines[i]}: {text.iloc[i]!r} is not an ISO 8601 time stamp; "
                "fix it (e.g. 2024-05-01T12:00:00+00:00)"
            )
        offsets = text.str.extract(_OFFSET, expand=False)
        norm = offsets.map(_offset_name, na_action=None).to_numpy(dtype=object)
        differ = norm != norm[0]
        if differ.any():
            j = _first(differ, lines)
            raise DataError(
                f"{source}, column {column!r}: mixed time zones: {word} {lines[0]} has {norm[0]}, "
                f"{word} {lines[j]} has {norm[j]}; write every stamp with one UTC offset (e.g. all in UTC)"
            )
        zone = "none" if norm[0] == "no UTC offset" else norm[0].removeprefix("offset ")
        stamps = parsed.dt.tz_localize(None)
    ticks = stamps.to_numpy(dtype="datetime64[ns]").view(np.int64)
    return ticks, 1e-9, zone


# -- whole-table checks -------------------------------------------------------------------
def check_not_constant(
    frame: pd.DataFrame | Mapping[str, np.ndarray],
    schema: Schema,
    *,
    source: str,
    scope: str = "the whole file",
    shown: Mapping[str, str] | None = None,
) -> None:
    """Raise DataError when an input or output column holds one value on every row.

    ``shown`` maps a schema column to the file column named in the message.
    """
    for c in schema.columns:
        if c.role not in ("input", "output"):
            continue
        x = np.asarray(frame[c.name], dtype=float)
        if len(x) and np.nanmin(x) == np.nanmax(x):
            raise DataError(
                f"{source}, column {(shown or {}).get(c.name, c.name)!r}: constant value {_num(x[0])} over {scope}; a constant {c.role} "
                "carries no information - remove it from [columns]"
            )


def _index_ticks(starts: np.ndarray, n: int) -> np.ndarray:
    """Each sorted row's sample index within its segment (``starts``: the sorted row where each segment starts)."""
    return np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))


@dataclass(frozen=True)
class _Sorted:
    """The rows grouped by segment in order of first appearance, file order kept inside a segment."""

    order: np.ndarray | None
    """The file row of each sorted row (None: the file's rows are in that order already)."""
    codes: np.ndarray
    """Its segment, as an index into ``ids``."""
    ids: np.ndarray
    """The segment ids, first appearance first."""
    starts: np.ndarray
    """The sorted row where each segment starts."""
    ticks: np.ndarray
    """Its time stamp in ticks of ``scale`` seconds."""
    scale: float
    lines: np.ndarray
    """Its line (or row) number."""
    time: pd.Series | None
    """The file's time column, to show a stamp as written (None without one: a stamp is then a sample index)."""

    def stamp(self, i: int) -> str:
        if self.time is None:
            return str(self.ticks[i])
        return show_cell(self.time.iloc[i if self.order is None else int(self.order[i])])


@dataclass(frozen=True)
class _Pieces:
    """The segments cut at gaps: piece k > 0 of segment s is named ``"s#k"``; pieces are runs of sorted rows."""

    starts: np.ndarray
    """The sorted row where each piece starts."""
    names: np.ndarray
    lengths: np.ndarray


def _check_settings(dt: float, gap_tolerance: float, min_segment_rows: int, *, source: str) -> None:
    """The spec's sampling settings: dt > 0, gap_tolerance >= dt, min_segment_rows >= 1 (SpecError otherwise)."""
    if not dt > 0:
        raise SpecError(f"{source}: dt must be a positive number of seconds, got {dt}")
    if not gap_tolerance >= dt:
        raise SpecError(f"{source}: gap_tolerance = {gap_tolerance} s is shorter than dt = {dt} s; make it at least dt")
    if int(min_segment_rows) < 1:
        raise SpecError(f"{source}: min_segment_rows must be at least 1, got {min_segment_rows}")


def _check_header(frame: pd.DataFrame, schema: Schema, *, source: str, time_col: str | None) -> None:
    """No declared column named like the segment or time column, and every needed column in the frame."""
    for c in schema.names():
        if c in (SEGMENT, TIME, time_col):
            raise SpecError(f"{source}: column {c!r} clashes with the {'time' if c != SEGMENT else 'segment'} column")
    required = {SEGMENT: "segment column", **({time_col: "time column"} if time_col is not None else {})}
    required.update({c: "declared column" for c in schema.names()})
    check_columns(list(frame.columns), required, source=source)


def _read_columns(
    frame: pd.DataFrame, schema: Schema, *, source: str, lines: np.ndarray, word: str, shown: Mapping[str, str]
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Each declared column in spec order: finite numbers (numeric roles) or text keys as codes and labels."""
    values: dict[str, np.ndarray] = {}
    labels: dict[str, np.ndarray] = {}
    for c in schema.columns:
        raw = frame[c.name]
        name = shown.get(c.name, c.name)
        if c.role in NUMERIC_ROLES:
            x = parse_numbers(raw, source=source, column=name, lines=lines, word=word)
            _require_finite(x, raw, source=source, column=name, lines=lines, word=word)
            values[c.name] = x
        else:
            values[c.name], labels[c.name] = _labels(raw, source=source, column=name, lines=lines, word=word)
    return values, labels


def _group_rows(
    seg_raw: pd.Series, time: tuple[np.ndarray, float] | None, dt: float, *, lines: np.ndarray,
    time_column: pd.Series | None
) -> _Sorted:
    """The rows sorted by segment; without time stamps a row's time is its sample index in its segment. Rows
    already grouped in that order (one segment, or records one after another) are not sorted again."""
    codes, ids = _factorize_text(seg_raw)
    n = len(codes)
    order = None
    if len(ids) > 1 and bool((codes[1:] < codes[:-1]).any()):
        order = np.argsort(codes, kind="stable")
        codes, lines = codes[order], lines[order]
    starts = np.searchsorted(codes, np.arange(len(ids)))  # codes are 0, 1, ... in first-appearance order
    if time is None:
        ticks, scale = _index_ticks(starts, n), float(dt)
    else:
        ticks, scale = time if order is None else (time[0][order], time[1])
    return _Sorted(order=order, codes=codes, ids=ids, starts=starts, ticks=ticks, scale=scale, lines=lines,
                   time=time_column)


def _check_steps(
    rows: _Sorted, dt: float, gap_tolerance: float, dt_tolerance: float, *, source: str, column: str | None, word: str
) -> np.ndarray:
    """The sorted rows after which a gap (a step longer than ``gap_tolerance``) cuts their segment, once every step
    from a row to the next within a segment is checked: time goes forward, and a step up to ``gap_tolerance`` is a
    multiple k >= 1 of ``dt`` within ``dt_tolerance * k * dt``.

    A step within a hair less than that tolerance of ``dt`` itself passes every check, so only the other steps
    (segment boundaries, gaps, faults: few in a clean record) go through the full test, which decides alone every
    step near an end of the tolerance."""
    ls = rows.lines
    d = np.subtract(rows.ticks[1:], rows.ticks[:-1])
    step = d if d.dtype == np.float64 and rows.scale == 1.0 else d * rows.scale
    tol = max(dt_tolerance * dt * (1 - 1e-9) - 4 * np.spacing(dt), 0.0)
    lo, hi = max(dt - tol, 0.51 * dt), min(dt + tol, 1.49 * dt, gap_tolerance)
    irr = np.flatnonzero((step < lo) | (step > hi)) if lo <= hi else np.arange(len(step))
    nxt = irr + 1
    same = rows.codes[irr] == rows.codes[nxt]
    bad = same & (d[irr] <= 0)
    if bad.any():
        i = int(irr[_first(bad, ls[nxt])])
        seg = rows.ids[rows.codes[i]]
        if d[i] == 0:
            raise DataError(
                f"{source}, column {column!r}, {word}s {ls[i]} and {ls[i + 1]}: duplicate time stamp "
                f"{rows.stamp(i + 1)} in segment {seg!r}; remove the repeated row"
            )
        raise DataError(
            f"{source}, column {column!r}, {word} {ls[i + 1]}: time goes backwards from {rows.stamp(i)} "
            f"({word} {ls[i]}) to {rows.stamp(i + 1)} in segment {seg!r}; sort the rows by time"
        )
    s = np.asarray(step[irr], dtype=float)
    within = same & (s <= gap_tolerance)
    k = np.rint(s / dt)
    off = within & ((k < 1) | (np.abs(s - k * dt) > dt_tolerance * np.maximum(k, 1) * dt))
    if off.any():
        i = int(irr[_first(off, ls[nxt])])
        raise DataError(
            f"{source}, column {column!r}, {word} {ls[i + 1]}: step of {_num(step[i])} s from {rows.stamp(i)} "
            f"({word} {ls[i]}) to {rows.stamp(i + 1)} is not a multiple of dt = {_num(dt)} s; "
            "resample the data to dt or fix dt in the spec"
        )
    return irr[same & (s > gap_tolerance)]


def _split_at_gaps(rows: _Sorted, gap_after: np.ndarray, *, source: str) -> _Pieces:
    """The segments cut after the sorted rows ``gap_after`` (each within a segment, never its last row)."""
    n = len(rows.codes)
    starts = np.sort(np.r_[rows.starts, gap_after + 1])
    seg = np.searchsorted(rows.starts, starts, side="right") - 1
    number = np.arange(len(starts)) - np.searchsorted(starts, rows.starts)[seg]
    names = (
        pd.Series(rows.ids[seg], dtype=object) + np.where(number > 0, "#" + number.astype(str), "")
    ).to_numpy(dtype=object)
    clash = set(names[number > 0]) & set(rows.ids)
    if clash:
        raise DataError(
            f"{source}: splitting a segment at a gap gives the id {sorted(clash)[0]!r}, which is already a "
            "segment id; rename that segment"
        )
    return _Pieces(starts=starts, names=names, lengths=np.diff(np.r_[starts, n]))


def _drop_short(
    pieces: _Pieces, lines: np.ndarray, min_segment_rows: int, drop: bool, *, source: str, word: str
) -> tuple[np.ndarray | None, list[tuple[str, int]]]:
    """Which pieces stay (None: all of them), and the ``(id, rows)`` of the pieces shorter than
    ``min_segment_rows``: a DataError naming the first such piece unless ``drop``, then a warning (and a DataError
    when nothing is left)."""
    short = pieces.lengths < int(min_segment_rows)
    if not short.any():
        return None, []
    names, lengths, starts = pieces.names, pieces.lengths, pieces.starts
    if not drop:
        p = int(np.flatnonzero(short)[np.argmin(lines[starts[short]])])
        a, b = lines[starts[p]], lines[starts[p] + lengths[p] - 1]
        where = f"{word} {a}" if lengths[p] == 1 else f"{word}s {a}-{b}"
        raise DataError(
            f"{source}: segment {names[p]!r} ({where}) has {_rows(lengths[p])}, fewer than "
            f"min_segment_rows = {int(min_segment_rows)}; set drop_short_segments = true in the spec to drop "
            "such segments, or lower min_segment_rows"
        )
    dropped = [(str(names[p]), int(lengths[p])) for p in np.flatnonzero(short)]
    if short.all():
        raise DataError(
            f"{source}: no segment has at least min_segment_rows = {int(min_segment_rows)} rows; "
            "check dt and gap_tolerance, or lower min_segment_rows"
        )
    plural = "" if len(dropped) == 1 else "s"
    warnings.warn(
        f"{source}: dropped {len(dropped)} segment{plural} shorter than min_segment_rows = "
        f"{int(min_segment_rows)} ({_rows(sum(r for _, r in dropped))})",
        stacklevel=3,  # validate_frame's caller
    )
    return ~short, dropped


def validate_frame(
    frame: pd.DataFrame,
    schema: Schema,
    dt: float,
    *,
    source: str,
    time_col: str | None,
    gap_tolerance: float,
    min_segment_rows: int = 2,
    time_unit: str = "s",
    dt_tolerance: float = 1e-6,
    drop_short_segments: bool = False,
    check_constant: bool = True,
    lines: np.ndarray | None = None,
    row_word: str = "line",
    shown: Mapping[str, str] | None = None,
) -> pd.DataFrame:
    """Check one parsed file and return its clean frame (``segment``, ``time`` s, schema columns).

    ``lines`` gives each row's line number in the file (default: position + 2, the
    header being line 1). ``shown`` maps a schema column to the file column it was read
    from, for messages (a record of a wide file reads ``u`` from ``uEst``). Without a time
    column (``time_col=None``) time is the sample index within each segment times ``dt``,
    from 0 in every segment. A step between consecutive stamps of a segment must be a
    positive multiple k >= 1 of ``dt`` within ``dt_tolerance * k * dt`` unless it exceeds
    ``gap_tolerance`` seconds, in which case the segment is split there. Pieces shorter
    than ``min_segment_rows`` raise DataError, or are dropped with a warning when
    ``drop_short_segments``; the dropped ``(id, rows)`` pairs are in
    ``result.attrs["dropped_segments"]`` and the time zone of datetime stamps in
    ``result.attrs["time_zone"]``.
    """
    _check_settings(dt, gap_tolerance, min_segment_rows, source=source)
    word = row_word
    n = len(frame)
    ln = np.arange(n) + (2 if word == "line" else 1) if lines is None else np.asarray(lines)
    if n == 0:
        raise DataError(f"{source}: no data rows; the file must hold at least {min_segment_rows} rows")
    shown = dict(shown or {})
    _check_header(frame, schema, source=source, time_col=time_col)

    seg_raw = frame[SEGMENT]
    if seg_raw.isna().any():
        i = _first(seg_raw.isna().to_numpy(), ln)
        raise DataError(f"{source}, column {SEGMENT!r}, {word} {ln[i]}: missing segment id; fill it or remove the row")
    zone, time = None, None
    if time_col is not None:
        ticks, scale, zone = parse_time(frame[time_col], time_unit, source=source, column=time_col, lines=ln, word=word)
        time = (ticks, scale)
    values, labels = _read_columns(frame, schema, source=source, lines=ln, word=word, shown=shown)
    if check_constant:
        check_not_constant(values, schema, source=source, shown=shown)

    rows = _group_rows(seg_raw, time, dt, lines=ln, time_column=frame[time_col] if time_col is not None else None)
    gaps = _check_steps(rows, dt, gap_tolerance, dt_tolerance, source=source, column=time_col, word=word)
    pieces = _split_at_gaps(rows, gaps, source=source)
    kept, dropped = _drop_short(pieces, rows.lines, min_segment_rows, drop_short_segments, source=source, word=word)

    # the sorted rows kept, and the file row of each (None: every row, in file order: nothing is gathered)
    keep = None if kept is None else np.repeat(kept, pieces.lengths)
    sel = rows.order if keep is None else np.flatnonzero(keep) if rows.order is None else rows.order[keep]
    names, lengths = (pieces.names, pieces.lengths) if kept is None else (pieces.names[kept], pieces.lengths[kept])
    ticks = rows.ticks if keep is None else rows.ticks[keep]
    cols: dict[str, Any] = {
        SEGMENT: _run_text(names, lengths),
        TIME: ticks if ticks.dtype == np.float64 and rows.scale == 1.0 else (ticks * rows.scale).astype(float),
    }
    for c in schema.columns:
        v = values[c.name] if sel is None else values[c.name][sel]
        cols[c.name] = _text_array(v, labels[c.name]) if c.name in labels else v
    out = pd.DataFrame(cols, copy=False)  # one array per column, none copied into a block
    out.attrs["dropped_segments"] = dropped
    out.attrs["time_zone"] = zone
    return out
