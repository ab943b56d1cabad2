"""What every executor shares: its error, and how a worker process sets itself up before its first job
(thread limits, plugin files). experiments/executors.py (local pool, Dask) and experiments/slurm.py both
stand on this module, so neither imports the other back."""

from __future__ import annotations

import sys
from pathlib import Path

from enginebench.errors import EngineBenchError


class ExecutorError(EngineBenchError):
    """An executor that cannot be used as asked (a missing package, an unreachable scheduler)."""


def limit_threads(threads: int) -> None:
    """At most ``threads`` BLAS/OpenMP/torch threads in this worker process.

    threadpoolctl limits only the libraries already loaded, and numpy and scipy each bring
    their own OpenBLAS: both are imported here rather than relied on being imported by
    then. (Left at the core count, scipy's LAPACK in two workers on two cores
    oversubscribes them; OpenBLAS's thread hand-offs then made one tridiagonalisation
    10-50x slower in a measurement.)
    """
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    import sklearn.metrics.pairwise  # noqa: F401  (its OpenMP runtime)
    from threadpoolctl import threadpool_limits

    threadpool_limits(threads)
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:  # pragma: no cover - torch is a core dependency
        pass


def load_shipped_plugins(sources: tuple[tuple[str, str], ...]) -> None:
    """Load plugin files on a worker: the original path when it holds the same text, else a shipped copy.

    Cluster nodes need not share the parent's file system, so the parent ships each file's
    text; the copy keeps the file name, hence the module name that pickled classes refer to.
    """
    import tempfile

    from enginebench.registry import load_plugin_file

    for path, text in sources:
        original = Path(path)
        if f"enginebench_plugin_{original.stem}" in sys.modules:
            continue
        try:
            same = original.is_file() and original.read_text(encoding="utf-8") == text
        except OSError:
            same = False
        if not same:
            folder = Path(tempfile.mkdtemp(prefix="enginebench-plugins-"))
            original = folder / original.name
            original.write_text(text, encoding="utf-8")
        load_plugin_file(original)
