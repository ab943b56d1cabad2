"""The files of one finished job: its metric rows with metadata, and its selection table; encoding and damage checks.

``jobs/<job-key>.parquet`` holds a job's metric rows, with its params, describe() and
timings as JSON in the file's metadata (``JOB_META_KEY``); ``selection/<job-key>.parquet``
holds its model-selection scores, the SHA-256 of which is recorded in the job file's
metadata (``selection_file``). ``Run`` (``results.run_folder``) writes and reads them
through the functions here.

Faults handled here:

* a damaged job file (truncated, garbled: job files carry Parquet page checksums, and the
  SHA-256 of everything they are read back as, metadata and column names included,
  checked on every read: ``content_sha256``):
  ``load_job`` raises one of ``READ_ERRORS``, so reading the run's metrics refuses with a
  message naming the file, and ``Run.finished_jobs`` does not count it: ``run --resume``
  recomputes that job and keeps every other job as it is (``Run.damaged_jobs`` names
  the damaged files and why);
* a damaged or missing selection table (a failed write of the table removes the job file
  again): ``selection_bytes`` says why, ``Run.selection_table`` refuses naming the file,
  and the job counts as damaged exactly like a damaged job file (not finished,
  recomputed by ``run --resume``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from enginebench.results.atomic import READ_ERRORS, damage_text, read_parquet, table_bytes

if TYPE_CHECKING:  # pandas is imported where a frame is made: listing runs reads none (issue 35)
    import pandas as pd

JOB_META_KEY = b"enginebench.job"
"""The key of a job file's Parquet metadata holding the job's metadata (JSON)."""
JOB_SHA_KEY = b"enginebench.sha256"
"""The key holding the SHA-256 of everything a job file is read back as (``content_sha256``)."""
CHECKSUMMED = "checksum"
"""Set in the metadata of every job file that carries ``JOB_SHA_KEY`` (older files carry neither)."""
SELECTION_DIR = "selection"
"""The folder of a run holding one selection table per job that selected hyperparameters."""
SELECTION_META = "selection_table"
"""The key under which a job's metadata brings its selection table (a DataFrame) to ``Run.write_job``."""
SELECTION_COLUMNS = {"target": "str", "window": "float64", "split": "str", "method": "str", "repetition": "int64",
                     "point": "int64", "resample": "int64", "score": "float64", "criterion": "str", "chosen": "bool"}
"""The fixed columns of ``Run.selection_table`` (the ``param:<name>`` columns come after ``point``)."""


def jsonable(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays become numbers and lists."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def encode_job(rows: pd.DataFrame, meta: dict[str, Any]) -> tuple[bytes, bytes | None]:
    """The bytes of a job file (``rows`` with ``meta`` in its metadata) and of its selection table (None without one).

    A selection table in ``meta`` (a non-empty DataFrame under ``SELECTION_META``) is taken
    out of the metadata; its SHA-256 and row count are recorded there as ``selection_file``.
    """
    import pandas as pd

    meta = dict(meta)
    selection = meta.pop(SELECTION_META, None)
    data = None
    if isinstance(selection, pd.DataFrame) and len(selection):
        data = table_bytes(pa.Table.from_pandas(selection, preserve_index=False))
        meta["selection_file"] = {"sha256": hashlib.sha256(data).hexdigest(), "rows": len(selection)}
    table = pa.Table.from_pandas(rows, preserve_index=False)
    meta_raw = json.dumps(jsonable({**meta, CHECKSUMMED: 1})).encode()
    metadata = {**(table.schema.metadata or {}), JOB_META_KEY: meta_raw}
    table = table.replace_schema_metadata(metadata)
    digest = content_sha256(table)
    table = table.replace_schema_metadata({**metadata, JOB_SHA_KEY: digest.encode()})
    return table_bytes(table), data


def content_sha256(table: pa.Table) -> str:
    """SHA-256 of what a job file is read back as: its metadata (the job's JSON, pandas' description of the
    frame) and each column's name, type and values, independent of how the file chunks them. A byte of the
    file that changes any of these changes the digest; one that changes none of them is harmless."""
    h = hashlib.sha256(b"enginebench job v1\0")
    metadata = table.schema.metadata or {}
    for key in (JOB_META_KEY, b"pandas"):
        value = metadata.get(key, b"")
        h.update(len(value).to_bytes(8, "little") + value)
    for name, column in zip(table.column_names, table.columns):
        h.update(f"\0{name}\0{column.type}\0".encode())
        values = column.to_numpy(zero_copy_only=False) if column.num_chunks else []
        if pa.types.is_floating(column.type) or pa.types.is_integer(column.type) or pa.types.is_boolean(column.type):
            h.update(np.ascontiguousarray(values).tobytes())
        else:
            h.update("\x1f".join("\x1e" if v is None else str(v) for v in values).encode("utf-8", "surrogatepass"))
        h.update(column.null_count.to_bytes(8, "little"))
    return h.hexdigest()


def check_content(table: pa.Table, meta: dict[str, Any]) -> None:
    """ValueError when a job file written with a checksum does not match it (or lost it)."""
    recorded = (table.schema.metadata or {}).get(JOB_SHA_KEY)
    if recorded is None:
        if meta.get(CHECKSUMMED):
            raise ValueError("the file's checksum is missing")
        return  # written before job files carried one
    metadata = {k: v for k, v in (table.schema.metadata or {}).items() if k != JOB_SHA_KEY}
    if content_sha256(table.replace_schema_metadata(metadata)).encode() != recorded:
        raise ValueError("the file does not match its SHA-256 checksum (a changed byte)")


_CHECKED: dict[bytes, tuple[pa.Table, bytes]] = {}
"""Job files already read and checked in this process, by the SHA-256 of their bytes: the parsed table and its
job metadata (JSON). One command reads a run's job files several times (its rows, then the metadata for the notes,
the verdict and the picks); the key is the content itself, so a file rewritten in place, even within one tick of
the file system's clock and at the same size, is read and checked again."""
_CHECKED_MAX = 4096


def _checked_table(path: Path) -> tuple[pa.Table, bytes]:
    """The job file's table and its job metadata (JSON bytes), checked (``check_content``); raises one of
    READ_ERRORS when the file is damaged. Parsed and checked once per content (``_CHECKED``)."""
    try:
        key = hashlib.sha256(Path(path).read_bytes()).digest()
    except OSError:
        key = None  # read_parquet says what is wrong, as it always did
    if key is not None and key in _CHECKED:
        return _CHECKED[key]
    table = read_parquet(path)
    raw = (table.schema.metadata or {}).get(JOB_META_KEY)
    if raw is None:
        raise ValueError("no enginebench job metadata in the file")
    meta = json.loads(raw)
    if not isinstance(meta, dict):
        raise ValueError("the job metadata is not a JSON object")
    check_content(table, meta)
    try:  # kept only when the bytes read and checked are the bytes of the key (no rewrite in between)
        same = key is not None and hashlib.sha256(Path(path).read_bytes()).digest() == key
    except OSError:
        same = False
    if same:
        if len(_CHECKED) >= _CHECKED_MAX:
            _CHECKED.pop(next(iter(_CHECKED)))
        _CHECKED[key] = (table, raw)
    return table, raw


def job_rows_frame(paths: list[Path]) -> pd.DataFrame | None:
    """The metric rows of the job files ``paths`` as one frame, value for value ``pd.concat`` of each file's
    ``load_job`` frame (``ignore_index``), converted to pandas once instead of once per file; None when the files
    differ in columns, types or pandas metadata, or one cannot be read or converted (the caller then reads them
    one by one, which names a damaged file)."""
    tables = []
    for path in paths:
        try:
            tables.append(_checked_table(path)[0])
        except READ_ERRORS:
            return None
    if not tables:
        return None
    first = tables[0]
    pandas_meta = (first.schema.metadata or {}).get(b"pandas")
    if any(not t.schema.equals(first.schema, check_metadata=False)
           or (t.schema.metadata or {}).get(b"pandas") != pandas_meta for t in tables[1:]):
        return None
    try:
        return pa.concat_tables(tables).to_pandas().reset_index(drop=True)
    except READ_ERRORS:
        return None


def load_job(path: Path, *, frame: bool = True) -> tuple[pd.DataFrame | None, dict[str, Any]]:
    """A job file's rows (when ``frame``) and metadata; raises one of READ_ERRORS when the file is damaged."""
    table, raw = _checked_table(path)
    meta = json.loads(raw)  # a fresh dict on every call: callers may change theirs
    if not frame:
        table.schema.names  # noqa: B018 - decodes the column names, which a garble can break
        json.loads((table.schema.metadata or {}).get(b"pandas", b"{}"))
        return None, meta
    return table.to_pandas(), meta


def selection_bytes(path: Path, meta: dict[str, Any]) -> tuple[bytes | None, str | None]:
    """(the bytes of the selection file ``path``, None) when the job (metadata ``meta``) recorded one and it is
    intact, (None, why) when it is damaged, (None, None) when the job has no selection table."""
    record = meta.get("selection_file")
    if record is None:
        return None, None
    if not isinstance(record, dict) or not isinstance(record.get("sha256"), str):
        return None, "its record of the selection table is garbled"
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None, f"its selection table {path} is missing"
    except OSError as exc:
        return None, f"its selection table {path} is unreadable ({damage_text(exc)})"
    if hashlib.sha256(data).hexdigest() != record["sha256"]:
        return None, f"its selection table {path} does not match the SHA-256 recorded in the job file"
    return data, None


def read_selection(data: bytes) -> pd.DataFrame:
    """A selection table from its file's bytes (page checksums verified); raises one of READ_ERRORS when damaged."""
    return pq.read_table(pa.BufferReader(data), page_checksum_verification=True).to_pandas()


def selection_frame(frames: list[pd.DataFrame]) -> pd.DataFrame:
    """Selection tables of several jobs as one frame with the columns in order (``SELECTION_COLUMNS``, the
    ``param:<name>`` columns after ``point``); an empty frame with the fixed columns when there is none."""
    import pandas as pd

    if not frames:
        return pd.DataFrame({c: pd.Series(dtype=t) for c, t in SELECTION_COLUMNS.items()})
    out = pd.concat(frames, ignore_index=True)
    params = [c for c in out.columns if c.startswith("param:")]
    fixed = list(SELECTION_COLUMNS)
    at = fixed.index("point") + 1
    return out[fixed[:at] + params + fixed[at:]].astype(SELECTION_COLUMNS)
