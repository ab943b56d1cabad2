"""What a run records about the machine and software it ran on."""

from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

PACKAGES = ("enginebench", "numpy", "scipy", "pandas", "pyarrow", "scikit-learn", "pysindy", "torch", "click", "rich")


def _version(name: str) -> str | None:
    try:
        return version(name)
    except PackageNotFoundError:
        return None


def git_commit(path: Path | None = None) -> str | None:
    """The commit of the source tree the package runs from, when it is a git checkout."""
    where = path or Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5)
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def gpu() -> str | None:
    if "torch" not in sys.modules:  # do not import torch just to say there is no GPU
        try:
            import torch  # noqa: F401
        except ImportError:
            return None
    import torch

    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None


def capture(seed: int, workers: int) -> dict[str, Any]:
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "gpu": gpu(),
        "workers": workers,
        **software(),
        "seed": seed,
    }


def software() -> dict[str, Any]:
    """The code that runs: package versions and the git commit (recorded at creation and at each resume)."""
    return {"packages": {p: _version(p) for p in PACKAGES}, "git_commit": git_commit()}


def resume_record(workers: int) -> dict[str, Any]:
    """What finished part of a run after its creation: when, with which code and packages, on how many workers.

    Kept in run.json's ``resumes``, so a run whose parts ran with different code says so
    (``runs show``) instead of passing for the work of its creation's environment."""
    return {
        "at": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        **software(),
        "workers": workers,
    }
