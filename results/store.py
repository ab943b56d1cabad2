"""The run store: one folder per run, one Parquet file per finished job, written atomically.

Layout::

    enginebench-runs/                   (--store, $ENGINEBENCH_STORE)
      <run-id>/
        run.json                        id, name, status, config hash, job count, times
        config.toml                     the resolved experiment
        environment.json                package versions, git commit, CPU/GPU, seeds
        jobs/<job-key>.parquet          metric rows of one finished job; params,
                                        describe() and timings in the file's metadata

A job file appears under its final name only once complete (temporary file + rename in
the same folder), so a killed run leaves finished jobs intact and no half-written file.

Faults, and what the store does about them:

* disk full (or any other failed write): the temporary file is removed, nothing is
  renamed into place, and a one-line :class:`StoreError` names the file, the store and
  says "disk full"; the jobs written before stay readable and ``run --resume`` finishes
  the run once there is space;
* two processes creating runs at once: run folders are claimed with an atomic ``mkdir``
  (a taken name gets the next free ``-k`` suffix), so run ids are distinct and no run
  writes into another's folder; ``latest`` is the run created last (``created_ns`` in
  run.json, then the id), whatever the ids' spelling;
* a damaged job file (truncated, garbled: job files carry Parquet page checksums): reading
  the run's metrics refuses with a message naming the file, and ``finished_jobs`` does not
  count it, so ``run --resume`` recomputes that job and keeps every other job as it is
  (``damaged_jobs`` names the damaged files and why).
"""

from __future__ import annotations

import calendar
import errno
import json
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import tomli_w

from enginebench.errors import StoreError

DEFAULT_STORE = "enginebench-runs"
JOB_META_KEY = b"enginebench.job"


def store_root(path: str | Path | None = None) -> Path:
    """The store folder: explicit path, else $ENGINEBENCH_STORE, else ./enginebench-runs."""
    if path:
        return Path(path)
    return Path(os.environ.get("ENGINEBENCH_STORE") or DEFAULT_STORE)


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


def _write_failed(path: Path, exc: OSError, store: Path | None, what: str, todo: str) -> StoreError:
    """A one-line StoreError for a failed write of ``path`` (``what`` names the file's purpose)."""
    where = f" in the store {store}" if store is not None else ""
    if exc.errno in DISK_FULL:
        return StoreError(
            f"disk full while writing {what} {path}{where} ({exc.strerror or exc}); nothing partial was kept; "
            f"free space and {todo}"
        )
    reason = " ".join(str(exc.strerror or exc).split())
    return StoreError(f"cannot write {what} {path}{where} ({reason}); fix the folder's permissions or space and {todo}")


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, fsync it, then rename it over ``path``.

    On any failure the temporary file is removed and ``path`` is left as it was; the
    OSError propagates (callers turn it into a StoreError that names the file).
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


def _table_bytes(table: pa.Table) -> bytes:
    """A Parquet file in memory, with page checksums so that a garbled page is detected on reading."""
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, write_page_checksum=True)
    return sink.getvalue().to_pybytes()


def _atomic_write_table(path: Path, table: pa.Table) -> None:
    _atomic_write_bytes(path, _table_bytes(table))


def _read_parquet(path: Path) -> pa.Table:
    """Read a whole Parquet file, verifying page checksums where the file has them."""
    return pq.read_table(path, page_checksum_verification=True)


def _damage(exc: BaseException) -> str:
    """The reason a stored file could not be read, on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 200 else text[:197] + "..."


READ_ERRORS = (OSError, pa.ArrowException, ValueError, KeyError, IndexError, TypeError, MemoryError)
"""What reading a damaged Parquet file can raise (pyarrow's errors, decoding errors of its metadata)."""


def _jsonable(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays become numbers and lists."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


@dataclass
class Run:
    """One run folder."""

    path: Path

    @property
    def id(self) -> str:
        return self.path.name

    @property
    def jobs_dir(self) -> Path:
        return self.path / "jobs"

    @property
    def store(self) -> Path:
        """The store folder holding this run."""
        return self.path.parent

    def _resume_hint(self) -> str:
        return f"finish the run with `enginebench run --resume {self.id}`"

    def _write(self, path: Path, data: bytes, what: str) -> None:
        """Atomic write inside the run; a failure becomes a StoreError naming the file and the store."""
        try:
            _atomic_write_bytes(path, data)
        except OSError as exc:
            raise _write_failed(path, exc, self.store, what, self._resume_hint()) from exc

    def info(self) -> dict[str, Any]:
        try:
            info = json.loads((self.path / "run.json").read_text())
        except (OSError, ValueError) as exc:
            raise StoreError(f"run {self.id}: run.json unreadable ({_damage(exc)}); the run folder is damaged") from None
        if not isinstance(info, dict):
            raise StoreError(f"run {self.id}: run.json does not hold a JSON object; the run folder is damaged")
        return info

    def update_info(self, **changes: Any) -> None:
        info = {**self.info(), **changes}
        self._write(self.path / "run.json", json.dumps(_jsonable(info), indent=2).encode(), "the run's status file")

    def config(self) -> dict[str, Any]:
        import tomllib

        return tomllib.loads((self.path / "config.toml").read_text())

    def environment(self) -> dict[str, Any]:
        return json.loads((self.path / "environment.json").read_text())

    def job_files(self) -> list[Path]:
        """The job files present under their final names (temporary files excluded), sorted."""
        if not self.jobs_dir.is_dir():
            return []
        return sorted(p for p in self.jobs_dir.glob("*.parquet") if not p.name.startswith("."))

    @staticmethod
    def _load_job(path: Path, *, frame: bool = True) -> tuple[pd.DataFrame | None, dict[str, Any]]:
        """A job file's rows (when ``frame``) and metadata; raises one of READ_ERRORS when the file is damaged."""
        table = _read_parquet(path)
        raw = (table.schema.metadata or {}).get(JOB_META_KEY)
        if raw is None:
            raise ValueError("no enginebench job metadata in the file")
        meta = json.loads(raw)
        if not isinstance(meta, dict):
            raise ValueError("the job metadata is not a JSON object")
        if not frame:
            table.schema.names  # noqa: B018 - decodes the column names, which a garble can break
            json.loads((table.schema.metadata or {}).get(b"pandas", b"{}"))
            return None, meta
        return table.to_pandas(), meta

    def _read_job(self, path: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
        """A job file's rows and metadata; StoreError naming the file when it is damaged."""
        try:
            return self._load_job(path)  # type: ignore[return-value]
        except READ_ERRORS as exc:
            raise StoreError(
                f"run {self.id}: job file {path} is damaged ({_damage(exc)}); the other jobs are intact: "
                f"`enginebench run --resume {self.id}` recomputes this one"
            ) from None

    def damaged_jobs(self) -> dict[str, str]:
        """Job key -> why its file cannot be read back whole, for every damaged job file present."""
        out = {}
        for p in self.job_files():
            try:
                self._load_job(p, frame=False)
            except READ_ERRORS as exc:
                out[p.stem] = _damage(exc)
        return out

    def finished_jobs(self, verify: bool = True) -> set[str]:
        """Keys of the jobs whose files are complete and readable.

        With ``verify`` (the default, what ``run --resume`` relies on) every job file is
        read back whole and a damaged one does not count, so resuming computes that job
        again and replaces the file while every other job is kept; ``damaged_jobs`` says
        which and why. ``verify=False`` only lists the files (fast, for counts).
        """
        keys = {p.stem for p in self.job_files()}
        return keys - set(self.damaged_jobs()) if verify else keys

    def write_job(self, key: str, rows: pd.DataFrame, meta: dict[str, Any]) -> Path:
        """Write one finished job's metric rows and metadata atomically (StoreError on a failed write)."""
        table = pa.Table.from_pandas(rows, preserve_index=False)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), JOB_META_KEY: json.dumps(_jsonable(meta)).encode()})
        path = self.jobs_dir / f"{key}.parquet"
        self._write(path, _table_bytes(table), f"job {key} of run {self.id} to")
        return path

    def write_table(self, relative: str, frame: pd.DataFrame) -> Path:
        """Store an extra artefact table (rankings, predictions) inside the run, atomically."""
        path = self.path / relative
        self._write(path, _table_bytes(pa.Table.from_pandas(frame, preserve_index=False)), "the table")
        return path

    def read_table(self, relative: str) -> pd.DataFrame:
        path = self.path / relative
        try:
            return _read_parquet(path).to_pandas()
        except READ_ERRORS as exc:
            raise StoreError(f"run {self.id}: {path} is unreadable ({_damage(exc)}); compute it again") from None

    def job_meta(self, key: str) -> dict[str, Any]:
        """The metadata of one finished job (status, reason, params, timings...)."""
        path = self.jobs_dir / f"{key}.parquet"
        if not path.is_file():
            raise StoreError(f"run {self.id}: job {key} has no file {path}; {self._resume_hint()}")
        return self._read_job(path)[1]

    def job_notes(self) -> dict[str, dict[tuple[str, str], int]]:
        """What the run's jobs said, counted: ``{"failed": {(method, reason): n}, "warnings": {(method, text): n}}``.

        Failure reasons come from each failed job's ``reason``; warnings from each job's
        ``warnings`` list (a selected hyperparameter at the edge of its grid, a model that
        kept no term...). Read from the job files' metadata only, so it is cheap.
        """
        out: dict[str, dict[tuple[str, str], int]] = {"failed": {}, "warnings": {}}
        for path in self.job_files():
            try:
                meta = self._load_job(path, frame=False)[1]
            except READ_ERRORS:  # a damaged file is reported by damaged_jobs and by the tables
                continue
            method = str(meta.get("method", "?"))
            if meta.get("status") not in (None, "ok"):
                key = (method, str(meta.get("reason", "no reason recorded")))
                out["failed"][key] = out["failed"].get(key, 0) + 1
            for text in meta.get("warnings", []) or []:
                key = (method, str(text))
                out["warnings"][key] = out["warnings"].get(key, 0) + 1
        return out

    def metrics(self) -> pd.DataFrame:
        """All metric rows of all finished jobs (one long frame); a damaged job file is refused by name."""
        files = self.job_files()
        if not files:
            raise StoreError(f"run {self.id} has no finished job yet")
        return pd.concat([self._read_job(p)[0] for p in files], ignore_index=True)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "run"


_SUFFIX = re.compile(r"^(.*?)(?:-(\d+))?$")


def _created_ns(run: Run) -> int:
    """When a run was created, in ns since the epoch: run.json's created_ns, else the id's stamp."""
    try:
        value = json.loads((run.path / "run.json").read_text()).get("created_ns")
        if isinstance(value, int):
            return value
    except (OSError, ValueError, AttributeError):
        pass
    try:
        return calendar.timegm(time.strptime(run.id[:15], "%Y%m%d-%H%M%S")) * 10**9
    except ValueError:
        return 0


def _order(run: Run) -> tuple[int, str, int]:
    """Creation order: creation time, then the id with its '-k' suffix compared as a number."""
    base, k = _SUFFIX.match(run.id).groups()  # type: ignore[union-attr]
    return _created_ns(run), base, int(k or 0)


class RunStore:
    """A folder of runs."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = store_root(root)

    def _claim(self, base: str) -> Path:
        """Create a new run folder atomically: ``base``, else ``base-1``, ``base-2``...

        ``mkdir`` either creates the folder or fails because it exists, so two processes
        can never claim the same folder.
        """
        try:
            self.root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _write_failed(self.root, exc, None, "the run store", "run again") from exc
        for k in range(10_000):
            path = self.root / (base if k == 0 else f"{base}-{k}")
            try:
                path.mkdir()
                return path
            except FileExistsError:
                continue
            except OSError as exc:
                raise _write_failed(path, exc, self.root, "the run folder", "run again") from exc
        raise StoreError(f"cannot create a run folder under {self.root}: {base} and 10000 variants are taken")

    def create(self, name: str, config: dict[str, Any], config_hash: str, environment: dict[str, Any], n_jobs: int) -> Run:
        """A new run folder with its config, environment and run.json (status running).

        run.json is written last: until it exists the folder is not a run (``runs`` skips
        it), and a failed write removes the folder again.
        """
        created_ns = time.time_ns()
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(created_ns / 1e9))
        path = self._claim(f"{stamp}-{_slug(name)}-{config_hash[:6]}")
        run = Run(path)
        try:
            try:
                (path / "jobs").mkdir()
            except OSError as exc:
                raise _write_failed(path / "jobs", exc, self.root, "the jobs folder", "run again") from exc
            run._write(path / "config.toml", tomli_w.dumps(_jsonable(config)).encode(), "the run's config")
            run._write(path / "environment.json", json.dumps(_jsonable(environment), indent=2).encode(),
                       "the run's environment")
            run._write(path / "run.json", json.dumps({
                "id": run.id, "name": name, "status": "running", "config_hash": config_hash, "n_jobs": n_jobs,
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(created_ns / 1e9)),
                "created_ns": created_ns, "pid": os.getpid(),
            }, indent=2).encode(), "the run's status file")
        except BaseException:
            shutil.rmtree(path, ignore_errors=True)
            raise
        return run

    def runs(self) -> list[Run]:
        """Every run of the store (a folder with a run.json), oldest first."""
        if not self.root.is_dir():
            return []
        return sorted((Run(p) for p in self.root.iterdir() if (p / "run.json").is_file()), key=_order)

    def get(self, ref: str) -> Run:
        """A run by id, unique id prefix, 'latest' (the run created last), or path."""
        path = Path(ref)
        if (path / "run.json").is_file():
            return Run(path)
        runs = self.runs()
        if ref == "latest":
            if not runs:
                raise StoreError(f"no runs in {self.root}")
            return runs[-1]
        matches = [r for r in runs if r.id == ref] or [r for r in runs if r.id.startswith(ref)]
        if not matches:
            raise StoreError(f"no run {ref!r} in {self.root}; 'enginebench runs list' shows the runs")
        if len(matches) > 1:
            raise StoreError(f"run reference {ref!r} is ambiguous in {self.root}: {', '.join(r.id for r in matches[:5])}")
        return matches[0]
