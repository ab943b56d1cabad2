"""Writing the files a command produces (tables, baselines, reports, figures): checked first, written whole.

Every command that writes a file goes through here, so a bad output path is one line
saying which path and what to do (``DataError``: ``error:``, exit 2 at the command line)
and never a traceback:

* ``check_output_file`` before any work: the folder must exist (it is not created, a
  typo in a folder name should not silently make a new tree) and the path must not be a
  folder;
* ``write_output`` writes a temporary file beside the target and renames it, so an
  interrupted or failed write (disk full, permissions) leaves the old file or none; a path
  that is not a regular file (``/dev/null``, ``/dev/stdout``, a named pipe, a symbolic link) is
  written directly instead, never replaced by a file (a pipe without a reader, or a socket,
  is refused with one line rather than waited on);
* ``output_folder`` creates a folder for many outputs (a report, figures), parents
  included, or says why it cannot.
"""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from pathlib import Path

from enginebench.errors import DataError

DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def os_reason(exc: OSError) -> str:
    """An OSError as a short phrase ('permission denied', 'disk full', ...)."""
    if exc.errno in DISK_FULL:
        return "disk full"
    return " ".join(str(exc.strerror or exc).split()).lower() or type(exc).__name__


def check_output_file(path: str | os.PathLike, option: str = "--output") -> Path:
    """``path`` as a Path once it can be written: its folder exists and it is not a folder itself."""
    path = Path(path)
    if str(path) == "" or path.name in ("", ".", ".."):
        raise DataError(f"{option} {str(path)!r}: give a file name to write")
    if path.is_dir():
        raise DataError(f"cannot write {path}: it is a folder; give a file name ({option})")
    folder = path.parent
    if not folder.is_dir():
        what = "is not a folder" if folder.exists() else "does not exist"
        raise DataError(f"cannot write {path}: folder {folder} {what}; create it or choose another path ({option})")
    if not os.access(folder, os.W_OK | os.X_OK) and not _special(path):
        raise DataError(f"cannot write {path}: folder {folder} is not writable; choose another path ({option})")
    return path


def _special(path: Path) -> bool:
    """True for an existing path that is not a plain regular file (a device, a pipe, a socket, a symbolic link)."""
    try:
        return not stat.S_ISREG(os.lstat(path).st_mode)
    except FileNotFoundError:
        return False


def _write_direct(path: Path, raw: bytes, option: str) -> Path:
    """Write into a special file as it is: a device or a link's target is opened and written, a pipe only when
    a reader is there (non-blocking open), a socket refused."""
    mode = os.stat(path).st_mode if path.exists() else 0
    if stat.S_ISSOCK(mode):
        raise DataError(f"cannot write {path}: it is a socket; give a file name ({option})")
    flags = os.O_WRONLY | (os.O_NONBLOCK if stat.S_ISFIFO(mode) else 0) | (os.O_TRUNC if stat.S_ISREG(mode) else 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ENXIO:
            raise DataError(f"cannot write {path}: a named pipe with no reader; start the reader first or give a "
                            f"file name ({option})") from None
        raise DataError(f"cannot write {path} ({os_reason(exc)}); choose another path ({option})") from None
    try:
        if stat.S_ISFIFO(mode):
            os.set_blocking(fd, True)
        view = memoryview(raw)
        while view:
            view = view[os.write(fd, view):]
    except OSError as exc:
        raise DataError(f"cannot write {path} ({os_reason(exc)}); choose another path ({option})") from None
    finally:
        os.close(fd)
    return path


def write_output(path: str | os.PathLike, data: str | bytes, option: str = "--output") -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` whole (temporary file, then rename; a special file is written
    directly); DataError on failure."""
    path = check_output_file(path, option)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    if _special(path):
        return _write_direct(path, raw, option)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
        if path.exists():
            os.chmod(tmp, path.stat().st_mode & 0o777)
        else:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except OSError as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise DataError(f"cannot write {path} ({os_reason(exc)}); nothing was written; fix that and run again "
                        f"or choose another path ({option})") from None
    return path


def output_folder(path: str | os.PathLike, option: str = "--output") -> Path:
    """Create the folder ``path`` (and its parents) for a command's files, or say why it cannot be."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise DataError(f"cannot write into {path}: it is a file, not a folder; choose a folder ({option})")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DataError(f"cannot create the folder {path} ({os_reason(exc)}); choose another path ({option})") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise DataError(f"cannot write into {path}: the folder is not writable; choose another path ({option})")
    return path
