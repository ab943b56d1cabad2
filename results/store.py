"""The run store: one folder per run, one Parquet file per finished job, written atomically.

Layout::

    enginebench-runs/                   (--store, $ENGINEBENCH_STORE)
      <run-id>/
        run.json                        id, name, status, config hash, job count, times, tags
        config.toml                     the resolved experiment
        environment.json                package versions, git commit, CPU/GPU, seeds
        jobs/<job-key>.parquet          metric rows of one finished job; params,
                                        describe() and timings in the file's metadata
        selection/<job-key>.parquet     the job's model-selection scores (one row per grid
                                        point and resample or fold), for jobs that selected;
                                        its SHA-256 is in the job file's metadata

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
  (``damaged_jobs`` names the damaged files and why);
* a damaged or missing selection table (a job file's metadata records the SHA-256 of its
  selection file, written right after it; a failed write of the table removes the job
  file again): ``Run.selection_table`` refuses naming the file, and the job counts as
  damaged exactly like a damaged job file (not finished, recomputed by ``run --resume``);
* a damaged run folder (run.json, config.toml or environment.json missing or
  unreadable): ``Run.damage()`` says why, ``runs list`` shows it as damaged, and
  ``latest`` is the newest run that is *not* damaged; reading it by id is one line;
* two processes writing one run (two ``run --resume`` at once): the writer holds an OS
  lock (``fcntl.flock`` on ``run.lock`` in the run folder, holding the writer's pid, and
  present only while held) from the moment the run is marked running until it is marked
  finished or interrupted, or its process dies; another writer gets a StoreError naming
  the run and the holder's pid;
* plugin files: a new run records the path and SHA-256 of every plugin file providing
  one of its methods (``plugins`` in run.json); ``Run.check_plugins`` refuses to resume
  or re-fit a run whose plugin files are absent, changed, not loaded, or new.

Resuming is prepared in one place, ``Run.prepare_resume``: the damage and plugin checks,
the lock, the removal of cut-short temporary files, and the lists of damaged and
finished jobs, for every plan the runner executes (an experiment, a learning curve).
"""

from __future__ import annotations

import calendar
import contextlib
import errno
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import tomli_w

from enginebench.errors import StoreError

try:
    import fcntl
except ImportError:  # not POSIX: runs are written unlocked
    fcntl = None  # type: ignore[assignment]

DEFAULT_STORE = "enginebench-runs"
JOB_META_KEY = b"enginebench.job"
LOCK_FILE = "run.lock"
"""The lock file of a run folder (see ``Run.lock``)."""
SELECTION_DIR = "selection"
"""The folder of a run holding one selection table per job that selected hyperparameters."""
SELECTION_META = "selection_table"
"""The key under which a job's metadata brings its selection table (a DataFrame) to ``Run.write_job``."""
SELECTION_COLUMNS = {"target": "str", "window": "float64", "split": "str", "method": "str", "repetition": "int64",
                     "point": "int64", "resample": "int64", "score": "float64", "criterion": "str", "chosen": "bool"}
"""The fixed columns of ``Run.selection_table`` (the ``param:<name>`` columns come after ``point``)."""
REQUIRED_FILES = ("run.json", "config.toml", "environment.json")
"""The files every run folder needs; a run missing one is damaged."""


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


_HELD: dict[str, int] = {}
"""Run folder -> open lock file descriptor, for the run locks this process holds."""


def _lock_key(path: Path) -> str:
    return str(Path(path).resolve())


def _lock_holder(fd: int) -> str:
    """The pid written in a lock file, for messages ('unknown' when unreadable)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        return "unknown"
    return text if text.isdigit() else "unknown"


def methods_used(config: dict[str, Any]) -> list[str]:
    """The method names a run's config uses: its methods and any method an option names (a cascade's stages)."""
    names = [str(m) for m in config.get("methods", []) if isinstance(m, str)]
    options = config.get("method_options", {})
    for opts in (options.values() if isinstance(options, dict) else []):
        if isinstance(opts, dict):
            names += [v for v in opts.values() if isinstance(v, str) and v not in names]
    return names


def _jsonable(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars and arrays become numbers and lists."""
    return json.loads(json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))


def _wall_time(before: dict[str, Any], changes: dict[str, Any], now_ns: int) -> dict[str, Any]:
    """What a status change adds to run.json: ``started_ns`` when the run is marked running (a new session), and
    the session's seconds added to ``wall_s`` when a running run gets another status."""
    status = changes.get("status")
    if status == "running":
        return {"started_ns": now_ns}
    start = before.get("started_ns", before.get("created_ns"))
    if status is None or before.get("status") != "running" or not isinstance(start, int):
        return {}
    return {"wall_s": round(float(before.get("wall_s") or 0.0) + (now_ns - start) / 1e9, 3)}


@dataclass(frozen=True)
class ResumeState:
    """What ``Run.prepare_resume`` found: the jobs to keep and the damaged job files to compute again."""

    finished: frozenset[str]
    """Keys of the jobs whose files are complete and readable."""
    damaged: dict[str, str]
    """Job key -> why its file is damaged."""


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
    def selection_dir(self) -> Path:
        return self.path / SELECTION_DIR

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

    def _damaged(self, name: str, why: str) -> StoreError:
        return StoreError(f"run {self.id}: {name} {why}; the run folder is damaged "
                          f"(`enginebench runs rm {self.id}` removes it)")

    def _load_object(self, name: str) -> dict[str, Any] | str:
        """run.json / environment.json / config.toml as a dict, or why it cannot be (a phrase)."""
        import tomllib

        try:
            text = (self.path / name).read_text(encoding="utf-8")
        except FileNotFoundError:
            return "is missing"
        except (OSError, ValueError) as exc:
            return f"is unreadable ({_damage(exc)})"
        try:
            data = tomllib.loads(text) if name.endswith(".toml") else json.loads(text)
        except ValueError as exc:
            return f"is not valid {'TOML' if name.endswith('.toml') else 'JSON'} ({_damage(exc)})"
        return data if isinstance(data, dict) else "does not hold a table of keys"

    def _read_object(self, name: str) -> dict[str, Any]:
        data = self._load_object(name)
        if isinstance(data, str):
            raise self._damaged(name, data)
        return data

    def info(self) -> dict[str, Any]:
        """run.json: id, name, status, config hash, job counts, times, recorded plugins."""
        return self._read_object("run.json")

    def update_info(self, **changes: Any) -> None:
        """Change run.json under the run's lock; the lock is kept while the status is running, else released.

        A status change also keeps ``wall_s``, the seconds the run has spent running over
        all its sessions (a session starts at creation or ``status="running"`` and ends
        at any other status; a session cut short by a kill is not counted).
        """
        held = self.holds_lock()
        self.lock()
        keep = held
        try:
            before = self.info()
            info = {**before, **changes, **_wall_time(before, changes, time.time_ns())}
            keep = info.get("status") == "running"
            self._write(self.path / "run.json", json.dumps(_jsonable(info), indent=2).encode(), "the run's status file")
        finally:
            if not keep:
                self.unlock()

    def config(self) -> dict[str, Any]:
        """config.toml: the resolved experiment."""
        return self._read_object("config.toml")

    def environment(self) -> dict[str, Any]:
        """environment.json: package versions, git commit, CPU/GPU, seeds."""
        return self._read_object("environment.json")

    def damage(self) -> str | None:
        """Why this run folder is damaged (a required file missing or unreadable), or None when it is whole."""
        for name in REQUIRED_FILES:
            data = self._load_object(name)
            if isinstance(data, str):
                return f"{name} {data}"
        return None

    # -- the write lock ------------------------------------------------------------
    def holds_lock(self) -> bool:
        """Whether this process holds the run's write lock."""
        return _lock_key(self.path) in _HELD

    def lock(self) -> None:
        """Take the run's write lock for this process, or fail with the holder's pid (no-op when held already).

        An OS lock (``fcntl.flock``) on ``run.lock``, which exists only while a writer
        holds it: the holder removes it before releasing, and a process that locked a
        file already removed tries again. The kernel releases the lock when the process
        dies (a killed run can be resumed at once; its stale file is reused). Where the
        file system has no locks (or the platform no ``fcntl``) the run is written unlocked.
        """
        key = _lock_key(self.path)
        if key in _HELD or fcntl is None:
            return
        path = self.path / LOCK_FILE
        for _ in range(100):
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise _write_failed(path, exc, self.store, "the run's lock file", "run again") from exc
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                holder = _lock_holder(fd)
                os.close(fd)
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise StoreError(
                        f"run {self.id} is being written by another process (pid {holder}, lock {path}); "
                        f"wait for it to end (or stop it), then `enginebench run --resume {self.id}` if it is unfinished"
                    ) from None
                return  # no locks on this file system
            try:
                current = os.stat(path).st_ino
            except FileNotFoundError:
                current = None
            if current != os.fstat(fd).st_ino:  # the previous holder removed this file as we locked it
                os.close(fd)
                continue
            try:
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
            except OSError:
                pass  # the pid is only for messages
            _HELD[key] = fd
            return
        raise StoreError(f"run {self.id}: cannot take the lock {path} (it keeps being replaced); run again")

    def unlock(self) -> None:
        """Release the run's write lock if this process holds it (its lock file is removed first)."""
        fd = _HELD.pop(_lock_key(self.path), None)
        if fd is not None:
            try:
                (self.path / LOCK_FILE).unlink(missing_ok=True)
            except OSError:
                pass  # a folder that is gone (runs rm) or read-only: the lock is released anyway
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)
            finally:
                os.close(fd)

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Hold the lock for one write (kept if this process held it before)."""
        held = self.holds_lock()
        self.lock()
        try:
            yield
        finally:
            if not held:
                self.unlock()

    # -- plugins ---------------------------------------------------------------------
    def plugins(self) -> list[dict[str, Any]] | None:
        """The plugin files the run recorded (path, sha256, methods), or None for a run made before they were recorded."""
        recorded = self.info().get("plugins")
        if recorded is None:
            return None
        if not isinstance(recorded, list) or not all(isinstance(r, dict) for r in recorded):
            raise self._damaged("run.json", "has a 'plugins' entry that is not a list of objects")
        return recorded

    def check_plugins(self, doing: str = "resumed") -> None:
        """Refuse (StoreError, one line) when this process's plugin files are not those the run was made with."""
        from enginebench.methods.registry import plugin_mismatches

        recorded = self.plugins()
        if recorded is None:
            return
        problems = plugin_mismatches(recorded, methods_used(self.config()))
        if problems:
            raise StoreError(f"run {self.id} cannot be {doing}: " + "; ".join(problems)
                             + "; use the plugin files the run was made with (`enginebench runs show` lists them)")

    # -- resuming --------------------------------------------------------------------
    def prepare_resume(self) -> "ResumeState":
        """Make the run ready to be finished by this process; every resume check and clean-up is here.

        In order: refuse a damaged run folder and plugin files other than the run's (one
        StoreError line each, nothing touched); take the write lock (a second writer is
        refused, naming the holder); remove temporary files of writes cut short by a kill;
        then list the damaged job files (computed again) and the finished jobs (kept). The
        lock is held until the run is marked finished or interrupted (``update_info``) or
        ``unlock`` is called (what a caller does when it fails before that).
        """
        why = self.damage()
        if why is not None:
            raise StoreError(f"run {self.id} cannot be resumed: {why}, so the run folder is damaged; start a new run "
                             f"(`enginebench runs rm {self.id}` removes this one)")
        self.check_plugins("resumed")
        self.lock()
        try:
            for folder in (self.jobs_dir, self.selection_dir):
                for stale in folder.glob(".*.tmp"):  # a write cut short by a kill: never a finished job
                    stale.unlink(missing_ok=True)
            damaged = self.damaged_jobs()
            finished = self.finished_jobs(verify=False) - set(damaged)
        except BaseException:
            self.unlock()
            raise
        return ResumeState(frozenset(finished), damaged)

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
                meta = self._load_job(p, frame=False)[1]
            except READ_ERRORS as exc:
                out[p.stem] = _damage(exc)
                continue
            why = self._selection_bytes(p.stem, meta)[1]
            if why is not None:
                out[p.stem] = why
        return out

    def _selection_bytes(self, key: str, meta: dict[str, Any]) -> tuple[bytes | None, str | None]:
        """(the selection file's bytes, None) when the job recorded one and it is intact, (None, why) when it
        is damaged, (None, None) when the job has no selection table."""
        record = meta.get("selection_file")
        if record is None:
            return None, None
        path = self.selection_dir / f"{key}.parquet"
        if not isinstance(record, dict) or not isinstance(record.get("sha256"), str):
            return None, "its record of the selection table is garbled"
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None, f"its selection table {path} is missing"
        except OSError as exc:
            return None, f"its selection table {path} is unreadable ({_damage(exc)})"
        if hashlib.sha256(data).hexdigest() != record["sha256"]:
            return None, f"its selection table {path} does not match the SHA-256 recorded in the job file"
        return data, None

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
        """Write one finished job's metric rows and metadata atomically (StoreError on a failed write).

        A selection table in ``meta`` (a DataFrame under ``SELECTION_META``) becomes the file
        ``selection/<key>.parquet``, its SHA-256 and row count recorded in the job's metadata
        (``selection_file``). The job file is written first, then the table; when the
        table's write fails the job file is removed again, so a job is finished only with
        both (a kill between the two leaves a job that ``damaged_jobs`` lists).
        """
        meta = dict(meta)
        selection = meta.pop(SELECTION_META, None)
        data = None
        if isinstance(selection, pd.DataFrame) and len(selection):
            data = _table_bytes(pa.Table.from_pandas(selection, preserve_index=False))
            meta["selection_file"] = {"sha256": hashlib.sha256(data).hexdigest(), "rows": len(selection)}
        table = pa.Table.from_pandas(rows, preserve_index=False)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), JOB_META_KEY: json.dumps(_jsonable(meta)).encode()})
        path = self.jobs_dir / f"{key}.parquet"
        selection_path = self.selection_dir / f"{key}.parquet"
        with self._writing():
            self._write(path, _table_bytes(table), f"job {key} of run {self.id} to")
            if data is None:
                with contextlib.suppress(OSError):  # an earlier attempt's table belongs to no job now
                    selection_path.unlink(missing_ok=True)
                return path
            try:
                self._write(selection_path, data, f"the selection table of job {key} of run {self.id} to")
            except BaseException:
                with contextlib.suppress(OSError):
                    path.unlink(missing_ok=True)  # not finished without its table
                raise
        return path

    def write_table(self, relative: str, frame: pd.DataFrame) -> Path:
        """Store an extra artefact table (rankings, predictions) inside the run, atomically."""
        path = self.path / relative
        with self._writing():
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

    def job_metas(self) -> dict[str, dict[str, Any]]:
        """Job key -> metadata of every readable job file (damaged files are left out: ``damaged_jobs`` names them)."""
        out = {}
        for path in self.job_files():
            try:
                out[path.stem] = self._load_job(path, frame=False)[1]
            except READ_ERRORS:
                continue
        return out

    def selection_table(self, job_key: str | None = None) -> pd.DataFrame:
        """The model-selection scores of the run's jobs (one job's with ``job_key``), one row per grid point and resample.

        Columns: target, window, split, method, repetition (the job's coordinates), point
        (index in the grid's order), one ``param:<name>`` column per hyperparameter (float,
        or text for non-numeric values; empty where a job's method lacks the parameter),
        resample (index of the bootstrap resample or fold; 0 for a validation part), score
        (the criterion, +inf for non-finite predictions), criterion (its name) and chosen
        (True on every row of the selected point). An empty frame with the fixed columns
        (``SELECTION_COLUMNS``) when there is none: methods with nothing to select, runs
        made before tables were stored. A damaged or missing table is a StoreError naming
        its file.
        """
        if job_key is None:
            paths = self.job_files()
        else:
            paths = [self.jobs_dir / f"{job_key}.parquet"]
            if not paths[0].is_file():
                raise StoreError(f"run {self.id}: job {job_key} has no file {paths[0]}; {self._resume_hint()}")
        frames = []
        for path in paths:
            try:
                meta = self._load_job(path, frame=False)[1]
            except READ_ERRORS as exc:
                raise StoreError(f"run {self.id}: job file {path} is damaged ({_damage(exc)}); the other jobs are "
                                 f"intact: `enginebench run --resume {self.id}` recomputes this one") from None
            data, why = self._selection_bytes(path.stem, meta)
            if why is None and data is not None:
                try:
                    frames.append(pq.read_table(pa.BufferReader(data), page_checksum_verification=True).to_pandas())
                except READ_ERRORS as exc:
                    why = f"its selection table {self.selection_dir / path.name} is damaged ({_damage(exc)})"
            if why is not None:
                raise StoreError(f"run {self.id}: job {path.stem}: {why}; its metrics are intact: "
                                 f"`enginebench run --resume {self.id}` recomputes the job")
        empty = pd.DataFrame({c: pd.Series(dtype=t) for c, t in SELECTION_COLUMNS.items()})
        if not frames:
            return empty
        out = pd.concat(frames, ignore_index=True)
        params = [c for c in out.columns if c.startswith("param:")]
        fixed = list(SELECTION_COLUMNS)
        at = fixed.index("point") + 1
        return out[fixed[:at] + params + fixed[at:]].astype(SELECTION_COLUMNS)

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

    def create(self, name: str, config: dict[str, Any], config_hash: str, environment: dict[str, Any], n_jobs: int,
               plugins: list[dict[str, Any]] | None = None, tags: dict[str, str] | None = None) -> Run:
        """A new run folder with its config, environment and run.json (status running), locked by this process.

        run.json is written last: until it exists the folder is not a run (``runs`` skips
        it), and a failed write removes the folder again. ``plugins`` (path, sha256,
        methods of each plugin file) defaults to the plugin files this process loaded for
        the config's methods (``methods.registry.plugin_records``). ``tags`` (KEY -> VALUE,
        checked by ``results.catalog.check_tags``) label the run; they are not part of the config.
        """
        if plugins is None:
            from enginebench.methods.registry import plugin_records

            plugins = plugin_records(methods_used(config))
        created_ns = time.time_ns()
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(created_ns / 1e9))
        path = self._claim(f"{stamp}-{_slug(name)}-{config_hash[:6]}")
        run = Run(path)
        try:
            run.lock()
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
                "created_ns": created_ns, "pid": os.getpid(), "plugins": plugins, "tags": dict(tags or {}),
            }, indent=2).encode(), "the run's status file")
        except BaseException:
            run.unlock()
            shutil.rmtree(path, ignore_errors=True)
            raise
        return run

    def runs(self) -> list[Run]:
        """Every run of the store (a folder with a run.json), oldest first."""
        if not self.root.is_dir():
            return []
        return sorted((Run(p) for p in self.root.iterdir() if (p / "run.json").is_file()), key=_order)

    def get(self, ref: str) -> Run:
        """A run by id, unique id prefix, path, or 'latest': the run created last among those not damaged.

        A damaged run (``Run.damage``) is skipped by 'latest' so that one broken folder
        does not stop every command; it is still reached by its id (to show or remove it).
        """
        path = Path(ref)
        if (path / "run.json").is_file():
            return Run(path)
        runs = self.runs()
        if ref == "latest":
            if not runs:
                raise StoreError(f"no runs in {self.root}")
            for run in reversed(runs):
                if run.damage() is None:
                    return run
            raise StoreError(f"every run in {self.root} is damaged; 'enginebench runs list' says why")
        matches = [r for r in runs if r.id == ref] or [r for r in runs if r.id.startswith(ref)]
        if not matches:
            raise StoreError(f"no run {ref!r} in {self.root}; 'enginebench runs list' shows the runs")
        if len(matches) > 1:
            raise StoreError(f"run reference {ref!r} is ambiguous in {self.root}: {', '.join(r.id for r in matches[:5])}")
        return matches[0]
