"""``enginebench learning-curve``: test error against months of training data."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from enginebench.cli.options import check_output, load_plugins, plugin_option, store_option
from enginebench.cli.progress import JobProgress
from enginebench.experiments.executors import EXECUTORS

if TYPE_CHECKING:
    from enginebench.results.run_folder import Run


@click.command("learning-curve")
@click.argument("experiment")
@click.option("--months", default="0.5,1,2,3,6", show_default=True,
              help="Comma-separated amounts of training data: the first N months of the training period, by time.")
@click.option("--methods", default="krls,mtl-krls", show_default=True,
              help="Comma-separated methods (options from the experiment where it sets them).")
@click.option("--repeats", type=click.IntRange(min=1), default=None, help="Repetitions (overrides the experiment).")
@click.option("--rows", type=click.Choice(["proportional", "fixed"]), default="proportional", show_default=True,
              help="Training rows per amount: the experiment's train_size scaled by the share of the training "
                   "period covered (more months, more rows), or train_size for every amount.")
@click.option("--train-size", type=click.IntRange(min=0), default=None,
              help="Training subsample of the whole training period (overrides the experiment; 0 = all rows).")
@click.option("--metric", default="mae", show_default=True, help="Metric of the curve (test part).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="PNG file for the plot [default: learning_curve.png in the run folder].")
@click.option("--jobs", "-j", "workers", type=click.IntRange(min=1), default=None, help="Worker processes [default: all cores].")
@click.option("--executor", type=click.Choice(EXECUTORS), default=None,
              help="Where jobs run, as for 'run' [default: local; dask with --scheduler].")
@click.option("--scheduler", default=None, metavar="ADDR", help="Dask scheduler address (as for 'run').")
@click.option("--quiet", "-q", is_flag=True, help="No progress bar.")
@store_option
@plugin_option
def learning_curve(experiment: str, months: str, methods: str, repeats, rows: str, train_size, metric: str,
                   plot_path, workers, executor, scheduler, quiet, store, plugins) -> None:
    """Run EXPERIMENT's methods on the first N months of its training data, for each N in --months.

    Every amount is scored on the experiment's unchanged test part, with its
    repetitions, subsampling and model selection. The jobs are stored as one run
    (splits read 'test@3mo'; an interrupted curve, stopped by Ctrl-C or SIGTERM, prints the
    command that finishes it, `enginebench run --resume RUN`, which ends with the same table
    and plot); the table prints the test metric's mean and Student-t 95% interval per
    amount, and a PNG plot is written when matplotlib is installed.
    """
    from enginebench.cli.interrupt import echo_resume_hint, stop_on_sigterm
    from enginebench.experiments.learning_curve import parse_months, run_learning_curve
    from enginebench.experiments.spec import load_spec
    from enginebench.results.store import RunStore

    check_output(plot_path, "--plot")
    from enginebench.errors import DataError
    from enginebench.results.metrics import METRICS

    if metric not in METRICS:
        raise DataError(f"--metric: unknown metric {metric!r}; use one of {', '.join(sorted(METRICS))}")
    load_plugins(plugins)
    amounts = parse_months(months)
    spec = load_spec(experiment)
    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    spec = spec.with_overrides(repetitions=repeats, train_size=train_size, methods=chosen,
                               method_options={k: v for k, v in spec.method_options.items() if k in chosen})
    store_obj = RunStore(store)
    known = {r.id for r in store_obj.runs()}
    stop_on_sigterm()
    try:
        with JobProgress(f"{spec.name} learning curve: preparing",
                         lambda job: f"{spec.name}: {job.split} {job.method} r{job.repetition}", quiet) as bar:
            result = run_learning_curve(spec, amounts, store_obj, rows=rows, workers=workers,
                                        plugins=tuple(str(Path(p).resolve()) for p in plugins), progress=bar,
                                        executor=executor or ("dask" if scheduler else "local"), scheduler=scheduler)
    except (KeyboardInterrupt, SystemExit):
        echo_resume_hint(store_obj, known)
        raise
    if result.n_failed:
        click.echo(f"{result.n_failed} of {result.n_jobs} jobs failed; they are counted in n_failed.")
    echo_curve(result.run, metric, plot_path)


def echo_curve(run: Run, metric: str = "mae", plot_path: str | Path | None = None) -> None:
    """Print a finished learning-curve run's amounts and table, draw its plot (default: in the run folder) and
    name the run: the end of ``learning-curve``, and of ``run --resume`` of a curve."""
    from enginebench.experiments.learning_curve import PLOT_FILE, SUMMARY_FILE, curve_table, plot_curve, summarize_curve

    cfg = run.config()
    stored = metric == "mae" and (run.path / SUMMARY_FILE).exists()
    summary = run.read_table(SUMMARY_FILE) if stored else summarize_curve(run.metrics(), metric=metric)
    amounts = run.info().get("amounts") or []
    click.echo(f"Learning curve of {cfg.get('name')} ({cfg.get('dataset')}, {cfg.get('mode')}); amounts: "
               + ", ".join(f"{a['months']:g} mo = {sum(a['hours'].values()):.1f} h logged"
                           + (" (the whole training period)" if a.get("whole_training_period") else "")
                           for a in amounts))
    click.echo(curve_table(summary), nl=False)
    written = plot_curve(summary, plot_path or run.path / PLOT_FILE) if not summary.empty else None
    if written is None:
        click.echo("plot skipped: matplotlib is not installed (pip install matplotlib)" if not summary.empty
                   else "plot skipped: nothing finished")
    else:
        click.echo(f"plot: {written}")
    click.echo(f"run {run.id} stored in {run.path}")
