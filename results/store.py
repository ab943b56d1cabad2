"""The run store: a folder of runs (``RunStore``): create (claim a folder), list, get by reference.

Layout::

    enginebench-runs/                   (--store, $ENGINEBENCH_STORE)
      <run-id>/                         one run folder (``Run``, results.run_folder)
        run.json                        id, name, status, config hash, job count, times, tags
        config.toml                     the resolved experiment
        environment.json                package versions, git commit, CPU/GPU, seeds
        jobs/<job-key>.parquet          metric rows of one finished job; params,
                                        describe() and timings in the file's metadata
        selection/<job-key>.parquet     the job's model-selection scores (one row per grid
                                        point and resample or fold), for jobs that selected;
                                        its SHA-256 is in the job file's metadata

The store's parts, one job each: ``results.atomic`` (atomic, checksummed writes; a full
disk), ``results.run_lock`` (one writer per run), ``results.job_files`` (job files and
selection tables; their damage), ``results.run_folder`` (``Run``: one run folder; a
damaged folder, plugin files, resuming) and this module (``RunStore``, ``open_run``).

Faults handled here: a destructive command given a path outside the store, ``.``, or an empty
reference (an unset ``$RUN``): ``get_own`` refuses all three, so ``runs rm`` deletes only run
folders directly inside the store. Two processes creating runs at once: run folders are claimed with an
atomic ``mkdir`` (a taken name gets the next free ``-k`` suffix), so run ids are distinct
and no run writes into another's folder; ``latest`` is the run created last
(``created_ns`` in run.json, then the id), whatever the ids' spelling, among the runs
that are not damaged. One unreadable run folder (run.json or another required file
missing, a folder or a link loop in its place, permission denied, bytes that are not
UTF-8, not JSON; jobs/ missing or not a folder; the folder itself unreadable) never
breaks a command for the whole store: ``runs`` lists it (a folder with anything named
run.json, or one this process may not look into, is a run), ``Run.damage`` says why
without raising, ``runs list`` shows it as damaged with that reason, and ``latest``
skips it.
"""

from __future__ import annotations

import calendar
import json
import os
import re
import shutil
import time
from pathlib import Path
from typing import Any

import tomli_w

from enginebench.errors import StoreError
from enginebench.results.atomic import write_failed
from enginebench.results.job_files import jsonable
from enginebench.results.run_folder import Run, methods_used

__all__ = [
    "DEFAULT_STORE", "RunStore", "open_run", "store_root"
]

DEFAULT_STORE = "enginebench-runs"


def store_root(path: str | Path | None = None) -> Path:
    """The store folder: explicit path, else $ENGINEBENCH_STORE, else ./enginebench-runs."""
    if path:
        return Path(path)
    return Path(os.environ.get("ENGINEBENCH_STORE") or DEFAULT_STORE)


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


def _looks_like_run(path: Path) -> bool:
    """A run folder: it has a run.json (or something else under that name: a folder, a dangling link, which
    ``Run.damage`` reports), or (a damaged one) a run's other parts and is not being created now. A folder of the
    store this process may not look into (permission denied) is listed too, as damaged."""
    try:
        if not path.is_dir():
            return False
        if path.is_symlink():
            return (path / "run.json").is_file()
        if (path / "run.json").is_file() or os.path.lexists(path / "run.json"):
            return True
        parts = any((path / name).exists() for name in ("config.toml", "environment.json", "jobs"))
        return parts and time.time() - path.stat().st_mtime > CREATING_S
    except FileNotFoundError:  # removed while the store was read
        return False
    except OSError:
        return True


CREATING_S = 60.0
"""A run folder without run.json younger than this is being created (run.json is written last), not damaged."""


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
            raise write_failed(self.root, exc, None, "the run store", "run again") from exc
        for k in range(10_000):
            path = self.root / (base if k == 0 else f"{base}-{k}")
            try:
                path.mkdir()
                return path
            except FileExistsError:
                continue
            except OSError as exc:
                raise write_failed(path, exc, self.root, "the run folder", "run again") from exc
        raise StoreError(f"cannot create a run folder under {self.root}: {base} and 10000 variants are taken")

    def create(self, name: str, config: dict[str, Any], config_hash: str, environment: dict[str, Any], n_jobs: int,
               plugins: list[dict[str, Any]] | None = None, tags: dict[str, str] | None = None) -> Run:
        """A new run folder with its config, environment and run.json (status running), locked by this process.

        run.json is written last: until it exists the folder is not a run (``runs`` skips
        it), and a failed write removes the folder again. ``plugins`` (path, sha256,
        methods of each plugin file) defaults to the plugin files this process loaded for
        the config's methods (``enginebench.registry.plugin_records``). ``tags`` (KEY -> VALUE,
        checked by ``results.catalog.check_tags``) label the run; they are not part of the config.
        """
        if plugins is None:
            from enginebench.registry import plugin_records

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
                raise write_failed(path / "jobs", exc, self.root, "the jobs folder", "run again") from exc
            run._write(path / "config.toml", tomli_w.dumps(jsonable(config)).encode(), "the run's config")
            run._write(path / "environment.json", json.dumps(jsonable(environment), indent=2).encode(),
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
        """Every run of the store, oldest first: each folder with a run.json, and each folder that holds a run's
        other parts (config.toml, environment.json, jobs/) without one, which ``Run.damage`` reports as damaged.
        A folder still being created (claimed less than a minute ago, no run.json yet) is not listed."""
        if not self.root.is_dir():
            return []
        return sorted((Run(p) for p in self.root.iterdir() if _looks_like_run(p)), key=_order)

    def get_own(self, ref: str, doing: str = "deleted") -> Run:
        """A run of this store, for commands that change or delete it: ``get``'s references, but an empty
        reference is refused (an unset ``$RUN`` in a script must not match every id), and the run must be a
        folder directly inside the store holding a run.json (a path to any other folder, ``.`` included,
        is refused: only runs of the store are ``doing``)."""
        if not str(ref).strip():
            raise StoreError(f"an empty run reference (an unset variable in a script?); name a run by its id, a "
                             f"unique id prefix or 'latest' (runs of {self.root} are {doing} only by name)")
        run = self.get(ref)
        root, path = self.root.resolve(), run.path
        inside = not path.is_symlink() and path.resolve().parent == root and (path / "run.json").is_file()
        if not inside and not path.is_symlink() and path.resolve().parent == root:
            raise StoreError(f"{ref}: run folder {path} has no run.json, so it is not known to be a complete run of "
                             f"the store; it is not {doing} by enginebench: remove it by hand if it is yours")
        if not inside:
            raise StoreError(f"{ref}: {path.resolve()} is not a run folder of the store {root}; only runs of the store "
                             f"are {doing} (give its id, or --store for another store)")
        return run

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


def open_run(ref: str | os.PathLike[str], store: str | os.PathLike[str] | None = None) -> Run:
    """A run by its folder or by reference: a ``Path`` (or a string naming an existing folder, or one with a
    path separator) is a run folder; any other string is an id, a unique id prefix or 'latest' in ``store``
    (default: $ENGINEBENCH_STORE, else ./enginebench-runs). A reference that finds no run is a StoreError
    of one line saying what to give instead; a reference of another type is a TypeError."""
    if not isinstance(ref, (str, os.PathLike)):
        raise TypeError(f"open_run takes a run id or a run folder (str or Path), not {type(ref).__name__} {ref!r}")
    text = os.fspath(ref)
    path = Path(text)
    if not isinstance(ref, os.PathLike) and not path.is_dir() and os.sep not in text and "/" not in text:
        return RunStore(store).get(text)
    if not path.is_dir():
        raise StoreError(f"no run folder {path}: it does not exist; give a run's folder, or its id in the store "
                         f"{store_root(store)} ('enginebench runs list' shows them)")
    if not (path / "run.json").is_file() and not _looks_like_run(path):
        raise StoreError(f"{path} is not a run folder (it has no run.json); give a run's folder, or its id in the "
                         f"store {store_root(store)} ('enginebench runs list' shows them)")
    return Run(path)
