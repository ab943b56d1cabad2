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
@click.option("--paired", "paired_metric", default="mae", show_default=True,
              help="Metric for the paired tests printed under term/md tables ('' to skip).")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@store_option
def table(run_ref: str, fmt: str, metrics: str, interval, paired_metric: str, output, store) -> None:
    """Print the comparison table of RUN (an id, a unique prefix, 'latest' or a run folder).

    csv is the long table: one row per dataset, target, mode, window, method, split and
    metric with mean, ci_low, ci_high, sd, median, iqr (over repetitions), n_repeats and
    n_failed. The other formats are wide: one column per metric, mean ± half-width.
    """
    from enginebench.results import tables
    from enginebench.results.store import RunStore

    run = RunStore(store).get(run_ref)
    interval = interval or run.config().get("interval", "t")
    raw = run.metrics()
    summary = tables.summarize(raw, interval=interval)
    cols = [m.strip() for m in metrics.split(",") if m.strip()]
    if fmt == "term" and output is None:
        Console().print(tables.to_rich(summary, cols, title=run.id))
        if paired_metric:
            click.echo(paired_lines(tables.paired_tests(raw, paired_metric), paired_metric))
        return
    text = {
        "term": lambda: tables.to_markdown(summary, cols),
        "md": lambda: tables.to_markdown(summary, cols) + ("\n" + paired_lines(tables.paired_tests(raw, paired_metric), paired_metric)
                                                           if paired_metric else ""),
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


def paired_lines(tests, metric: str) -> str:
    """Plain sentences for the paired tests of each method against its block's best."""
    if tests.empty:
        return ""
    lines = [f"Paired tests on {metric} against the best method of each block (over repetitions):"]
    for r in tests.itertuples():
        lines.append(f"  {r.target}, {r.mode}, window {r.window:g} s, {r.split}: {r.method} - {r.versus} = {r.mean_difference:+.4g}"
                     f"  (paired t p = {r.t_pvalue:.2g}, Wilcoxon p = {r.wilcoxon_pvalue:.2g}, n = {r.n_pairs})")
    return "\n".join(lines) + "\n"


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
