"""The protocol engine: prepare an experiment, plan its jobs, run them, store every result.

Flow: load the dataset, cut the splits, build the samples of every (target, window,
split) once, then run the job graph (target x window x split x method x repetition) on
an executor. The parent process writes each finished job to the run store as soon as
it arrives.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable

from enginebench.datasets import catalog
from enginebench.datasets.samples import make_samples
from enginebench.datasets.splits import make_splits
from enginebench.errors import SpecError, StoreError
from enginebench.experiments import environment
from enginebench.experiments.executors import default_workers, run_local
from enginebench.experiments.jobs import Context, Job, Problem
from enginebench.experiments.spec import ExperimentSpec, from_dict
from enginebench.methods import registry
from enginebench.results.store import Run, RunStore

ProgressFn = Callable[[int, int, Job], None]


def physical_model_for(ds) -> object | None:
    """The dataset's declared physical model, if the toolkit knows it."""
    name = ds.meta.get("physical_model")
    if not name:
        return None
    from enginebench.datasets.physical import get_physical_model

    return get_physical_model(name, ds.meta)


def prepare(spec: ExperimentSpec) -> Context:
    """Load data and methods and build every problem's samples (fails early on bad specs)."""
    methods = {}
    for name in spec.methods:
        cls = registry.get(name)
        method = cls(**spec.method_options.get(name, {}))
        method.check_mode(spec.mode)
        methods[name] = method
    ds = catalog.load(spec.dataset, variant=spec.dataset_variant)
    dataset_hash = ds.content_hash()  # of the data as stored, before this experiment re-roles columns
    if spec.roles:
        ds = ds.with_roles(spec.roles)
    pm = physical_model_for(ds)
    splits = make_splits(ds, **spec.split)
    problems = {}
    for target, window, split in itertools.product(spec.targets, spec.windows, splits):
        train = make_samples(split.train, [target], spec.mode, window, physical_model=pm)
        parts = {name: make_samples(part, [target], spec.mode, window, physical_model=pm)
                 for name, part in split.parts().items()}
        problems[(target, window, split.name)] = Problem(train=train, parts=parts)
    return Context(spec=spec, dataset=ds.name, problems=problems, methods=methods, dataset_hash=dataset_hash)


def plan(ctx: Context) -> list[Job]:
    """Every job of the run, in a stable order (repetition outermost so early results cover all methods)."""
    spec = ctx.spec
    splits = sorted({key[2] for key in ctx.problems}, key=list({k[2]: 0 for k in ctx.problems}).index)
    return [
        Job(target, window, split, method, rep)
        for rep in range(spec.repetitions)
        for target in spec.targets
        for window in spec.windows
        for split in splits
        for method in spec.methods
    ]


@dataclass
class RunResult:
    run: Run
    n_jobs: int
    n_failed: int


def run_experiment(
    spec: ExperimentSpec,
    store: RunStore,
    *,
    workers: int | None = None,
    plugins: tuple[str, ...] = (),
    progress: ProgressFn | None = None,
    resume: Run | None = None,
) -> RunResult:
    """Run ``spec`` end to end and return the stored run.

    With ``resume``, the run's own config is used, its finished jobs are kept as they
    are, and only the missing jobs run (a job is finished once its file exists: files
    are written atomically, so a half-written job never counts).
    """
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise SpecError(f"--jobs must be >= 1, got {workers}")
    if resume is not None:
        spec = from_dict(resume.config(), origin=f"run {resume.id}")
        if spec.config_hash() != resume.info().get("config_hash"):
            raise StoreError(f"run {resume.id}: its config.toml no longer matches its config hash; it cannot be resumed safely")
    ctx = prepare(spec)
    jobs = plan(ctx)
    if resume is None:
        run = store.create(spec.name, spec.to_dict(), spec.config_hash(), environment.capture(spec.seed, workers), len(jobs))
        run.update_info(dataset_hash=ctx.dataset_hash)
        todo = jobs
    else:
        run = resume
        for stale in run.jobs_dir.glob(".*.tmp"):  # a write cut short by a kill: never a finished job
            stale.unlink(missing_ok=True)
        finished = run.finished_jobs()
        todo = [j for j in jobs if j.key not in finished]
        run.update_info(status="running", resumed=run.info().get("resumed", 0) + 1)
    n_failed = 0
    done = len(jobs) - len(todo)
    try:
        for job, (rows, meta) in run_local(ctx, todo, workers, plugins):
            run.write_job(job.key, rows, meta)
            n_failed += meta["status"] != "ok"
            done += 1
            if progress:
                progress(done, len(jobs), job)
    except BaseException:
        run.update_info(status="interrupted", finished_jobs=done)
        raise
    n_failed = sum(run.job_meta(j.key).get("status") != "ok" for j in jobs) if resume is not None else n_failed
    run.update_info(status="finished", finished_jobs=done, failed_jobs=n_failed)
    return RunResult(run=run, n_jobs=len(jobs), n_failed=n_failed)
