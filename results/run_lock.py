"""The write lock of a run folder: one writing process per run.

Fault handled here: two processes writing one run (two ``run --resume`` at once): the
writer holds an OS lock (``fcntl.flock`` on ``run.lock`` in the run folder, holding the
writer's pid, and present only while held) from the moment the run is marked running
until it is marked finished or interrupted, or its process dies; another writer gets a
StoreError naming the run and the holder's pid. ``Run.lock``/``Run.unlock`` call these.
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path
from typing import Iterator

from enginebench.errors import StoreError
from enginebench.results.atomic import write_failed

try:
    import fcntl
except ImportError:  # not POSIX: runs are written unlocked
    fcntl = None  # type: ignore[assignment]

LOCK_FILE = "run.lock"
"""The lock file of a run folder."""


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


def holds(folder: Path) -> bool:
    """Whether this process holds the write lock of the run folder ``folder``."""
    return _lock_key(folder) in _HELD


def acquire(folder: Path, run_id: str) -> None:
    """Take the write lock of the run folder ``folder`` (run ``run_id``) for this process, or fail with the
    holder's pid (no-op when held already).

    An OS lock (``fcntl.flock``) on ``run.lock``, which exists only while a writer
    holds it: the holder removes it before releasing, and a process that locked a
    file already removed tries again. The kernel releases the lock when the process
    dies (a killed run can be resumed at once; its stale file is reused). Where the
    file system has no locks (or the platform no ``fcntl``) the run is written unlocked.
    """
    key = _lock_key(folder)
    if key in _HELD or fcntl is None:
        return
    path = folder / LOCK_FILE
    for _ in range(100):
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise write_failed(path, exc, folder.parent, "the run's lock file", "run again") from exc
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _lock_holder(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise StoreError(
                    f"run {run_id} is being written by another process (pid {holder}, lock {path}); "
                    f"wait for it to end (or stop it), then `enginebench run --resume {run_id}` if it is unfinished"
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
    raise StoreError(f"run {run_id}: cannot take the lock {path} (it keeps being replaced); run again")


def release(folder: Path) -> None:
    """Release the write lock of ``folder`` if this process holds it (its lock file is removed first)."""
    fd = _HELD.pop(_lock_key(folder), None)
    if fd is not None:
        try:
            (folder / LOCK_FILE).unlink(missing_ok=True)
        except OSError:
            pass  # a folder that is gone (runs rm) or read-only: the lock is released anyway
        try:
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)


@contextlib.contextmanager
def holding(folder: Path, run_id: str) -> Iterator[None]:
    """Hold the lock of ``folder`` for one write (kept if this process held it before)."""
    held = holds(folder)
    acquire(folder, run_id)
    try:
        yield
    finally:
        if not held:
            release(folder)
