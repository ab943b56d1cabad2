"""Datasets on disk: one Parquet file whose footer carries roles, units, dt and a content hash.

The schema metadata key ``b"enginebench"`` holds a JSON document::

    {"format": 1, "name": ..., "schema": {col: {"role", "unit"}}, "dt": ...,
     "meta": {...}, "content_hash": "<sha256>", "rows": n, "segments": k}

so that ``datasets list/show`` can describe a file from its footer alone
(:func:`read_metadata`) and :func:`read_dataset` can prove that the values it returns
are the values that were written. Pages are written with CRC checksums and verified
on read, so a damaged page is caught even when only some columns are read; the
content hash additionally catches a file whose values were rewritten by another tool.

``meta`` is stored as JSON: tuples come back as lists, numpy scalars and arrays as
plain numbers and lists, and entries that JSON cannot hold are left out with a warning.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.schema import Schema
from enginebench.errors import DataError

META_KEY = b"enginebench"
FORMAT_VERSION = 1


def _json_default(value: Any) -> Any:
    """JSON fallback for numpy scalars and arrays (everything else is not serialisable)."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _serialisable_meta(meta: dict[str, Any], path: Path) -> dict[str, Any]:
    """The JSON-serialisable entries of ``meta``; the others are dropped with a warning."""
    kept: dict[str, Any] = {}
    dropped: list[str] = []
    for key, value in meta.items():
        try:
            kept[str(key)] = json.loads(json.dumps(value, default=_json_default))
        except (TypeError, ValueError):
            dropped.append(str(key))
    if dropped:
        warnings.warn(
            f"{path}: meta entries {', '.join(map(repr, dropped))} are not JSON-serialisable and were not stored",
            stacklevel=3,
        )
    return kept


def write_dataset(ds: Dataset, path: str | os.PathLike[str], *, compression: str = "zstd") -> Path:
    """Write ``ds`` to one Parquet file at ``path`` atomically and return the path.

    Only ``segment``, ``time`` and the schema's columns are written. The file is first
    written to a temporary file in the same folder and then renamed over ``path``
    (``os.replace``), so a crash leaves either the old file or the new one, never half of one.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cols = [SEGMENT, TIME, *ds.schema.names()]
    table = pa.Table.from_pandas(ds.frame[cols], preserve_index=False)
    doc = {
        "format": FORMAT_VERSION,
        "name": ds.name,
        "schema": ds.schema.to_dict(),
        "dt": float(ds.dt),
        "meta": _serialisable_meta(ds.meta, path),
        "content_hash": ds.content_hash(),
        "rows": len(ds.frame),
        "segments": len(ds.segment_bounds()),
    }
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), META_KEY: json.dumps(doc).encode()})
    fd, tmp_name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        pq.write_table(table, tmp_name, compression=compression, write_page_checksum=True)
        with open(tmp_name, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise
    return path


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def _footer_schema(path: Path) -> pa.Schema:
    """The Arrow schema from the footer, or a DataError saying why the file cannot be used."""
    if not path.exists():
        raise DataError(f"file {path} not found; check the path")
    if path.is_dir():
        raise DataError(f"file {path} is a folder, not a dataset file; give the path of the .parquet file")
    try:
        return pq.read_schema(path)
    except (pa.ArrowInvalid, OSError) as exc:
        raise DataError(
            f"file {path} is not a Parquet file ({_one_line(exc)}); enginebench datasets are Parquet files "
            "written by write_dataset - import CSV or other tables through a TOML import spec"
        ) from exc


def _parse_doc(path: Path, schema: pa.Schema) -> dict[str, Any]:
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise DataError(
            f"file {path} is a Parquet file without enginebench metadata (roles, units, dt); "
            "import it through a TOML import spec that declares them"
        )
    try:
        doc = json.loads(raw)
        Schema.from_dict(doc["schema"])
        float(doc["dt"])
        str(doc["name"])
    except (ValueError, KeyError, TypeError, DataError) as exc:
        raise DataError(
            f"file {path} has damaged enginebench metadata ({_one_line(exc)}); re-create the file from its source"
        ) from exc
    if int(doc.get("format", 0)) > FORMAT_VERSION:
        raise DataError(
            f"file {path} was written by a newer enginebench (format {doc['format']}, this one reads up to "
            f"{FORMAT_VERSION}); upgrade enginebench"
        )
    return doc


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The stored metadata of a dataset file, read from the footer only (no data pages).

    Returns the JSON document described in the module docstring, with ``rows`` taken
    from the Parquet footer and ``path`` added.
    """
    path = Path(path)
    doc = _parse_doc(path, _footer_schema(path))
    try:
        rows = pq.read_metadata(path).num_rows
    except (pa.ArrowInvalid, OSError) as exc:
        raise DataError(
            f"file {path} is corrupted: cannot read its footer ({_one_line(exc)}); restore it from a backup"
        ) from exc
    return {**doc, "rows": int(rows), "path": str(path)}


def read_dataset(path: str | os.PathLike[str], columns: list[str] | None = None) -> Dataset:
    """Read a dataset file, optionally only some of its columns (plus ``segment`` and ``time``).

    With ``columns`` only those column chunks are read and the schema is narrowed to
    them (in the stored order). When every column is read, the stored content hash is
    recomputed and compared: a mismatch raises DataError.
    """
    path = Path(path)
    doc = _parse_doc(path, _footer_schema(path))
    schema = Schema.from_dict(doc["schema"])
    names = schema.names()
    if columns is not None:
        wanted = [c for c in dict.fromkeys(columns) if c not in (SEGMENT, TIME)]
        unknown = [c for c in wanted if c not in schema]
        if unknown:
            raise DataError(
                f"file {path} has no column(s) {', '.join(map(repr, unknown))}; "
                f"the dataset has {', '.join(map(repr, names))}"
            )
        schema = schema.select(wanted)
    full = schema.names() == names
    try:
        table = pq.read_table(path, columns=[SEGMENT, TIME, *schema.names()], page_checksum_verification=True)
        frame = table.to_pandas()
    except (pa.ArrowException, OSError) as exc:
        raise DataError(
            f"file {path} is corrupted: cannot decode its data ({_one_line(exc)}); "
            "restore it from a backup or re-create it from its source"
        ) from exc
    meta = dict(doc.get("meta", {}))
    ds = Dataset(name=str(doc["name"]), frame=frame, schema=schema, dt=float(doc["dt"]), meta=meta)
    if full and ds.content_hash() != doc.get("content_hash"):
        raise DataError(
            f"file {path} is corrupted: content hash mismatch (stored {str(doc.get('content_hash'))[:12]}, "
            f"computed {ds.content_hash()[:12]}); its values changed after it was written - "
            "restore it from a backup or re-create it from its source"
        )
    return ds
