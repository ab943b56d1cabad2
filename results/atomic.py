"""Atomic, checksummed file writes and checked reads: the store's only way of putting bytes on disk.

A file appears under its final name only once complete (temporary file beside it, fsync,
rename in the same folder, fsync of the folder), so a killed write leaves the old file or
none, never half a file. Parquet files are written with page checksums, so a garbled page
is detected on reading.

Fault handled here: disk full (or any other failed write): the temporary file is
removed, nothing is renamed into place, and ``write_failed`` makes the one-line
:class:`StoreError` that names the file, the store and says "disk full"; what was written
before stays readable.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from enginebench.errors import StoreError

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
"""Write errors reported as a full disk (no space left, quota exceeded)."""


def _write_bytes(fh: Any, data: bytes, path: Path) -> None:
    """Write ``data`` to the open file ``fh`` at ``path`` (one place, so tests can simulate a full disk here)."""
    fh.write(data)


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable where the platform allows it (best effort)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_failed(path: Path, exc: OSError, store: Path | None, what: str, todo: str) -> StoreError:
    """A one-line StoreError for a failed write of ``path`` (``what`` names the file's purpose)."""
    where = f" in the store {store}" if store is not None else ""
    if exc.errno in DISK_FULL:
        return StoreError(
            f"disk full while writing {what} {path}{where} ({exc.strerror or exc}); nothing partial was kept; "
            f"free space and {todo}"
        )
    reason = " ".join(str(exc.strerror or exc).split())
    return StoreError(f"cannot write {what} {path}{where} ({reason}); fix the folder's permissions or space and {todo}")


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, fsync it, then rename it over ``path``.

    On any failure the temporary file is removed and ``path`` is left as it was; the
    OSError propagates (``write_failed`` turns it into a StoreError
    that names the file).
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            _write_bytes(fh, data, Path(tmp))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def table_bytes(table: pa.Table) -> bytes:
    """A Parquet file in memory, with page checksums so that a garbled page is detected on reading."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, write_page_checksum=True)
    return sink.getvalue().to_pybytes()


def read_parquet(path: Path) -> pa.Table:
    """Read a whole Parquet file, verifying page checksums where the file has them."""
    return pq.read_table(path, page_checksum_verification=True)


def damage_text(exc: BaseException) -> str:
    """The reason a stored file could not be read, on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


READ_ERRORS = (OSError, pa.ArrowException, ValueError, KeyError, IndexError, TypeError, MemoryError)
"""What reading a damaged Parquet file can raise (pyarrow's errors, decoding errors of its metadata)."""
