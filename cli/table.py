"""``enginebench table`` and ``enginebench runs``: read stored runs."""

from __future__ import annotations

import click
from rich.console import Console

from enginebench.cli.options import check_metrics, check_output, emit, split_list, store_option


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--format", "fmt", type=click.Choice(["term", "md", "latex", "csv", "html"]), default="term", show_default=True)
@click.option("--metrics", default=None, help="Comma-separated metric columns (wide formats) "
              "[default: mae,mape,ppmcc,rmae; rmse,nrmse,fit,rmae for a simulation-mode run].")
@click.option("--interval", type=click.Choice(["t", "bootstrap"]), default=None, help="Interval over repetitions [default: the run's].")
@click.option("--paired", "paired_metric", default=None,
              help="Metric for the paired tests printed under term/md tables ('' to skip) "
                   "[default: rmse for a simulation-mode run, else mae].")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@click.option("--width", type=click.IntRange(min=40), default=None,
              help="Columns of the term table: its blocks split their metric columns to fit "
                   "[default: the terminal's width, 80 when it is not known].")
@store_option
def table(run_ref: str, fmt: str, metrics: str, interval, paired_metric: str, output, width, store) -> None:
    """Print the comparison table of RUN (an id, a unique prefix, 'latest' or a run folder).

    csv is the long table: one row per dataset, target, mode, window, method, split and
    metric with mean, ci_low, ci_high, sd, median, iqr (over repetitions), n_repeats and
    n_failed, and each metric's unit. The other formats are wide: one column per metric,
    mean ± half-width, headed with its unit (mae [degC], mape [%]). The term format prints
    one block per (target, mode, Delta, split) that fits the terminal (or --width).
    """
    from enginebench.results import tables
    from enginebench.results.store import RunStore
    from enginebench.results.units import run_units

    check_output(output)
    run = RunStore(store).get(run_ref)
    interval = interval or run.config().get("interval", "t")
    raw = run.metrics()
    summary = tables.summarize(raw, interval=interval)
    if paired_metric is None:
        paired_metric = tables.default_paired_metric(str(run.config().get("mode", "")))
    cols = split_list(metrics) or None
    if cols:
        check_metrics(cols, summary["metric"], "--metrics", run.id)
    if paired_metric:
        check_metrics([paired_metric], raw["metric"], "--paired", run.id)
    notes = job_note_lines(run)
    units = run_units(run.info())  # {} for a run made before units were recorded: headers without units
    if fmt == "term" and output is None:
        console = Console(width=width) if width else Console()
        console.print(tables.to_rich(summary, cols, title=run.id, units=units, width=console.width))
        if paired_metric:
            click.echo(paired_lines(tables.paired_tests(raw, paired_metric), paired_metric))
        for line in notes:
            click.echo(line)  # not through rich: a reason is one line, never wrapped
        return
    text = {
        "term": lambda: tables.to_term(summary, cols, title=run.id, units=units, width=width or 80) + (
            "\n" + paired_lines(tables.paired_tests(raw, paired_metric), paired_metric) if paired_metric else ""),
        "md": lambda: tables.to_markdown(summary, cols, units=units) + (
            "\n" + paired_lines(tables.paired_tests(raw, paired_metric), paired_metric) if paired_metric else ""),
        "latex": lambda: tables.to_latex(summary, cols, units=units),
        "csv": lambda: tables.to_csv(summary, units=units),
        "html": lambda: tables.to_html(summary, cols, units=units),
    }[fmt]()
    if notes and fmt in ("term", "md"):
        text += "\n" + "\n".join(notes) + "\n"
    emit(text, output)
    if notes and fmt not in ("term", "md"):  # csv, LaTeX and HTML stay parseable: the notes go to stderr
        for line in notes:
            click.echo(line, err=True)


def job_note_lines(run, width: int = 200) -> list[str]:
    """The run's distinct failure reasons and job warnings with their counts, one short line each.

    Same wording as at the end of ``run`` (``results.notes.note_lines``); a reason longer
    than ``width`` characters is cut (``runs show`` prints it whole).
    """
    from enginebench.results.notes import note_lines

    def short(text: str) -> str:
        text = " ".join(text.split())
        return text if len(text) <= width else text[: width - 3] + "..."

    notes = run.job_notes()
    return note_lines({kind: {(m, short(t)): n for (m, t), n in found.items()} for kind, found in notes.items()})


def paired_lines(tests, metric: str) -> str:
    """Plain sentences for the paired tests of each method against its block's best (raw and Holm p-values)."""
    from enginebench.results.tables import paired_text

    return paired_text(tests, metric)


@click.group()
def runs() -> None:
    """List the runs of a store."""


@runs.command("list")
@store_option
def runs_list(store) -> None:
    """One line per run: id, status, finished jobs, dataset, methods (a damaged run: why)."""
    from enginebench.results.store import RunStore

    rs = RunStore(store)
    found = rs.runs()
    if not found:
        click.echo(f"no runs in {rs.root}")
        return
    for r in found:
        why = r.damage()
        if why is not None:  # listed with the reason; every other run stays usable
            click.echo(f"{r.id}  {'damaged':<11} {why}")
            continue
        info = r.info()
        cfg = r.config()
        click.echo(f"{r.id}  {info.get('status', '?'):<11} {info['finished_jobs'] if 'finished_jobs' in info else len(r.finished_jobs(verify=False))}/{info.get('n_jobs', '?')} jobs"
                   f"  {cfg.get('dataset', '?')}  {','.join(str(m) for m in cfg.get('methods', []))}")


@runs.command("show")
@click.argument("run_ref", metavar="RUN", default="latest")
@store_option
def runs_show(run_ref: str, store) -> None:
    """Config, environment, plugin files, failure reasons and warnings, timings and a per-method summary of RUN."""
    import json

    from enginebench.results.store import RunStore
    from enginebench.results.tables import summarize

    from enginebench.results.notes import note_lines

    run = RunStore(store).get(run_ref)
    info, cfg, env = run.info(), run.config(), run.environment()
    plugins = run.plugins() or []
    metrics = run.metrics() if run.job_files() else None  # read first: a damaged job file is the only line printed
    notes = note_lines(run.job_notes())
    click.echo(f"run {run.id}: {info.get('status')} ({info['finished_jobs'] if 'finished_jobs' in info else len(run.finished_jobs(verify=False))}/{info.get('n_jobs')} jobs, "
               f"{info.get('failed_jobs', 0)} failed), created {info.get('created')}, config hash {info.get('config_hash', '')[:12]}")
    click.echo(f"experiment: {cfg.get('name')} on {cfg.get('dataset')} {cfg.get('dataset_variant', '')}; targets {cfg.get('targets')}; "
               f"mode {cfg.get('mode')}, windows {cfg.get('windows')}; {cfg.get('repetitions')} repetitions, seed {cfg.get('seed')}")
    click.echo(f"environment: python {env.get('python')}, {env.get('cpu')} x{env.get('cpu_count')}, gpu {env.get('gpu')}, "
               f"git {env.get('git_commit')}")
    click.echo("packages: " + json.dumps(env.get("packages", {})))
    for rec in plugins:
        click.echo(f"plugin file: {rec.get('path')} (sha256 {str(rec.get('sha256'))[:12]}; "
                   f"methods {', '.join(map(str, rec.get('methods', [])))})")
    if notes:
        click.echo("\nwhat the jobs said (distinct failure reasons and warnings, with counts):")
        for line in notes:
            click.echo("  " + line)
    if metrics is None:
        click.echo("\nno finished job yet")
        return
    times = metrics[metrics["metric"].str.startswith("time_")].groupby(["method", "metric"])["value"].mean().unstack()
    click.echo("\nmean seconds per job:\n" + times.round(3).to_string())
    summary = summarize(metrics, interval=cfg.get("interval", "t"))
    main = summary[summary["metric"].isin(["mae", "rmae"])][["target", "window", "split", "method", "metric", "mean", "ci_low", "ci_high", "n_repeats", "n_failed"]]
    click.echo("\n" + main.to_string(index=False))


@runs.command("rm")
@click.argument("run_refs", metavar="RUN...", nargs=-1, required=True)
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@store_option
def runs_rm(run_refs, yes: bool, store) -> None:
    """Delete runs from the store."""
    import shutil

    from enginebench.results.store import RunStore

    rs = RunStore(store)
    targets = [rs.get(ref) for ref in run_refs]
    if not yes:
        click.confirm(f"delete {len(targets)} run(s): {', '.join(r.id for r in targets)}?", abort=True)
    for r in targets:
        r.lock()  # a run another process is writing is refused, naming that process
        shutil.rmtree(r.path)
        r.unlock()
        click.echo(f"deleted {r.id}")
