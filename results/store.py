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
"""

from __future__ import annotations

import json
import os
import re
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


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _atomic_write_table(path: Path, table: pa.Table) -> None:
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink)
    _atomic_write_bytes(path, sink.getvalue().to_pybytes())


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

    def info(self) -> dict[str, Any]:
        try:
            return json.loads((self.path / "run.json").read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise StoreError(f"run {self.id}: run.json unreadable ({exc}); the run folder is damaged") from None

    def update_info(self, **changes: Any) -> None:
        info = {**self.info(), **changes}
        _atomic_write_bytes(self.path / "run.json", json.dumps(_jsonable(info), indent=2).encode())

    def config(self) -> dict[str, Any]:
        import tomllib

        return tomllib.loads((self.path / "config.toml").read_text())

    def environment(self) -> dict[str, Any]:
        return json.loads((self.path / "environment.json").read_text())

    def finished_jobs(self) -> set[str]:
        if not self.jobs_dir.is_dir():
            return set()
        return {p.stem for p in self.jobs_dir.glob("*.parquet") if not p.name.startswith(".")}

    def write_job(self, key: str, rows: pd.DataFrame, meta: dict[str, Any]) -> Path:
        table = pa.Table.from_pandas(rows, preserve_index=False)
        table = table.replace_schema_metadata({**(table.schema.metadata or {}), JOB_META_KEY: json.dumps(_jsonable(meta)).encode()})
        path = self.jobs_dir / f"{key}.parquet"
        _atomic_write_table(path, table)
        return path

    def write_table(self, relative: str, frame: pd.DataFrame) -> Path:
        """Store an extra artefact table (rankings, predictions) inside the run, atomically."""
        path = self.path / relative
        _atomic_write_table(path, pa.Table.from_pandas(frame, preserve_index=False))
        return path

    def read_table(self, relative: str) -> pd.DataFrame:
        return pq.read_table(self.path / relative).to_pandas()

    def job_meta(self, key: str) -> dict[str, Any]:
        path = self.jobs_dir / f"{key}.parquet"
        try:
            md = pq.read_schema(path).metadata or {}
        except (OSError, pa.ArrowInvalid) as exc:
            raise StoreError(f"run {self.id}: job file {path.name} is unreadable ({exc}); delete it and resume the run") from None
        return json.loads(md.get(JOB_META_KEY, b"{}"))

    def metrics(self) -> pd.DataFrame:
        """All metric rows of all finished jobs (one long frame)."""
        files = sorted(p for p in self.jobs_dir.glob("*.parquet") if not p.name.startswith("."))
        if not files:
            raise StoreError(f"run {self.id} has no finished job yet")
        frames = []
        for p in files:
            try:
                frames.append(pq.read_table(p).to_pandas())
            except (OSError, pa.ArrowInvalid) as exc:
                raise StoreError(f"run {self.id}: job file {p.name} is unreadable ({exc}); delete it and resume the run") from None
        return pd.concat(frames, ignore_index=True)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "run"


class RunStore:
    """A folder of runs."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = store_root(root)

    def create(self, name: str, config: dict[str, Any], config_hash: str, environment: dict[str, Any], n_jobs: int) -> Run:
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime())
        base = f"{stamp}-{_slug(name)}-{config_hash[:6]}"
        self.root.mkdir(parents=True, exist_ok=True)
        for k in range(1000):
            path = self.root / (base if k == 0 else f"{base}-{k}")
            try:
                path.mkdir()
                break
            except FileExistsError:
                continue
        else:  # pragma: no cover - a thousand runs in one second
            raise StoreError(f"cannot create a run folder under {self.root}")
        run = Run(path)
        (path / "jobs").mkdir()
        _atomic_write_bytes(path / "config.toml", tomli_w.dumps(_jsonable(config)).encode())
        _atomic_write_bytes(path / "environment.json", json.dumps(_jsonable(environment), indent=2).encode())
        _atomic_write_bytes(path / "run.json", json.dumps({
            "id": run.id, "name": name, "status": "running", "config_hash": config_hash, "n_jobs": n_jobs,
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        }, indent=2).encode())
        return run

    def runs(self) -> list[Run]:
        if not self.root.is_dir():
            return []
        return sorted((Run(p) for p in self.root.iterdir() if (p / "run.json").is_file()), key=lambda r: r.id)

    def get(self, ref: str) -> Run:
        """A run by id, unique id prefix, 'latest', or path."""
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
