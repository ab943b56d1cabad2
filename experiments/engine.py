"""The steps every plan over the protocol goes through: load and check the data, plan the jobs, execute them.

An experiment (``runner.py``) and a learning curve (``learning_curve.py``, one more job
coordinate: the training amount) both prepare a ``Context`` and end in ``execute``: the
jobs run on an executor and the parent process writes each finished job to the run store
as soon as it arrives. This module imports neither of them.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from enginebench.datasets import catalog
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.io import read_dataset, read_metadata
from enginebench.datasets.pools import RawSegments, check_targets
from enginebench.datasets.schema import Schema
from enginebench.errors import SpecError, StoreError
from enginebench.experiments import environment
from enginebench.experiments.executors import default_workers, run_jobs, shares_memory
from enginebench.experiments.jobs import JOINT, Context, Job, Problem, joint_methods
from enginebench.experiments.search import check_search
from enginebench.experiments.selection import record_blocks
from enginebench.experiments.spec import ExperimentSpec
from enginebench.results.run_folder import ResumeState, Run


ProgressFn = Callable[[int, int, Job], None]


def physical_model_for(ds) -> object | None:
    """The dataset's declared physical model, if the toolkit knows it."""
    name = ds.meta.get("physical_model")
    if not name:
        return None
    from enginebench.physical import get_physical_model

    return get_physical_model(name, ds.meta)


def needed_columns(schema: Schema, spec: ExperimentSpec) -> list[str]:
    """The columns an experiment reads: run-time inputs, its targets, group keys, and internals in simulation mode.

    Internal channels are read only in simulation mode, where cascades train on them;
    other outputs are never read. At full size this halves what is loaded.
    """
    keep = set(schema.inputs) | set(spec.targets) | set(schema.groups)
    if spec.mode == "simulation":
        keep |= set(schema.internals)
    column = spec.split.get("column")
    if isinstance(column, str):
        keep.add(column)
    return [c for c in schema.names() if c in keep]


def load_dataset(spec: ExperimentSpec) -> tuple[Dataset, str, ExperimentSpec]:
    """The experiment's dataset with its roles applied (only the needed columns), the stored data's hash, and
    the spec with ``targets = "all"`` resolved to the dataset's output columns.

    A Parquet-backed dataset is read with column projection and hashed by the content
    hash stored in its footer (the hash of the data as stored, before re-roling).
    """
    path = catalog.locate(spec.dataset, variant=spec.dataset_variant)
    if path is None:  # a TOML import spec: imported whole
        ds = catalog.load(spec.dataset, variant=spec.dataset_variant)
        dataset_hash = ds.content_hash()
        ds = ds.with_roles(spec.roles) if spec.roles else ds
        spec = spec.with_outputs(ds.schema.outputs)
        check_targets(ds.schema, spec.targets)
        return ds, dataset_hash, spec
    doc = read_metadata(path)
    schema = Schema.from_dict(doc["schema"])
    roled = schema.with_roles(spec.roles) if spec.roles else schema
    spec = spec.with_outputs(roled.outputs)
    check_targets(roled, spec.targets)  # before reading, against every stored column
    columns = needed_columns(roled, spec)
    ds = read_dataset(path, columns=columns)
    if spec.roles:
        ds = ds.with_roles({k: v for k, v in spec.roles.items() if k in columns})
    return ds, str(doc.get("content_hash", "")), spec


def check_protocol(spec: ExperimentSpec, problems: dict[tuple[str, float, str], Problem]) -> None:
    """Spec mistakes that only the data reveal, found before the first job (one SpecError each).

    A selection needing a validation part the split lacks; a simulation-mode bootstrap over
    fewer than two training records; more k-fold blocks than the training rows can hold
    (each block needs its own init window and something to score); a search whose library is missing.
    """
    sel = spec.selection
    check_search(sel.search)  # bayes without optuna: refused before the first job
    for (target, window, split), problem in problems.items():
        where = f"split {split!r}"
        if sel.kind == "validation" and "validation" not in problem.parts:
            raise SpecError(f"{where}: [selection] kind = 'validation' needs a validation part, and the split has "
                            "none; add one to [split] (e.g. validation = [...] or validation_fraction) or use "
                            "kind = 'kfold'")
        if sel.kind in ("none", "validation"):
            continue
        sizes = problem.train.segment_sizes
        if spec.mode == "simulation" and sel.kind == "bootstrap" and len(sizes) < 2:
            raise SpecError(f"{where}: [selection] kind = 'bootstrap' resamples whole training records in "
                            f"simulation mode, and the training part has {len(sizes)}; use kind = 'kfold' "
                            "(contiguous time blocks inside the records) or a validation part")
        if spec.mode == "simulation" and sel.kind == "kfold":
            record_blocks(sizes, sel.folds, spec.init_samples)
        elif sel.kind == "kfold" and sel.folds > len(problem.train):
            raise SpecError(f"{where}: [selection] folds = {sel.folds} but the training part has only "
                            f"{len(problem.train)} rows; use fewer folds")


SPILL_MIN_BYTES = 64 * 2**20
"""Raw data above this size go to a shared memory-mapped file before workers start."""


def spill_problems(ctx: Context, directory: Path, min_bytes: int | None = None) -> None:
    """Move large raw arrays of ``ctx`` to memory-mapped files in ``directory`` (in place).

    Workers on this machine then map one shared copy instead of each unpickling its
    own (and keeping the pickled bytes alive beside it): at full marine size this is
    the difference between one and three copies of 1.2 GB.
    """
    min_bytes = SPILL_MIN_BYTES if min_bytes is None else min_bytes
    spilled: dict[int, RawSegments] = {}
    for problem in ctx.problems.values():
        for pool in (problem.train, *problem.parts.values()):
            raw = getattr(pool, "raw", None)
            if raw is None or raw.spill_file is not None or raw.nbytes < min_bytes:
                continue
            if id(raw) not in spilled:
                spilled[id(raw)] = raw.spill(directory / f"raw-{len(spilled)}.f64")
            pool.raw = spilled[id(raw)]


MAX_JOBS = 100_000
"""Jobs one run may plan unless ``ENGINEBENCH_MAX_JOBS`` raises it (the marine paper's full protocol plans 960)."""
MAX_FITS = 10_000
"""Model fits one job's selection may make per grid point (resamples or folds, times trials) unless
``ENGINEBENCH_MAX_FITS`` raises it."""


def _limit(name: str, default: int) -> int:
    raw = os.environ.get(name)
    try:
        return int(raw) if raw else default
    except ValueError:
        raise SpecError(f"{name}={raw!r} must be a whole number") from None


def check_work(spec: ExperimentSpec) -> None:
    """SpecError, before any data is read or job planned, when the experiment asks for more work than any run
    should do (10^12 repetitions, 10^7 resamples, 10^9 trials): the estimate and the limit that raises it."""
    targets = 1 if spec.all_targets else len(spec.targets)
    jobs = spec.repetitions * targets * len(spec.windows) * len(spec.methods)
    limit = _limit("ENGINEBENCH_MAX_JOBS", MAX_JOBS)
    if jobs > limit:
        raise SpecError(f"experiment {spec.name!r} plans at least {jobs:,} jobs ({spec.repetitions:,} repetitions x "
                        f"{targets} target(s) x {len(spec.windows)} window(s) x {len(spec.methods)} method(s)), more "
                        f"than the limit of {limit:,}; lower repetitions, or set ENGINEBENCH_MAX_JOBS to raise it")
    sel = spec.selection
    per_point = {"bootstrap": sel.resamples, "kfold": sel.folds}.get(sel.kind, 1)
    fits = per_point * (sel.trials if sel.search != "grid" else 1)
    limit = _limit("ENGINEBENCH_MAX_FITS", MAX_FITS)
    if fits > limit:
        raise SpecError(f"experiment {spec.name!r}: [selection] asks for {fits:,} fits per job and grid point "
                        f"({sel.kind}{f', {sel.trials:,} trials' if sel.search != 'grid' else ''}), more than the limit "
                        f"of {limit:,}; lower resamples, folds or trials, or set ENGINEBENCH_MAX_FITS to raise it")


def check_job_keys(jobs: list[Job]) -> None:
    """StoreError when two planned jobs would share a file (their keys are injective: never expected)."""
    seen: dict[str, Job] = {}
    for job in jobs:
        if job.key in seen:
            raise StoreError(f"jobs {seen[job.key]} and {job} would be stored as one file {job.key}.parquet; "
                             "rename one of the targets, splits or methods")
        seen[job.key] = job


def plan(ctx: Context) -> list[Job]:
    """Every job of the run, in a stable order (repetition outermost so early results cover all methods).

    A method fitting all targets at once has one job per (window, split, repetition), target ``JOINT``.
    """
    spec = ctx.spec
    splits = sorted({key[2] for key in ctx.problems}, key=list({k[2]: 0 for k in ctx.problems}).index)
    joint = {m for m in joint_methods(spec, ctx.methods) if any(k[0] == JOINT for k in ctx.problems)}
    return [
        Job(target, window, split, method, rep)
        for rep in range(spec.repetitions)
        for target in (*spec.targets, JOINT)
        for window in spec.windows
        for split in splits
        for method in spec.methods
        if (target == JOINT) == (method in joint) and (target, window, split) in ctx.problems
    ]


@dataclass
class RunResult:
    run: Run
    n_jobs: int
    n_failed: int
    damaged: dict[str, str] = field(default_factory=dict)
    """On resume: job files found damaged (key -> why) and computed again."""


def context_units(ctx: Context) -> dict[str, str]:
    """``{column: unit}`` of the columns a run loaded (its problems' training data), recorded in run.json as
    ``units`` for the labels of its tables and figures (``results.units.run_units`` reads them back)."""
    return {k: u for p in ctx.problems.values() for k, u in p.train.raw.units.items() if u}


def check_workers(workers: int | None) -> int:
    """``workers`` or all cores; SpecError below one."""
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise SpecError(f"--jobs must be >= 1, got {workers}")
    return workers


def execute(
    ctx: Context,
    run: Run,
    *,
    workers: int,
    plugins: tuple[str, ...] = (),
    progress: ProgressFn | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    resume: ResumeState | None = None,
    executor_options: dict[str, Any] | None = None,
) -> RunResult:
    """Run the jobs of ``plan(ctx)`` that ``run`` lacks and write each as it arrives; mark the run finished.

    Every plan over the runner ends here (an experiment, a learning curve), so each gets
    the executors, the store's atomic writes and resume alike.
    """
    jobs = plan(ctx)
    check_job_keys(jobs)
    if resume is None:
        todo = jobs
    else:
        todo = [j for j in jobs if j.key not in resume.finished]
        info = run.info()
        run.update_info(status="running", resumed=info.get("resumed", 0) + 1, finished_jobs=len(jobs) - len(todo),
                        resumes=[*info.get("resumes", []), environment.resume_record(workers)])
    n_failed = 0
    done = len(jobs) - len(todo)
    if hasattr(progress, "planned"):  # a progress display told the total before the first job finishes
        progress.planned(done, len(jobs))
    if hasattr(progress, "plan_jobs"):  # ... and which jobs, for costs per method (experiments/progress.py)
        progress.plan_jobs(todo)
    spill_dir = None
    if len(todo) > 1 and shares_memory(executor, workers, scheduler):
        spill_dir = tempfile.mkdtemp(prefix="enginebench-raw-")
        spill_problems(ctx, Path(spill_dir))
    results = None
    try:
        results = run_jobs(executor, ctx, todo, workers=workers, plugins=plugins, scheduler=scheduler,
                           run_dir=run.path, options=executor_options)
        for job, (rows, meta) in results:
            run.write_job(job.key, rows, meta)
            n_failed += meta["status"] != "ok"
            done += 1
            if hasattr(progress, "job_done"):
                progress.job_done(job, meta)
            if progress:
                progress(done, len(jobs), job)
    except BaseException:
        run.update_info(status="interrupted", finished_jobs=done)
        raise
    finally:
        if results is not None:  # stop the executor now (queued jobs cancelled), not when the traceback is freed
            results.close()
        if spill_dir is not None:
            shutil.rmtree(spill_dir, ignore_errors=True)
    stored = run.finished_jobs(verify=False)
    lost = [j.key for j in jobs if j.key not in stored]
    if lost:
        run.update_info(status="interrupted", finished_jobs=len(jobs) - len(lost))
        raise StoreError(f"run {run.id}: {len(lost)} of {len(jobs)} planned jobs are not stored (first: {lost[0]}); "
                         f"'enginebench run --resume {run.id}' computes them")
    n_failed = sum(run.job_meta(j.key).get("status") != "ok" for j in jobs) if resume is not None else n_failed
    if ctx.finish is not None:
        ctx.finish(run)
    run.update_info(status="finished", finished_jobs=done, failed_jobs=n_failed)
    return RunResult(run=run, n_jobs=len(jobs), n_failed=n_failed, damaged=dict(resume.damaged) if resume else {})
