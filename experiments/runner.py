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
from enginebench.errors import SpecError
from enginebench.experiments import environment
from enginebench.experiments.executors import default_workers, run_local
from enginebench.experiments.jobs import Context, Job, Problem
from enginebench.experiments.spec import ExperimentSpec
from enginebench.methods import registry
from enginebench.results.store import Run, RunStore

ProgressFn = Callable[[int, int, Job], None]


def physical_model_for(ds) -> object | None:
    """The dataset's declared physical model, if the toolkit knows it."""
    name = ds.meta.get("physical_model")
    if not name:
        return None
    from enginebench.datasets.physical import get_physical_model

    return get_physical_model(name)


def prepare(spec: ExperimentSpec) -> Context:
    """Load data and methods and build every problem's samples (fails early on bad specs)."""
    methods = {}
    for name in spec.methods:
        cls = registry.get(name)
        method = cls(**spec.method_options.get(name, {}))
        method.check_mode(spec.mode)
        methods[name] = method
    ds = catalog.load(spec.dataset, variant=spec.dataset_variant)
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
    return Context(spec=spec, dataset=ds.name, problems=problems, methods=methods)


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
) -> RunResult:
    """Run ``spec`` end to end and return the stored run."""
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise SpecError(f"--jobs must be >= 1, got {workers}")
    ctx = prepare(spec)
    jobs = plan(ctx)
    run = store.create(spec.name, spec.to_dict(), spec.config_hash(), environment.capture(spec.seed, workers), len(jobs))
    n_failed = 0
    done = 0
    try:
        for job, (rows, meta) in run_local(ctx, jobs, workers, plugins):
            run.write_job(job.key, rows, meta)
            n_failed += meta["status"] != "ok"
            done += 1
            if progress:
                progress(done, len(jobs), job)
    except BaseException:
        run.update_info(status="interrupted", finished_jobs=done)
        raise
    run.update_info(status="finished", finished_jobs=done, failed_jobs=n_failed)
    return RunResult(run=run, n_jobs=len(jobs), n_failed=n_failed)
