"""The run catalogue: one entry per stored run, filters over the entries, and the tags of a run.

``entries(store)`` reads what the store knows of each run (run.json, config.toml, the
job files present, the write lock) into an :class:`Entry`; a damaged run folder becomes
an entry with status ``damaged`` and its reason, so one broken folder never stops a
listing. ``Filters`` select entries by dataset, method, status, tags and creation time;
``catalog_text`` lays them out as a fixed-width table that fits a terminal width,
``catalog_records`` as plain records for CSV and JSON.

A run's status, from what the store knows:

* ``finished``: every job ran and none failed;
* ``failed``: the run finished but some of its jobs failed (``failed_jobs`` says how many);
* ``running``: marked running and its write lock is held (a process is writing it);
* ``interrupted``: stopped before the end (marked so, or marked running with nobody
  holding its lock: the writer was killed); ``run --resume`` finishes it;
* ``damaged``: run.json, config.toml or environment.json is missing or unreadable.

Tags are KEY=VALUE labels kept in run.json (never in the config, so never in the config
hash): given at ``run --tag``, changed by ``edit_tags``.
"""

from __future__ import annotations

import errno
import os
import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any, Iterable, Sequence

from enginebench.errors import SpecError, StoreError
from enginebench.results.run_folder import Run, methods_used
from enginebench.results.run_lock import LOCK_FILE
from enginebench.results.store import RunStore

try:
    import fcntl
except ImportError:  # not POSIX: a run marked running is taken at its word
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "STATUSES", "Entry", "Filters", "catalog_csv", "catalog_records", "catalog_text", "check_tags", "edit_tags", "entries",
    "entry", "parse_since", "parse_tags", "select", "writer_pid",
]

STATUSES = ("finished", "failed", "running", "interrupted", "damaged")
"""Every status a catalogue entry can have (see the module docstring)."""
_AGE = re.compile(r"^(\d+(?:\.\d+)?)([smhdw])$")
_AGE_SECONDS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 604800}


# -- tags -----------------------------------------------------------------------------

def _check_key(key: str, where: str) -> None:
    if not key:
        raise SpecError(f"{where}: the tag has no key; write KEY=VALUE (e.g. --tag owner=ana)")
    if "=" in key or not key.isprintable() or key != key.strip():
        raise SpecError(f"{where}: tag key {key!r} must be printable, without '=' or surrounding spaces")


def check_tags(tags: dict[str, str], where: str = "--tag") -> None:
    """Refuse (SpecError, one line) a tag whose key is empty, holds '=' or is not printable, or whose value is not printable."""
    for key, value in tags.items():
        _check_key(key, where)
        if not isinstance(value, str) or not value.isprintable():
            raise SpecError(f"{where}: the value of tag {key!r} must be printable text, got {value!r}")


def _split(text: str, where: str, value_needed: bool) -> tuple[str, str | None]:
    key, eq, value = text.partition("=")
    if not eq and value_needed:
        raise SpecError(f"{where} {text!r}: write KEY=VALUE (e.g. --tag owner=ana)")
    _check_key(key, f"{where} {text!r}")
    if eq and not value.isprintable():
        raise SpecError(f"{where} {text!r}: the value must be printable text")
    return key, (value if eq else None)


def parse_tags(texts: Iterable[str], where: str = "--tag") -> dict[str, str]:
    """``KEY=VALUE`` texts as a dict (a later value of a key wins); SpecError naming the bad one."""
    return dict(_split(t, where, True) for t in texts)  # type: ignore[misc]


def writer_pid(run: Run) -> str | None:
    """The pid of the process writing ``run`` (holding its write lock), ``"unknown"`` when unreadable, None when none.

    The lock file exists only while held, so no file means no writer. Otherwise the lock
    is probed with a shared, non-blocking ``flock`` released at once (where the file
    system cannot lock, the run's own status is trusted and a writer is assumed).
    """
    if run.holds_lock():
        return str(os.getpid())
    try:
        fd = os.open(run.path / LOCK_FILE, os.O_RDONLY)
    except FileNotFoundError:
        return None
    except OSError:
        return "unknown"
    try:
        if fcntl is None:
            return "unknown"
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return "unknown"  # no locks on this file system
            text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            return text if text.isdigit() else "unknown"
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


def edit_tags(run: Run, add: dict[str, str] | None = None, remove: Sequence[str] = ()) -> dict[str, str]:
    """Set the tags ``add`` and remove the keys ``remove`` in ``run``'s run.json; the tags after the edit.

    Refused with one StoreError line when the run is damaged, another process is writing
    it, or a key to remove is not a tag of the run (nothing is changed then).
    """
    add = dict(add or {})
    check_tags(add)
    why = run.damage()
    if why is not None:
        raise StoreError(f"run {run.id} is damaged ({why}); its tags cannot be changed")
    pid = writer_pid(run)
    if pid is not None and not run.holds_lock():
        raise StoreError(f"run {run.id} is being written by another process (pid {pid}); "
                         "change its tags once that process has ended")
    tags = {str(k): str(v) for k, v in (run.info().get("tags") or {}).items()}
    missing = [k for k in remove if k not in tags]
    if missing:
        have = ", ".join(sorted(tags)) or "none"
        raise StoreError(f"run {run.id} has no tag {', '.join(map(repr, missing))}; its tags: {have}")
    tags = {k: v for k, v in tags.items() if k not in set(remove)} | add
    held = run.holds_lock()
    run.update_info(tags=tags)
    if not held:  # update_info keeps the lock of a run marked running (here: one whose writer died)
        run.unlock()
    return tags


# -- entries ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Entry:
    """What the catalogue knows of one run (fields a damaged run lacks are empty)."""

    id: str
    status: str
    name: str = ""
    dataset: str = ""
    methods: tuple[str, ...] = ()
    used: tuple[str, ...] = ()
    """Every method the run used: its methods and the stages any of them names (``--method`` matches these)."""
    jobs_done: int = 0
    jobs_total: int | None = None
    failed_jobs: int = 0
    created: datetime | None = None
    wall_s: float | None = None
    tags: dict[str, str] = field(default_factory=dict)
    damage: str | None = None


def _read(read) -> dict[str, Any]:
    try:
        return read()
    except StoreError:
        return {}


def _created(run: Run, info: dict[str, Any]) -> datetime | None:
    ns = info.get("created_ns")
    if isinstance(ns, int):
        return datetime.fromtimestamp(ns / 1e9, timezone.utc).astimezone()
    try:  # a run whose run.json is unreadable: the UTC stamp its id starts with
        return datetime.strptime(run.id[:15], "%Y%m%d-%H%M%S").replace(tzinfo=timezone.utc).astimezone()
    except ValueError:
        return None


def _job_count(run: Run) -> int:
    """Job files present; 0 when the jobs folder cannot be read (``Run.damage`` says why)."""
    try:
        return len(run.job_files())
    except OSError:
        return 0


def entry(run: Run, now: datetime | None = None) -> Entry:
    """The catalogue entry of ``run``; never raises for a damaged run folder (its status is ``damaged``)."""
    now = now or datetime.now(timezone.utc)
    damage = run.damage()
    info, cfg = _read(run.info), _read(run.config)
    status = str(info.get("status", "?"))
    started = info.get("started_ns", info.get("created_ns"))
    wall = info.get("wall_s")
    if status == "running":
        if writer_pid(run) is None:
            status = "interrupted"  # marked running, but nobody holds its lock: its process was killed
        elif isinstance(started, int):  # still running: the time so far
            wall = float(wall or 0.0) + max(0.0, now.timestamp() - started / 1e9)
    failed = int(info.get("failed_jobs") or 0)
    if status == "finished" and failed:
        status = "failed"
    tags = info.get("tags") if isinstance(info.get("tags"), dict) else {}
    total = info.get("n_jobs")
    return Entry(
        id=run.id, status="damaged" if damage else status, name=str(info.get("name", cfg.get("name", ""))),
        dataset=str(cfg.get("dataset", "")), methods=tuple(str(m) for m in cfg.get("methods", []) or []),
        used=tuple(methods_used(cfg)), jobs_done=_job_count(run), jobs_total=total if isinstance(total, int) else None,
        failed_jobs=failed, created=_created(run, info), wall_s=float(wall) if isinstance(wall, (int, float)) else None,
        tags={str(k): str(v) for k, v in tags.items()}, damage=damage,
    )


def entries(store: RunStore, now: datetime | None = None) -> list[Entry]:
    """The entry of every run of ``store``, oldest first."""
    now = now or datetime.now(timezone.utc)
    return [entry(r, now) for r in store.runs()]


# -- filters ------------------------------------------------------------------------------

def parse_since(text: str, now: datetime | None = None) -> datetime:
    """``--since``: an ISO date or date-time (local time unless it names a zone) or an age (90s, 30m, 2h, 3d, 1w)."""
    now = now or datetime.now(timezone.utc)
    raw = text.strip()
    age = _AGE.match(raw)
    if age:
        try:
            return now - timedelta(seconds=float(age[1]) * _AGE_SECONDS[age[2]])
        except (OverflowError, ValueError):  # an age before year 1: every run is younger
            return datetime.min.replace(tzinfo=timezone.utc)
    try:
        when = datetime.fromisoformat(raw)
    except ValueError:
        raise SpecError(f"--since {text!r} is neither an ISO date/time (2025-01-31, 2025-01-31T14:30) "
                        "nor an age (30m, 2h, 3d, 1w)") from None
    return when if when.tzinfo is not None else when.astimezone()


@dataclass(frozen=True)
class Filters:
    """What ``runs list`` keeps: every given criterion must hold (tags: all of them; statuses: any of them)."""

    dataset: str | None = None
    method: str | None = None
    statuses: tuple[str, ...] = ()
    tags: tuple[tuple[str, str | None], ...] = ()
    """(key, value) pairs; a value of None matches any value of the key."""
    since: datetime | None = None

    @classmethod
    def parse(cls, *, dataset: str | None = None, method: str | None = None, statuses: Sequence[str] = (),
              tags: Sequence[str] = (), since: str | None = None, now: datetime | None = None) -> "Filters":
        """Filters from command-line texts; SpecError (one line, naming the option) for a bad value."""
        for s in statuses:
            if s not in STATUSES:
                raise SpecError(f"--status {s!r} is not a run status; use one of {', '.join(STATUSES)}")
        pairs = tuple(_split(t, "--tag", False) for t in tags)
        return cls(dataset or None, method or None, tuple(statuses), pairs,
                   parse_since(since, now) if since else None)

    def __call__(self, e: Entry) -> bool:
        if self.dataset and self.dataset not in (e.dataset, Path(e.dataset).name, Path(e.dataset).stem):
            return False
        if self.method and self.method not in e.used:
            return False
        if self.statuses and e.status not in self.statuses:
            return False
        if any(k not in e.tags or (v is not None and e.tags[k] != v) for k, v in self.tags):
            return False
        return self.since is None or (e.created is not None and e.created >= self.since)


def select(found: Iterable[Entry], filters: Filters) -> list[Entry]:
    """The entries every filter keeps, in their order."""
    return [e for e in found if filters(e)]


# -- output -------------------------------------------------------------------------------

def _duration(seconds: float | None) -> str:
    if seconds is None:
        return ""
    s = int(round(seconds))
    for unit, size, sub, subsize in (("d", 86400, "h", 3600), ("h", 3600, "m", 60), ("m", 60, "s", 1)):
        if s >= size:
            return f"{s // size}{unit}{(s % size) // subsize:02d}{sub}"
    return f"{s}s"


def _tags_text(tags: dict[str, str], sep: str = ",") -> str:
    return sep.join(f"{k}={v}" for k, v in tags.items())


# display order; (header, min width when trimmed, or 0: never trimmed, natural width cap)
_COLUMNS = {
    "id": ("id", 0, 0), "status": ("status", 0, 0), "jobs": ("jobs", 0, 0), "created": ("created", 0, 0),
    "wall": ("wall", 0, 0), "name": ("name", 8, 24), "dataset": ("dataset", 8, 24), "methods": ("methods", 8, 30),
    "tags": ("tags", 8, 40),
}
_KEEP_FIRST = ("id", "status", "jobs", "dataset", "tags", "methods", "created", "wall", "name")
"""Columns from most to least useful: the last ones are trimmed, then dropped, first when space runs out."""


def _cells(e: Entry) -> dict[str, str]:
    return {
        "id": e.id, "status": e.status, "name": e.name, "dataset": Path(e.dataset).name if e.dataset else "",
        "methods": ",".join(e.methods), "jobs": f"{e.jobs_done}/{'?' if e.jobs_total is None else e.jobs_total}",
        "created": e.created.strftime("%Y-%m-%d %H:%M") if e.created else "", "wall": _duration(e.wall_s),
        "tags": _tags_text(e.tags),
    }


def _trim(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(width - 1, 0)] + "…"


def _fit(natural: dict[str, int], width: int) -> dict[str, int]:
    """Column -> width: the most useful columns that fit in ``width``, trimming the least useful first."""
    keep = [c for c in _KEEP_FIRST if c in natural]
    while True:
        widths = {c: natural[c] for c in keep}
        excess = sum(widths.values()) + 2 * (len(keep) - 1) - width
        for c in reversed(keep):
            lowest = _COLUMNS[c][1]
            if excess <= 0:
                break
            if lowest and widths[c] > lowest:
                cut = min(excess, widths[c] - lowest)
                widths[c] -= cut
                excess -= cut
        if excess <= 0 or len(keep) == 1:
            return widths
        keep.pop()


def catalog_text(found: Sequence[Entry], width: int = 80) -> str:
    """A header line and one row per entry, fitted to ``width`` columns (the id is never cut or dropped).

    A damaged run's row is its id, ``damaged`` and the reason, whole.
    """
    rows = [_cells(e) for e in found]
    whole = [r for r, e in zip(rows, found) if e.damage is None]
    natural = {}
    for c, (header, _, cap) in _COLUMNS.items():
        longest = max([len(r[c]) for r in (rows if c in ("id", "status") else whole)], default=0)
        if longest or c in ("id", "status", "jobs"):
            natural[c] = max(len(header), min(longest, cap) if cap else longest)
    widths = _fit(natural, width)
    shown = [c for c in _COLUMNS if c in widths]

    def line(cells: dict[str, str]) -> str:
        return "  ".join(_trim(cells[c], widths[c]).ljust(widths[c]) for c in shown).rstrip()

    out = [line({c: h for c, (h, _, _) in _COLUMNS.items()})]
    for r, e in zip(rows, found):
        if e.damage is not None:
            out.append(f"{e.id.ljust(widths['id'])}  {'damaged'.ljust(widths.get('status', 0))}  {e.damage}")
        else:
            out.append(line(r))
    return "\n".join(out) + "\n"


def catalog_records(found: Sequence[Entry]) -> list[dict[str, Any]]:
    """One plain record per entry (JSON-ready): every field, the creation time as local ISO 8601."""
    return [{
        "id": e.id, "name": e.name, "dataset": e.dataset, "methods": list(e.methods), "status": e.status,
        "jobs_done": e.jobs_done, "jobs_total": e.jobs_total, "failed_jobs": e.failed_jobs,
        "created": e.created.isoformat(timespec="seconds") if e.created else None, "wall_s": e.wall_s,
        "tags": dict(e.tags), "damage": e.damage,
    } for e in found]


def catalog_csv(found: Sequence[Entry]) -> str:
    """CSV of ``catalog_records``: methods joined by ',', tags as KEY=VALUE joined by ';'."""
    import csv
    import io

    buf = io.StringIO()
    records = catalog_records(found)
    names = list(catalog_records([Entry("", "")])[0])
    writer = csv.DictWriter(buf, fieldnames=names, lineterminator="\n")
    writer.writeheader()
    for rec in records:
        writer.writerow({**rec, "methods": ",".join(rec["methods"]), "tags": _tags_text(rec["tags"], ";"),
                         "damage": rec["damage"] or ""})
    return buf.getvalue()

