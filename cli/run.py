"""``enginebench run``: run an experiment and print its comparison table."""

from __future__ import annotations

from pathlib import Path

import click
from rich.console import Console

from enginebench.cli.interrupt import echo_resume_hint, stop_on_sigterm
from enginebench.cli.options import load_plugins, plugin_option, store_option
from enginebench.cli.progress import JobProgress
from enginebench.experiments.executors import EXECUTORS


@click.command()
@click.argument("experiment", required=False)
@click.option("--resume", "resume_ref", default=None, metavar="RUN",
              help="Finish an interrupted run: only its missing jobs run, with its own config.")
@click.option("--repeats", type=click.IntRange(min=1), default=None, help="Repetitions (overrides the experiment).")
@click.option("--methods", default=None, help="Comma-separated methods to run (overrides the experiment).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Base seed (overrides the experiment).")
@click.option("--train-size", type=click.IntRange(min=0), default=None, help="Training subsample size (0 = all rows).")
@click.option("--jobs", "-j", "workers", type=click.IntRange(min=1), default=None, help="Worker processes of the local pool or local Dask cluster [default: all cores].")
@click.option("--executor", type=click.Choice(EXECUTORS), default=None,
              help="Where jobs run: local (process pool), dask (a Dask cluster) or slurm (SLURM job arrays through "
                   "submitit; docs/cluster.md) [default: local; dask with --scheduler].")
@click.option("--scheduler", default=None, metavar="ADDR",
              help="Dask scheduler address (tcp://HOST:8786, e.g. of a dask-jobqueue SLURMCluster); "
                   "without it --executor dask starts a local cluster of --jobs workers.")
@click.option("--slurm", "slurm_options", multiple=True, metavar="KEY=VALUE",
              help="A [slurm] setting of --executor slurm over the experiment's (repeatable): partition, time, cpus, "
                   "memory, max_parallel, account, qos, setup, cluster...")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
@click.option("--keep-models", is_flag=True, help="Store each job's fitted model in the run (as [store] models = true; "
              "docs/models.md): `enginebench export` and `enginebench.api.load_model` read them.")
@click.option("--tag", "tags", multiple=True, metavar="KEY=VALUE",
              help="Label the run (repeatable); kept in its run.json, not in its config; `runs list --tag` filters on it.")
@store_option
@plugin_option
def run(experiment, resume_ref, repeats, methods, seed, train_size, workers, executor, scheduler, slurm_options, quiet,
        keep_models, tags, store, plugins) -> None:
    """Run EXPERIMENT (a built-in name or a .toml file) and store it as a run.

    Every finished job is written to the run store at once, so an interrupted run keeps
    what it finished. The comparison table is printed at the end; `enginebench table RUN`
    prints it again in other formats. `--executor dask` runs the jobs on a Dask cluster
    (install with `pip install "enginebench[dask]"`); the results are the same.
    """
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.slurm_settings import parse_slurm_options
    from enginebench.experiments.spec import load_spec
    from enginebench.results.store import RunStore
    from enginebench.cli.table import paired_lines
    from enginebench.results.summary import paired_tests, summarize
    from enginebench.results.tables import to_rich

    from enginebench.errors import SpecError

    stop_on_sigterm()
    from enginebench.results.catalog import parse_tags

    tag_map = parse_tags(tags)
    if slurm_options and (executor or "local") != "slurm":
        raise SpecError("--slurm KEY=VALUE sets resources of --executor slurm; add --executor slurm")
    load_plugins(plugins)
    store_obj = RunStore(store)
    resume = spec = None
    if resume_ref:
        if experiment or repeats or methods or seed is not None or train_size is not None or keep_models:
            raise SpecError("--resume RUN takes the run's own config; give no EXPERIMENT or overrides with it")
        if tag_map:
            raise SpecError(f"--tag is for a new run; tag {resume_ref} with `enginebench runs tag {resume_ref} KEY=VALUE`")
        resume = store_obj.get(resume_ref)  # the store checks and prepares it (Run.prepare_resume)
        name = resume.id
    elif not experiment:
        raise SpecError("give an EXPERIMENT (built-in name or .toml file) or --resume RUN")
    else:
        spec = load_spec(experiment)
        overrides = {"repetitions": repeats, "seed": seed, "train_size": train_size}
        if keep_models:
            overrides["store"] = {**spec.store, "models": True}
        if methods:
            overrides["methods"] = [m.strip() for m in methods.split(",") if m.strip()]
            overrides["method_options"] = {k: v for k, v in spec.method_options.items() if k in overrides["methods"]}
        spec = spec.with_overrides(**overrides)
        name = spec.name
    known = {r.id for r in store_obj.runs()}
    try:
        with JobProgress(f"{name}: preparing", lambda job: f"{name}: last done {job.method} r{job.repetition}", quiet,
                         running=f"{name}: running",
                         running_label=lambda job: f"{name}: running {job.method} {job.target} r{job.repetition}"
                         ) as bar:
            result = run_experiment(spec, store_obj, workers=workers,
                                    plugins=tuple(str(Path(p).resolve()) for p in plugins), progress=bar,
                                    resume=resume, executor=executor or ("dask" if scheduler else "local"),
                                    scheduler=scheduler, tags=tag_map,
                                    executor_options=parse_slurm_options(slurm_options))
            bar.describe(f"{name}: done")
    except (KeyboardInterrupt, SystemExit):
        echo_resume_hint(store_obj, known, resume)
        raise
    raw = result.run.metrics()
    cfg = result.run.config()
    summary = summarize(raw, interval=cfg.get("interval", "t"))
    out = Console()
    from enginebench.results.units import run_units

    if "learning_curve" in cfg:  # a resumed learning curve ends as `learning-curve` does: its table and plot
        from enginebench.cli.learning_curve import echo_curve

        echo_curve(result.run)
    elif result.n_failed < result.n_jobs:
        out.print(to_rich(summary, title=f"{cfg.get('name')} ({cfg.get('dataset')}, {cfg.get('mode')})",
                          units=run_units(result.run.info()), width=out.width, bold=out.color_system is not None))
        from enginebench.results.tables import default_paired_metric

        paired_metric = default_paired_metric(cfg.get("mode", ""))
        click.echo(paired_lines(paired_tests(raw, paired_metric), paired_metric, out.width), nl=False)
    else:
        click.echo(f"no table: every one of the {result.n_jobs} jobs failed; the reasons:")
    for key, why in result.damaged.items():
        out.print(f"[yellow]job file {key}.parquet was damaged ({why}); it was computed again[/yellow]")
    from enginebench.results.notes import run_note_lines

    from enginebench.results.term import note_text

    click.echo(note_text(run_note_lines(result.run)), nl=False)  # each once, wrapped to the terminal
    if result.n_failed:
        out.print(f"[yellow]{result.n_failed} of {result.n_jobs} jobs failed; 'enginebench runs show {result.run.id}' "
                  "lists the reasons.[/yellow]")
    out.print(f"run {result.run.id} stored in {result.run.path}")
    dead = all_failed_methods(raw)
    if dead:
        # exit 1, not 2: the input was fine and the run is stored, but a method produced no result at all
        raise SystemExit(f"error: every job of {', '.join(dead)} failed (reasons above); run {result.run.id} is stored")


def all_failed_methods(metrics) -> list[str]:
    """Methods none of whose jobs succeeded."""
    status = metrics.groupby("method", sort=False)["status"].agg(lambda s: bool((s != "ok").all()))
    return [m for m, dead in status.items() if dead]
