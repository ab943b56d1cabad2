"""``enginebench rank``: feature ranking by backward elimination for a stored run."""

from __future__ import annotations

import click

from enginebench.cli.options import load_plugins, plugin_option, store_option


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--methods", default=None, help="Comma-separated methods to rank [default: the run's non-baseline methods].")
@click.option("--repetition", type=click.IntRange(min=0), default=0, show_default=True,
              help="Whose training subsample and seed to use.")
@store_option
@plugin_option
def rank(run_ref: str, methods, repetition: int, store, plugins) -> None:
    """Rank the input variables of RUN's methods by backward elimination.

    One ranking per target, window and method, computed on the training rows of one
    repetition; a lagged series counts as one variable, and a hybrid's PM prediction is
    the variable "PM". The rankings are printed and stored in the run folder
    (rankings/*.parquet).
    """
    from enginebench.experiments.rank_run import rank_run
    from enginebench.results.store import RunStore

    load_plugins(plugins)
    run = RunStore(store).get(run_ref)
    run.check_plugins("ranked (its methods are re-fitted)")
    chosen = [m.strip() for m in methods.split(",")] if methods else None
    for key, table in rank_run(run, chosen, repetition):
        click.echo(f"\n{key}")
        for row in table.itertuples():
            err = "" if row.error_after_removal != row.error_after_removal else f"   (error without it and below: {row.error_after_removal:.4g})"
            click.echo(f"  {row.rank:>2}. {row.variable}{err}")
