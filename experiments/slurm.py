"""The SLURM executor (``--executor slurm``): each job one task of a SLURM job array, through submitit.

The run's process (the driver: a login node, or a small batch job of its own) pickles the
prepared context once into the run folder, which lives on the cluster's shared file system
(``--store``), and submits one job array per method, with that method's resources (partition,
time, cpus, memory from the experiment's ``[slurm]`` table, its ``[slurm.methods.NAME]`` tables
and ``--slurm KEY=VALUE``) and a concurrency cap (``max_parallel``: SLURM's ``%N``). Each task
loads the context once, runs its job and writes the result atomically to
``<run>/slurm/results/<job key>.pkl``; the driver stores each result as it lands (it alone writes
the run's job files, as with every executor) and removes the pickle.

Preemption and time-outs: a task is a checkpointable callable, so SLURM requeues a preempted or
timed-out task (submitit's ``max_num_timeout``, 3), which runs its job again from the start (a job
is atomic). A driver that dies leaves the tasks running; their results land in the run folder, and
``enginebench run --resume RUN --executor slurm`` stores those first and submits only the jobs with
neither a job file nor a result (the runner's resume).

``cluster = "local"`` runs the tasks as processes of this machine through submitit's local
executor (tests, a try before the cluster), ``"debug"`` in this process.
"""

from __future__ import annotations

import math
import pickle
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Iterator, Mapping

from enginebench.experiments.executor_base import ExecutorError, limit_threads, load_shipped_plugins
from enginebench.experiments.slurm_settings import SLURM, resources
from enginebench.results.atomic import atomic_write_bytes

if TYPE_CHECKING:
    from enginebench.experiments.jobs import Context, Job

SLURM_MISSING = 'the slurm executor needs submitit: pip install "enginebench[slurm]"'
POLL_S = 2.0
"""How often the driver asks which tasks finished (submitit caches sacct between asks)."""


def submitit_parameters(res: Mapping[str, Any], max_parallel: int, setup: list[str], name: str) -> dict[str, Any]:
    """submitit's AutoExecutor parameters for one method's array (generic ones, and slurm_ ones the local
    executor ignores)."""
    params: dict[str, Any] = {"name": name, "cpus_per_task": int(res["cpus"]), "slurm_array_parallelism": max_parallel}
    limit = res.get("time")
    if isinstance(limit, int):
        params["timeout_min"] = limit
    elif limit:
        params["slurm_time"] = limit
        params["timeout_min"] = _minutes(limit)
    memory = res.get("memory")
    if isinstance(memory, str):
        params["slurm_mem"] = memory
    elif memory:
        params["mem_gb"] = max(1, math.ceil(memory))
    if res.get("gpus"):
        params["gpus_per_node"] = int(res["gpus"])
    for key in ("partition", "account", "qos", "constraint"):
        if res.get(key):
            params[f"slurm_{key}"] = res[key]
    if setup:
        params["slurm_setup"] = list(setup)
    return params


def _minutes(limit: str) -> int:
    """SLURM time text in whole minutes (rounded up)."""
    days, _, rest = limit.rpartition("-")
    parts = [int(p) for p in rest.split(":")]
    if days:  # D-HH[:MM[:SS]]
        h, m, s = (parts + [0, 0])[:3]
    elif len(parts) == 3:
        h, m, s = parts
    elif len(parts) == 2:
        h, m, s = 0, parts[0], parts[1]
    else:
        h, m, s = 0, parts[0], 0
    return max(1, math.ceil((int(days or 0) * 86400 + h * 3600 + m * 60 + s) / 60))


# -- the tasks ---------------------------------------------------------------------------------

_TASK_CTX: dict[str, Any] = {}


@dataclass(frozen=True)
class _Task:
    """One array task: run one job from the context file and write its result next to it.

    Checkpointable (submitit calls ``checkpoint`` on preemption or time-out): the task is
    requeued and runs its job again from the start; a result already written is kept.
    """

    context_file: str
    results_dir: str
    threads: int
    plugin_sources: tuple[tuple[str, str], ...]

    def __call__(self, job: "Job") -> str:
        out = Path(self.results_dir) / f"{job.key}.pkl"
        if out.is_file():
            return str(out)
        ctx = _TASK_CTX.get(self.context_file)
        if ctx is None:
            if self.threads:  # 0: a task in the driver's own process (cluster "debug") leaves its limits alone
                limit_threads(self.threads)
            load_shipped_plugins(self.plugin_sources)
            with open(self.context_file, "rb") as fh:
                ctx = pickle.load(fh)
            _TASK_CTX.clear()
            _TASK_CTX[self.context_file] = ctx
        from enginebench.experiments.jobs import run_job

        result = run_job(ctx, job)
        atomic_write_bytes(out, pickle.dumps((job, result), protocol=pickle.HIGHEST_PROTOCOL))
        return str(out)

    def checkpoint(self, *args: Any, **kwargs: Any) -> Any:
        import submitit

        return submitit.helpers.DelayedSubmission(self, *args, **kwargs)


def _read_result(path: Path) -> tuple["Job", Any] | None:
    """A task's (job, result), or None when the file is unreadable (a task killed mid-write leaves none:
    writes are atomic, so this is a file damaged otherwise; its job is run again)."""
    try:
        with open(path, "rb") as fh:
            return pickle.load(fh)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ValueError):
        return None


# -- the driver --------------------------------------------------------------------------------

def check_submitit() -> None:
    import importlib.util

    if importlib.util.find_spec("submitit") is None:
        raise ExecutorError(SLURM_MISSING)


def run_slurm(
    ctx: "Context",
    jobs: Iterable["Job"],
    run_dir: str | Path,
    plugins: tuple[str, ...] = (),
    options: Mapping[str, Any] | None = None,
) -> Iterator[tuple["Job", Any]]:
    """Yield (job, result) as the array tasks finish; results a previous driver's tasks left in
    ``<run_dir>/slurm/results`` come first, without submitting their jobs again.

    ``options`` (``--slurm KEY=VALUE``) override the top-level keys of the spec's ``[slurm]`` table.
    """
    jobs = list(jobs)
    if not jobs:
        return
    settings = {**SLURM.defaults(), **(ctx.spec.slurm or {}), **dict(options or {})}
    root = Path(run_dir) / "slurm"
    results_dir = root / "results"
    results_dir.mkdir(parents=True, exist_ok=True)
    wanted = {job.key: job for job in jobs}
    for stale in results_dir.glob(".*.tmp"):
        stale.unlink(missing_ok=True)
    for path in sorted(results_dir.glob("*.pkl")):
        found = _read_result(path) if path.stem in wanted else None
        if found is None:
            continue
        yield found
        path.unlink(missing_ok=True)
        del wanted[path.stem]
    if not wanted:
        return
    check_submitit()
    import submitit

    token = uuid.uuid4().hex[:8]
    context_file = root / f"context-{token}.pkl"
    atomic_write_bytes(context_file, pickle.dumps(ctx, protocol=pickle.HIGHEST_PROTOCOL))
    sources = tuple((str(Path(p).resolve()), Path(p).read_text(encoding="utf-8")) for p in plugins)
    try:
        executor = submitit.AutoExecutor(folder=root / "logs", cluster=settings["cluster"])
    except RuntimeError as exc:  # submitit finds no srun: this machine is not in a SLURM cluster
        raise ExecutorError(f"the slurm executor found no SLURM here ({_first_line(exc)}); run on a cluster's login "
                            "node, or set [slurm] cluster = \"local\" to run the tasks on this machine") from None
    submitted: dict[str, tuple[Any, Job]] = {}
    try:
        by_method: dict[str, list[Job]] = {}
        for job in wanted.values():
            by_method.setdefault(job.method, []).append(job)
        for method, group in by_method.items():
            res = resources(settings, method)
            executor.update_parameters(**submitit_parameters(res, int(settings["max_parallel"]),
                                                             list(settings["setup"]), f"enginebench-{method}"))
            threads = 0 if settings["cluster"] == "debug" else int(res["cpus"])
            task = _Task(str(context_file), str(results_dir), threads, sources)
            try:
                with executor.batch():
                    handles = [executor.submit(task, job) for job in group]
            except Exception as exc:  # sbatch refused: a partition that does not exist, a limit exceeded
                raise ExecutorError(f"SLURM refused the array of {method} ({type(exc).__name__}: "
                                    f"{_first_line(exc)}); check the [slurm] resources") from None
            submitted.update((job.key, (h, job)) for h, job in zip(handles, group))
        pending = dict(submitted)
        while pending:
            finished = [key for key, (handle, _) in pending.items() if handle.done()]
            if not finished:
                time.sleep(POLL_S if settings["cluster"] == "slurm" else 0.1)
                continue
            for key in finished:
                handle, job = pending.pop(key)
                path = results_dir / f"{key}.pkl"
                found = _read_result(path) if path.is_file() else None
                if found is None:
                    raise ExecutorError(
                        f"job {key} ended on the cluster without a result (task {handle.job_id}: "
                        f"{_task_failure(handle)}); finished jobs are stored: 'enginebench run --resume RUN "
                        f"--executor slurm' runs the rest (its log: {handle.paths.stderr})")
                yield found
                path.unlink(missing_ok=True)
    finally:
        context_file.unlink(missing_ok=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else "no detail"


def _task_failure(handle: Any) -> str:
    """Why a task gave no result, in one line (its exception, or its state)."""
    try:
        exc = handle.exception()
    except Exception as err:  # the state cannot be read: say so rather than fail again
        return f"{type(err).__name__}: {_first_line(err)}"
    if exc is None:
        return f"state {handle.state}"
    return f"{type(exc).__name__}: {_first_line(exc)}"
