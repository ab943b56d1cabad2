"""The protocol engine's entry: prepare an experiment, run its jobs, store every result, or resume a run.

Flow: load the dataset, cut the splits, build the samples of every (target, window,
split) once, then run the job graph (target x window x split x method x repetition) on
an executor (``engine.py``). The parent process writes each finished job to the run store
as soon as it arrives. A stored learning-curve run resumes here too (``context_of_run``).
"""

from __future__ import annotations

import itertools
from typing import Any

from enginebench import registry
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.splits import make_splits
from enginebench.errors import SpecError, StoreError
from enginebench.experiments import environment
from enginebench.experiments.coverage import range_coverage
from enginebench.experiments.engine import (
    ProgressFn, RunResult, check_protocol, check_work, check_workers, context_units, execute, load_dataset,
    physical_model_for, plan,
)
from enginebench.experiments.executors import check_executor
from enginebench.experiments.jobs import JOINT, Context, Problem, joint_methods
from enginebench.experiments.learning_curve import curve_settings, prepare_curve
from enginebench.experiments.recorded_options import method_options, with_recorded_options
from enginebench.experiments.spec import ExperimentSpec, from_dict
from enginebench.method import TrainingShape
from enginebench.results.run_folder import Run
from enginebench.results.store import RunStore


def prepare(spec: ExperimentSpec) -> Context:
    """Load data and methods and set up every problem's sample pools (fails early on bad specs).

    The raw arrays of each split part are read once and shared by all targets and
    windows; features are built per job for the rows it uses (see ``SamplePool``).
    """
    methods = {}
    for name in spec.methods:
        cls = registry.get(name)
        method = cls(**spec.method_options.get(name, {}))
        method.check_mode(spec.mode)
        methods[name] = method
    ds, dataset_hash, spec = load_dataset(spec)
    pm = physical_model_for(ds)
    splits = make_splits(ds, **spec.split)
    name = ds.name
    del ds  # from here on only the split parts' frames are alive, and each goes once its arrays are read
    internals = None if spec.mode == "simulation" else []
    raws: dict[str, dict[str, RawSegments]] = {}
    while splits:
        split = splits.pop(0)
        parts = {"train": split.train, **split.parts()}
        arrays = raws[split.name] = {}
        del split
        for part_name in list(parts):
            arrays[part_name] = RawSegments.from_dataset(parts.pop(part_name), outputs=spec.targets, internals=internals)
    problems = {}
    for target, window, split in itertools.product(spec.targets, spec.windows, raws):
        pools = {part: SamplePool(raw, [target], spec.mode, window, physical_model=pm,
                                  init_samples=0 if part == "train" else spec.init_samples)
                 for part, raw in raws[split].items()}
        train = pools.pop("train")
        problems[(target, window, split)] = Problem(train=train, parts=pools)
    if joint_methods(spec, methods):
        if JOINT in spec.targets:
            raise SpecError(f"target {JOINT!r} is the name of the joint jobs; rename the column to run joint_targets")
        for window, split in itertools.product(spec.windows, raws):
            pools = {part: SamplePool(raw, list(spec.targets), spec.mode, window, physical_model=pm,
                                      init_samples=0 if part == "train" else spec.init_samples)
                     for part, raw in raws[split].items()}
            problems[(JOINT, window, split)] = Problem(train=pools.pop("train"), parts=pools)
    check_protocol(spec, problems)
    for raw in {id(r["train"]): r["train"] for r in raws.values()}.values():
        shape = TrainingShape(records=tuple(len(s.t) for s in raw.segments), inputs=tuple(raw.inputs),
                              targets=tuple(spec.targets), dt=float(raw.dt), mode=spec.mode)
        for method in methods.values():
            method.check_columns(list(raw.inputs), list(raw.internals), list(spec.targets))
            method.check_data(shape)
    return Context(spec=spec, dataset=name, problems=problems, methods=methods, dataset_hash=dataset_hash,
                   coverage=range_coverage(raws))


def context_of_run(run: Run) -> Context:
    """The prepared context of a stored run from its own config (an experiment, or a learning curve over one).

    StoreError when the config no longer matches the run's config hash (checked before any data is read).
    """
    config = run.config()
    origin = f"run {run.id}"
    if "learning_curve" in config:  # a plan over this runner: the training amount is one more job coordinate
        spec, months, rows, digest = curve_settings(config, origin)
        build = lambda: prepare_curve(spec, months, rows).context  # noqa: E731
    else:
        spec = from_dict(config, origin=origin)
        digest = spec.config_hash()
        build = lambda: prepare(spec)  # noqa: E731
    if digest != run.info().get("config_hash"):
        raise StoreError(f"run {run.id}: its config.toml no longer matches its config hash; it cannot be resumed safely")
    return with_recorded_options(build(), run)



def run_experiment(
    spec: ExperimentSpec | None,
    store: RunStore,
    *,
    workers: int | None = None,
    plugins: tuple[str, ...] = (),
    progress: ProgressFn | None = None,
    resume: Run | None = None,
    executor: str = "local",
    scheduler: str | None = None,
    tags: dict[str, str] | None = None,
    executor_options: dict[str, Any] | None = None,
) -> RunResult:
    """Run ``spec`` end to end and return the stored run (a new run gets ``tags``, KEY -> VALUE, in its run.json).

    ``executor`` is ``local`` (in-process or a process pool of ``workers``) or ``dask``
    (the cluster at ``scheduler``, or a LocalCluster of ``workers`` processes without one) or
    ``slurm`` (job arrays through submitit; ``executor_options`` override the spec's ``[slurm]`` keys).

    With ``resume``, the run's own config is used (``spec`` is ignored), its finished jobs
    are kept as they are, and only the missing jobs run (a job is finished once its file
    exists: files are written atomically, so a half-written job never counts); the
    checks and clean-up before that are the store's (``Run.prepare_resume``).
    """
    workers = check_workers(workers)
    check_executor(executor, scheduler)
    if resume is None:
        check_work(spec)
        ctx = prepare(spec)
        spec = ctx.spec  # targets = "all" resolved
        run = store.create(spec.name, spec.to_dict(), spec.config_hash(), environment.capture(spec.seed, workers),
                           len(plan(ctx)), tags=tags)
        run.update_info(dataset_hash=ctx.dataset_hash, units=context_units(ctx), range_coverage=ctx.coverage,
                        method_options=method_options(ctx))
        return execute(ctx, run, workers=workers, plugins=plugins, progress=progress, executor=executor,
                       scheduler=scheduler, executor_options=executor_options)
    state = resume.prepare_resume()  # refuses a damaged run, other plugin files, a second writer
    try:
        ctx = context_of_run(resume)
    except BaseException:
        resume.unlock()
        raise
    return execute(ctx, resume, workers=workers, plugins=plugins, progress=progress, executor=executor,
                   scheduler=scheduler, resume=state, executor_options=executor_options)
