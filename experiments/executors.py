"""Executors: where jobs run. In-process for one worker, a local process pool otherwise.

The prepared context is pickled once and unpickled once per worker (after the worker has
loaded any plugin files, so plugin classes resolve). Results come back to the parent,
which alone writes to the run store.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, Iterable, Iterator

from enginebench.experiments.jobs import Context, Job, run_job

_CTX: Context | None = None


def _init_worker(blob: bytes, plugins: tuple[str, ...], threads: int) -> None:
    global _CTX
    from threadpoolctl import threadpool_limits

    threadpool_limits(threads)
    try:
        import torch

        torch.set_num_threads(threads)
    except ImportError:  # pragma: no cover - torch is a core dependency
        pass
    if plugins:
        from enginebench.methods.registry import load_plugin_file

        for path in plugins:
            load_plugin_file(path)
    _CTX = pickle.loads(blob)


def _work(job: Job) -> tuple[Job, Any]:
    assert _CTX is not None
    return job, run_job(_CTX, job)


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def run_local(
    ctx: Context, jobs: Iterable[Job], workers: int, plugins: tuple[str, ...] = (),
) -> Iterator[tuple[Job, Any]]:
    """Yield (job, result) as jobs finish."""
    jobs = list(jobs)
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield job, run_job(ctx, job)
        return
    blob = pickle.dumps(ctx, protocol=pickle.HIGHEST_PROTOCOL)
    threads = max(1, default_workers() // workers)
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                             initializer=_init_worker, initargs=(blob, plugins, threads)) as pool:
        pending = {pool.submit(_work, job) for job in jobs}
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                yield fut.result()
