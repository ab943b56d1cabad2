"""``enginebench table`` and ``enginebench runs``: read stored runs."""

from __future__ import annotations

import click
from rich.console import Console

from enginebench.cli.options import store_option


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--format", "fmt", type=click.Choice(["term", "md", "latex", "csv", "html"]), default="term", show_default=True)
@click.option("--metrics", default="mae,mape,ppmcc,rmae", show_default=True, help="Comma-separated metric columns (wide formats).")
@click.option("--interval", type=click.Choice(["t", "bootstrap"]), default=None, help="Interval over repetitions [default: the run's].")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@store_option
def table(run_ref: str, fmt: str, metrics: str, interval, output, store) -> None:
    """Print the comparison table of RUN (an id, a unique prefix, 'latest' or a run folder).

    csv is the long table: one row per dataset, target, mode, window, method, split and
    metric with mean, ci_low, ci_high, sd, median, iqr (over repetitions), n_repeats and
    n_failed. The other formats are wide: one column per metric, mean ± half-width.
    """
    from enginebench.results import tables
    from enginebench.results.store import RunStore

    run = RunStore(store).get(run_ref)
    interval = interval or run.config().get("interval", "t")
    summary = tables.summarize(run.metrics(), interval=interval)
    cols = [m.strip() for m in metrics.split(",") if m.strip()]
    if fmt == "term" and output is None:
        Console().print(tables.to_rich(summary, cols, title=run.id))
        return
    text = {
        "term": lambda: tables.to_markdown(summary, cols),
        "md": lambda: tables.to_markdown(summary, cols),
        "latex": lambda: tables.to_latex(summary, cols),
        "csv": lambda: tables.to_csv(summary),
        "html": lambda: tables.to_html(summary, cols),
    }[fmt]()
    if output:
        with open(output, "w", encoding="utf-8") as fh:
            fh.write(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)


@click.group()
def runs() -> None:
    """List the runs of a store."""


@runs.command("list")
@store_option
def runs_list(store) -> None:
    """One line per run: id, status, finished jobs, dataset, methods."""
    from enginebench.results.store import RunStore

    rs = RunStore(store)
    found = rs.runs()
    if not found:
        click.echo(f"no runs in {rs.root}")
        return
    for r in found:
        info = r.info()
        cfg = r.config()
        click.echo(f"{r.id}  {info.get('status', '?'):<11} {info.get('finished_jobs', len(r.finished_jobs()))}/{info.get('n_jobs', '?')} jobs"
                   f"  {cfg.get('dataset', '?')}  {','.join(cfg.get('methods', []))}")
