"""Executors: where jobs run. In-process for one worker, a local process pool otherwise,
a Dask distributed cluster (``--executor dask``), or SLURM job arrays through submitit
(``--executor slurm``, experiments/slurm.py). ``EXECUTORS`` is the one list of their names
(the CLI's choices); ``run_jobs`` picks one.

The prepared context is pickled once and unpickled once per worker (after the worker has
loaded any plugin files, so plugin classes resolve). Results come back to the parent,
which alone writes to the run store.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import socket
import threading
import time
import uuid
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Iterator, Mapping

from enginebench.experiments.executor_base import ExecutorError, limit_threads, load_shipped_plugins

if TYPE_CHECKING:  # imported where used: the CLI reads EXECUTORS without loading the job machinery
    from enginebench.experiments.jobs import Context, Job

_CTX: Context | None = None


PARENT_POLL_S = 1.0
"""How often a pool worker checks that the run's process is still alive."""


def _exit_with_parent(parent: int) -> None:
    """A daemon thread of each pool worker: exit as soon as the run's process is gone (a kill -9 of the run
    leaves no worker computing for nobody and holding memory)."""

    def watch() -> None:
        while True:
            time.sleep(PARENT_POLL_S)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="enginebench-parent-watch", daemon=True).start()


def _init_worker(blob: bytes, plugins: tuple[str, ...], threads: int, parent: int | None = None) -> None:
    global _CTX
    if parent is not None:
        _exit_with_parent(parent)
    limit_threads(threads)
    if plugins:
        from enginebench.registry import load_plugin_file

        for path in plugins:
            load_plugin_file(path)
    _CTX = pickle.loads(blob)


def _work(job: Job) -> tuple[Job, Any]:
    from enginebench.experiments.jobs import run_job

    assert _CTX is not None
    return job, run_job(_CTX, job)


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


class WorkerDied(ExecutorError):
    """A local pool's worker process died (killed for memory, or failing at start): one line saying what to do."""


WORKER_DIED = (
    "a worker process died ({exc}); the jobs finished before are stored and `enginebench run --resume RUN` "
    "computes the rest; the machine may have run out of memory (fewer workers, `-j`, need less)"
)
"""Why a local pool broke, and what to do: one line (enginebench.api.run adds a script's own cause)."""


def run_local(
    ctx: Context, jobs: Iterable[Job], workers: int, plugins: tuple[str, ...] = (),
) -> Iterator[tuple[Job, Any]]:
    """Yield (job, result) as jobs finish.

    Left early (an interrupt, SIGTERM, a failing consumer) the pool stops at once: queued
    jobs are cancelled and the workers still computing are terminated (they write nothing:
    the caller stores results), instead of the pool's default exit, which waits until every
    queued job has run for nobody.
    """
    from enginebench.experiments.jobs import run_job

    jobs = list(jobs)
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield job, run_job(ctx, job)
        return
    blob = pickle.dumps(ctx, protocol=pickle.HIGHEST_PROTOCOL)
    threads = max(1, default_workers() // workers)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"),
                               initializer=_init_worker, initargs=(blob, plugins, threads, os.getpid()))
    pending = {pool.submit(_work, job) for job in jobs}
    try:
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                try:
                    result = fut.result()
                except BrokenProcessPool as exc:
                    raise WorkerDied(WORKER_DIED.format(exc=exc)) from exc
                yield result
    finally:
        if pending:
            _stop(pool)
        pool.shutdown(wait=True)


def _stop(pool: ProcessPoolExecutor) -> None:
    """Terminate a pool's workers and drop its queued jobs (running jobs are lost, never half-written).

    No public API stops a running task, and ``shutdown(cancel_futures=True)`` alone let the
    workers run on through the queue (14 of 16 queued jobs ran, measured); a terminated
    worker breaks the pool, whose manager then fails every pending future and exits. The
    process handles are taken before ``shutdown``, which forgets them.
    """
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for proc in processes:
        proc.terminate()
    pool.shutdown(wait=False, cancel_futures=True)


# --- Dask distributed -------------------------------------------------------------------

CONNECT_TIMEOUT_S = 10.0
"""How long to wait for a given Dask scheduler before giving up with one error line."""

WORKER_WAIT_S = 120.0
"""How long to wait for the first worker (a batch queue may take a while to start one)."""

DASK_MISSING = 'the dask executor needs dask.distributed: pip install "enginebench[dask]"'


_DASK_CTX: dict[str, Context] = {}
_DASK_LOCK = threading.Lock()


@dataclass(frozen=True)
class _Payload:
    """What every Dask worker receives once: the pickled context and how to open it."""

    token: str
    """Unique per run: a worker unpickles the context once per token."""
    origin: tuple[str, int]
    """(host, pid) of the parent: a worker in the parent process needs no setup."""
    threads: int
    """BLAS/torch threads per worker process (0: leave as is)."""
    plugin_sources: tuple[tuple[str, str], ...]
    """(path, text) of each plugin file."""
    blob: bytes


def _dask_context(payload: _Payload) -> Context:
    """The run's context on this worker, unpickled once per worker process (then cached).

    Plugin files are loaded first so that plugin classes resolve while unpickling. A
    worker living in the parent process (a threaded LocalCluster) already has both, so it
    changes neither the parent's thread limits nor its plugin registry.
    """
    with _DASK_LOCK:
        ctx = _DASK_CTX.get(payload.token)
        if ctx is not None:
            return ctx
        if payload.origin != (socket.gethostname(), os.getpid()):
            if payload.threads:
                limit_threads(payload.threads)
            load_shipped_plugins(payload.plugin_sources)
        ctx = pickle.loads(payload.blob)
        _DASK_CTX.clear()  # one run at a time per worker: drop a previous run's context
        _DASK_CTX[payload.token] = ctx
        return ctx


def _dask_work(payload: _Payload, job: Job) -> tuple[Job, Any]:
    from enginebench.experiments.jobs import run_job

    return job, run_job(_dask_context(payload), job)


EXECUTORS = ("local", "dask", "slurm")
"""Every executor's name, here only: ``--executor``'s choices come from this list."""


def check_executor(executor: str, scheduler: str | None, timeout: float | None = None) -> None:
    """Fail early, before any data is loaded or a run is created, on an executor that cannot work.

    Checks the name, that dask.distributed is installed, and that a given scheduler answers.
    """
    if executor not in EXECUTORS:
        raise ExecutorError(f"unknown executor {executor!r}; use one of {', '.join(EXECUTORS)}")
    if executor != "dask":
        if scheduler:
            raise ExecutorError(f"--scheduler {scheduler} needs --executor dask (the {executor} executor has no "
                                "scheduler)")
        if executor == "slurm":
            from enginebench.experiments.slurm import check_submitit

            check_submitit()
        return
    if scheduler is not None:
        client, _ = _connect(scheduler, 1, CONNECT_TIMEOUT_S if timeout is None else timeout)
        client.close()
    else:
        try:
            import distributed  # noqa: F401
        except ImportError:
            raise ExecutorError(DASK_MISSING) from None


def _connect(scheduler: str | None, workers: int, timeout: float):
    """A Dask client (and the LocalCluster it owns, or None) for ``scheduler``."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ExecutorError(DASK_MISSING) from None
    if scheduler is None:
        # one single-threaded worker process per --jobs, like the local pool; no memory
        # limit (the local pool has none either); the dashboard on a free port, never a fixed one
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", memory_limit=0)
        return Client(cluster), cluster
    try:
        return Client(scheduler, timeout=timeout), None
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise ExecutorError(
            f"cannot reach the Dask scheduler at {scheduler!r} within {timeout:g} s ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else 'no detail'}); check the address (e.g. tcp://HOST:8786) "
            f"and that the cluster is up, or leave out --scheduler to start a local cluster"
        ) from None


def run_dask(
    ctx: Context,
    jobs: Iterable[Job],
    workers: int,
    plugins: tuple[str, ...] = (),
    scheduler: str | None = None,
    connect_timeout: float | None = None,
) -> Iterator[tuple[Job, Any]]:
    """Yield (job, result) as jobs finish on a Dask cluster.

    With ``scheduler`` (an address such as ``tcp://host:8786``, e.g. of a dask-jobqueue
    SLURMCluster) the jobs run on that cluster's workers and ``workers`` is not used;
    without it a LocalCluster of ``workers`` single-threaded processes is started and
    closed again. The context is pickled once in the parent and broadcast to every
    worker; results come back to the parent, which alone writes to the run store.
    Leaving the generator early (an interrupt) cancels the jobs still queued.
    """
    jobs = list(jobs)
    if not jobs:
        return
    plugin_sources = tuple((str(Path(p).resolve()), Path(p).read_text(encoding="utf-8")) for p in plugins)
    threads = max(1, default_workers() // workers) if scheduler is None else 1
    blob = pickle.dumps(ctx, protocol=pickle.HIGHEST_PROTOCOL)
    payload = _Payload(uuid.uuid4().hex, (socket.gethostname(), os.getpid()), threads, plugin_sources, blob)
    client, cluster = _connect(scheduler, workers, CONNECT_TIMEOUT_S if connect_timeout is None else connect_timeout)
    futures: list = []
    try:
        from distributed import CancelledError, KilledWorker, as_completed

        cluster_trouble = (KilledWorker, CancelledError, OSError, TimeoutError)  # OSError: comm closed
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT_S)  # a batch queue may be slow to start one
        except TimeoutError:
            raise ExecutorError(
                f"no Dask worker joined the scheduler at {scheduler or 'the local cluster'} within {WORKER_WAIT_S:g} s; "
                f"start workers first (for dask-jobqueue: cluster.scale(jobs=N)) and run again"
            ) from None
        shipped = client.scatter(payload, broadcast=True, hash=False)
        futures = [client.submit(_dask_work, shipped, job, pure=False, key=f"enginebench-{payload.token[:8]}-{job.key}")
                   for job in jobs]
        job_of = {fut.key: job for fut, job in zip(futures, jobs)}
        for fut in as_completed(futures):
            try:
                yield fut.result()
            except cluster_trouble as exc:  # a worker died or the cluster went away: not a method's failure
                job = job_of[fut.key]
                raise ExecutorError(
                    f"job {job.key} could not run on the Dask cluster ({type(exc).__name__}: {exc}); "
                    f"finished jobs are stored: 'enginebench run --resume RUN' runs the rest"
                ) from exc
    finally:
        if futures:
            client.cancel(futures)
        client.close()
        if cluster is not None:
            cluster.close()


def shares_memory(executor: str, workers: int, scheduler: str | None) -> bool:
    """Whether the jobs run in processes of this machine (so large raw arrays are worth memory-mapping once)."""
    return workers > 1 if executor == "local" else executor == "dask" and scheduler is None


def run_jobs(
    executor: str,
    ctx: Context,
    jobs: Iterable[Job],
    *,
    workers: int,
    plugins: tuple[str, ...] = (),
    scheduler: str | None = None,
    run_dir: str | Path | None = None,
    options: Mapping[str, Any] | None = None,
) -> Iterator[tuple[Job, Any]]:
    """The (job, result) pairs of ``jobs`` as they finish on ``executor`` (one of ``EXECUTORS``).

    ``run_dir`` is the run folder (the slurm executor shares the context and the results through it);
    ``options`` are the executor's settings from the command line (slurm: ``--slurm KEY=VALUE``).
    """
    if executor == "dask":
        return run_dask(ctx, jobs, workers, plugins, scheduler)
    if executor == "slurm":
        from enginebench.experiments.slurm import run_slurm

        if run_dir is None:
            raise ExecutorError("the slurm executor needs the run folder (on a shared file system)")
        return run_slurm(ctx, jobs, run_dir, plugins, options)
    if executor != "local":
        raise ExecutorError(f"unknown executor {executor!r}; use one of {', '.join(EXECUTORS)}")
    return run_local(ctx, jobs, workers, plugins)
