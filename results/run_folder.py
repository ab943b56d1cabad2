"""One run folder and its files (``Run``): status, config, environment, job files, selection tables, resuming.

Layout of a run folder (the store of them is ``results.store.RunStore``)::

    <run-id>/
      run.json                        id, name, status, config hash, job count, times, tags
      config.toml                     the resolved experiment
      environment.json                package versions, git commit, CPU/GPU, seeds
      jobs/<job-key>.parquet          metric rows of one finished job (``results.job_files``)
      selection/<job-key>.parquet     the job's model-selection scores, for jobs that selected
      models/<job-key>.npz            the job's fitted model, with [store] models = true (results.model_store)

Every file is written atomically (``results.atomic``) under the run's write lock
(``results.run_lock``); damaged job files and selection tables are checked in
``results.job_files``.

Faults handled here:

* a damaged run folder (run.json, config.toml or environment.json missing, unreadable
  (permission denied, a folder or a dangling link in its place, bytes that are not UTF-8),
  not valid JSON/TOML or with a garbled field; jobs/ missing, not a folder or unreadable;
  the run folder itself unreadable): ``Run.damage()`` says why and never raises, ``runs
  list`` shows it as damaged with that reason, and ``latest`` is the newest run that is
  *not* damaged, so one such folder never stops a command for the whole store; reading
  it by id is one line;
* plugin files: a new run records the path and SHA-256 of every plugin file providing
  one of its methods (``plugins`` in run.json); ``Run.check_plugins`` refuses to resume
  or re-fit a run whose plugin files are absent, changed, not loaded, or new.

Resuming is prepared in one place, ``Run.prepare_resume``: the damage and plugin checks,
the lock, the removal of cut-short temporary files, and the lists of damaged and
finished jobs, for every plan the runner executes (an experiment, a learning curve).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa

from enginebench.errors import StoreError
from enginebench.results import run_lock
from enginebench.results.atomic import READ_ERRORS, atomic_write_bytes, damage_text, read_parquet, table_bytes, write_failed
from enginebench.results.model_store import MODEL_META, MODELS_DIR
from enginebench.results.job_files import (
    SELECTION_DIR, encode_job, job_rows_frame, jsonable, load_job, read_selection, selection_bytes, selection_frame,
)

if TYPE_CHECKING:  # pandas is imported where a frame is made: listing runs reads none (issue 35)
    import pandas as pd

REQUIRED_FILES = ("run.json", "config.toml", "environment.json")
"""The files every run folder needs; a run missing one is damaged."""


def methods_used(config: dict[str, Any]) -> list[str]:
    """The method names a run's config uses: its methods and any method an option names (a cascade's stages)."""
    names = [str(m) for m in config.get("methods", []) if isinstance(m, str)]
    options = config.get("method_options", {})
    for opts in (options.values() if isinstance(options, dict) else []):
        if isinstance(opts, dict):
            names += [v for v in opts.values() if isinstance(v, str) and v not in names]
    return names




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


RUN_FIELDS: dict[str, tuple[type, ...]] = {"tags": (dict, type(None)), "resumes": (list, type(None)),
                                           "status": (str,)}
"""run.json fields every command reads, with the shapes they must have (a garbled one makes the run damaged;
``plugins`` has its own check, ``Run.plugins``)."""


def _bad_field(info: dict[str, Any]) -> str | None:
    """Why a run.json field has a shape no command can read (a garbled edit), or None."""
    for key, kinds in RUN_FIELDS.items():
        value = info.get(key)
        if key in info and (not isinstance(value, kinds) or isinstance(value, bool) and bool not in kinds):
            return f"field {key!r} is {type(value).__name__} {json.dumps(value)[:40]}, not a {kinds[0].__name__}"
    tags = info.get("tags") or {}
    if not all(isinstance(k, str) and isinstance(v, str) for k, v in tags.items()):
        return "field 'tags' holds a value that is not text"
    if not all(isinstance(r, dict) for r in info.get("resumes") or []):
        return "field 'resumes' holds an entry that is not a table"
    return None


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

    def __post_init__(self) -> None:
        if not isinstance(self.path, (str, os.PathLike)):
            raise TypeError(f"Run takes a run folder (str or Path), not {type(self.path).__name__} {self.path!r}; "
                            "enginebench.api.open_run opens a run by id or folder")
        self.path = Path(self.path)

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
            atomic_write_bytes(path, data)
        except OSError as exc:
            raise write_failed(path, exc, self.store, what, self._resume_hint()) from exc

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
            return f"is unreadable ({damage_text(exc)})"
        try:
            data = tomllib.loads(text) if name.endswith(".toml") else json.loads(text)
        except ValueError as exc:
            return f"is not valid {'TOML' if name.endswith('.toml') else 'JSON'} ({damage_text(exc)})"
        if not isinstance(data, dict):
            return "does not hold a table of keys"
        return _bad_field(data) if name == "run.json" and _bad_field(data) else data

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
            self._write(self.path / "run.json", json.dumps(jsonable(info), indent=2).encode(), "the run's status file")
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
        """Why this run folder is damaged (a required file missing or unreadable, its jobs folder missing, not a
        folder or unreadable), or None when it is whole; never raises."""
        for name in REQUIRED_FILES:
            data = self._load_object(name)
            if isinstance(data, str):
                return f"{name} {data}"
        try:
            if not self.jobs_dir.is_dir():
                return "jobs/ is " + ("not a folder" if os.path.lexists(self.jobs_dir) else "missing")
            os.listdir(self.jobs_dir)
        except OSError as exc:
            return f"jobs/ is unreadable ({damage_text(exc)})"
        return None

    # -- the write lock (results.run_lock) ------------------------------------------
    def holds_lock(self) -> bool:
        """Whether this process holds the run's write lock."""
        return run_lock.holds(self.path)

    def lock(self) -> None:
        """Take the run's write lock for this process, or fail with the holder's pid (no-op when held already);
        see ``results.run_lock.acquire``."""
        run_lock.acquire(self.path, self.id)

    def unlock(self) -> None:
        """Release the run's write lock if this process holds it (its lock file is removed first)."""
        run_lock.release(self.path)

    def _writing(self) -> contextlib.AbstractContextManager[None]:
        """Hold the lock for one write (kept if this process held it before)."""
        return run_lock.holding(self.path, self.id)

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
        from enginebench.registry import plugin_mismatches

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
        return load_job(path, frame=frame)

    def _read_job(self, path: Path) -> tuple[pd.DataFrame, dict[str, Any]]:
        """A job file's rows and metadata; StoreError naming the file when it is damaged."""
        try:
            return self._load_job(path)  # type: ignore[return-value]
        except READ_ERRORS as exc:
            raise StoreError(
                f"run {self.id}: job file {path} is damaged ({damage_text(exc)}); the other jobs are intact: "
                f"`enginebench run --resume {self.id}` recomputes this one"
            ) from None

    def damaged_jobs(self) -> dict[str, str]:
        """Job key -> why its file cannot be read back whole, for every damaged job file present."""
        out = {}
        for p in self.job_files():
            try:
                meta = self._load_job(p, frame=False)[1]
            except READ_ERRORS as exc:
                out[p.stem] = damage_text(exc)
                continue
            why = self._selection_bytes(p.stem, meta)[1]
            if why is not None:
                out[p.stem] = why
        return out

    def _selection_bytes(self, key: str, meta: dict[str, Any]) -> tuple[bytes | None, str | None]:
        """The job ``key``'s selection file checked against its record (``job_files.selection_bytes``)."""
        return selection_bytes(self.selection_dir / f"{key}.parquet", meta)

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
        model = meta.get(MODEL_META)  # a stored model (results/model_store.py): written first, its SHA-256 recorded
        if model is not None:
            meta = {k: v for k, v in meta.items() if k != MODEL_META}
            meta["model_file"] = {"sha256": hashlib.sha256(model).hexdigest(), "bytes": len(model)}
        job, data = encode_job(rows, meta)
        path = self.jobs_dir / f"{key}.parquet"
        selection_path = self.selection_dir / f"{key}.parquet"
        with self._writing():
            if model is not None:
                (self.path / MODELS_DIR).mkdir(exist_ok=True)
                self._write(self.path / MODELS_DIR / f"{key}.npz", model, f"the stored model of job {key} of run {self.id} to")
            self._write(path, job, f"job {key} of run {self.id} to")
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
            self._write(path, table_bytes(pa.Table.from_pandas(frame, preserve_index=False)), "the table")
        return path

    def read_table(self, relative: str) -> pd.DataFrame:
        path = self.path / relative
        try:
            return read_parquet(path).to_pandas()
        except READ_ERRORS as exc:
            raise StoreError(f"run {self.id}: {path} is unreadable ({damage_text(exc)}); compute it again") from None

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
                raise StoreError(f"run {self.id}: job file {path} is damaged ({damage_text(exc)}); the other jobs are "
                                 f"intact: `enginebench run --resume {self.id}` recomputes this one") from None
            data, why = self._selection_bytes(path.stem, meta)
            if why is None and data is not None:
                try:
                    frames.append(read_selection(data))
                except READ_ERRORS as exc:
                    why = f"its selection table {self.selection_dir / path.name} is damaged ({damage_text(exc)})"
            if why is not None:
                raise StoreError(f"run {self.id}: job {path.stem}: {why}; its metrics are intact: "
                                 f"`enginebench run --resume {self.id}` recomputes the job")
        return selection_frame(frames)

    def metrics(self) -> pd.DataFrame:
        """All metric rows of all finished jobs (one long frame); a damaged job file is refused by name."""
        files = self.job_files()
        why = None if files else self.damage()
        if why is not None:
            raise StoreError(f"run {self.id}: {why}; the run folder is damaged (`enginebench runs rm {self.id}` removes it)")
        if not files:
            raise StoreError(f"run {self.id} has no finished job yet")
        together = job_rows_frame(files)  # one conversion to pandas for all files (the same frame, faster)
        if together is not None:
            return together
        import pandas as pd

        return pd.concat([self._read_job(p)[0] for p in files], ignore_index=True)
