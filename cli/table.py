"""``enginebench table``: the comparison table of a stored run (``runs`` lives in cli/runs.py)."""

from __future__ import annotations

import click
from rich.console import Console

from enginebench.cli.options import check_metrics, check_output, emit, split_list, store_option
from enginebench.results.formats import FORMATS, renderer


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--format", "fmt", type=click.Choice(FORMATS), default="term", show_default=True)
@click.option("--metrics", default=None, help="Comma-separated metric columns (wide formats), or 'all' (every "
              "metric the run has) [default: mae,mape,ppmcc,rmae; rmse,nrmse,fit,rmae for a simulation-mode run].")
@click.option("--interval", type=click.Choice(["t", "bootstrap"]), default=None, help="Interval over repetitions [default: the run's].")
@click.option("--paired", "paired_metric", default=None,
              help="Metric for the paired tests printed under term/md tables ('' to skip) "
                   "[default: rmse for a simulation-mode run, else mae].")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@click.option("--width", type=click.IntRange(min=40), default=None,
              help="Columns of the term table: its blocks split their metric columns to fit "
                   "[default: the terminal's width, 80 when it is not known].")
@click.option("--by-record", "by_record", is_flag=True,
              help="One column per test record (the first --metrics metric, default nrmse in simulation mode, else mae) "
                   "and the mean over records with its 95% t interval (n = records); term or csv.")
@click.option("--picks", is_flag=True,
              help="The hyperparameters each job selected: one block per method, one row per job (term or csv).")
@click.option("--folds", is_flag=True,
              help="Each job's selection scores: its --top best grid points by mean score with the score on every "
                   "resample or fold, * on the selected one; jobs without a stored selection table are named with "
                   "why (term or csv; with --picks in term, after the picks).")
@click.option("--top", type=click.IntRange(min=1), default=3, show_default=True,
              help="Grid points per job that --folds shows (the selected one always).")
@store_option
def table(run_ref: str, fmt: str, metrics: str, interval, paired_metric: str, output, width, by_record: bool,
          picks: bool, folds: bool, top: int, store) -> None:
    """Print the comparison table of RUN (an id, a unique prefix, 'latest' or a run folder).

    csv is the long table: one row per dataset, target, mode, window, method, split and
    metric with mean, ci_low, ci_high, sd, median, iqr (over repetitions), n_repeats and
    n_failed, and each metric's unit. The other formats are wide: one column per metric,
    mean ± half-width, headed with its unit (mae [degC], mape [%]). The term format prints
    one block per (target, mode, Delta, split) that fits the terminal (or --width).
    --picks and --folds print the chosen model instead: the selected hyperparameters and the
    selection scores behind them (docs/runs.md).
    """
    from enginebench.results import tables
    from enginebench.results.notes import run_note_lines
    from enginebench.results.store import open_run
    from enginebench.results.term import note_text
    from enginebench.results.units import run_units

    check_output(output)
    run = open_run(run_ref, store)
    if picks or folds:
        return _picks(run, fmt, picks, folds, top, output)
    if by_record:  # one metric: 'all' means the default one
        return _by_record(run, [] if _is_all(metrics) else split_list(metrics), fmt, output, width)
    interval = interval or run.config().get("interval", "t")
    raw = run.metrics()
    if len(raw) and not (raw["status"] == "ok").any():  # nothing to tabulate: say why instead
        click.echo(note_text(run_note_lines(run, width=200), width), nl=False)
        from enginebench.errors import DataError

        raise DataError(f"no job of run {run.id} succeeded, so there is no table; the reasons are above")
    summary = tables.summarize(raw, interval=interval)
    if paired_metric is None:
        paired_metric = tables.default_paired_metric(str(run.config().get("mode", "")))
    from enginebench.results.realtime import expand_rt

    cols = all_metrics(summary) if _is_all(metrics) else expand_rt(split_list(metrics)) or None  # rt: the step times
    if cols:
        check_metrics(cols, summary["metric"], "--metrics", run.id)
    if paired_metric:
        check_metrics([paired_metric], raw["metric"], "--paired", run.id)
    notes = run_note_lines(run, width=200)  # a reason longer than 200 characters is cut (runs show prints it whole)
    units = run_units(run.info())  # {} for a run made before units were recorded: headers without units
    if fmt == "term" and output is None:
        console = Console(width=width) if width else Console()
        console.print(tables.to_rich(summary, cols, title=run.id, units=units, width=console.width,
                                     bold=console.color_system is not None))  # a pipe or file gets no bold
        tests = tables.paired_tests(raw, paired_metric) if paired_metric else None
        if paired_metric:
            click.echo(paired_lines(tests, paired_metric, console.width))
        if notes:
            click.echo(note_text(notes, width), nl=False)  # each once, wrapped to the terminal or --width
        _verdict(run, raw, summary, tests, paired_metric, console.width)
        return
    text = renderer(fmt)(summary, cols, title=run.id, units=units, width=width or 80)
    if paired_metric and fmt in ("term", "md"):  # text formats carry the paired tests under the table
        text += "\n" + paired_lines(tables.paired_tests(raw, paired_metric), paired_metric,
                                    width or 80 if fmt == "term" else None)
    if notes and fmt in ("term", "md"):
        text += "\n" + "\n".join(notes) + "\n"
    emit(text, output)
    if notes and fmt not in ("term", "md"):  # csv, LaTeX and HTML stay parseable: the notes go to stderr
        for line in notes:
            click.echo(line, err=True)


def _verdict(run, raw, summary, tests, metric: str | None, width: int) -> None:
    """The report's verdict lines (``results.verdict``), one per test block, wrapped to ``width``."""
    import textwrap

    from enginebench.results import tables
    from enginebench.results.verdict import verdicts

    metric = metric or tables.default_paired_metric(str(run.config().get("mode", "")))
    found = verdicts(raw, summary, tests, metric, run.job_metas().values())
    if not found:
        return
    click.echo(f"\nVerdict (lowest mean {metric} on the test part; margin over the best baseline):")
    for v in found:
        click.echo(textwrap.fill(v.text(), width, initial_indent="  ", subsequent_indent="    ",
                                 break_long_words=False, break_on_hyphens=False))


def _is_all(text: str | None) -> bool:
    return (text or "").strip().lower() == "all"


def all_metrics(summary) -> list[str]:
    """``--metrics all``: every metric of the summary, the known ones in METRICS' order, then the rest (skill_...);
    not the count columns the wide table adds itself."""
    from enginebench.results.metrics import METRICS
    from enginebench.results.tables import COUNT_COLUMNS

    have = set(summary["metric"])
    return ([m for m in METRICS if m in have]
            + sorted(m for m in have if m not in METRICS and m not in COUNT_COLUMNS))


def _by_record(run, metrics: list[str], fmt: str, output, width) -> None:
    from enginebench.results.metrics import PER_SEGMENT
    from enginebench.results.records import record_frame, record_table, to_rich
    from enginebench.results.units import run_units

    metric = metrics[0] if metrics else ("nrmse" if run.config().get("mode") == "simulation" else "mae")
    if metric not in PER_SEGMENT:
        raise click.UsageError(f"--by-record shows one of {', '.join(PER_SEGMENT)} per record, got --metrics {metric}")
    frame = record_frame(run.job_metas())
    result = record_table(frame, metric)
    if result.empty:
        raise click.ClickException(f"run {run.id} keeps no per-record results (runs made before they were kept, or "
                                   "parts of more than 200 segments); rerun it to get them")
    if fmt == "csv":
        emit(result.to_csv(index=False), output)
        return
    if fmt != "term":
        raise click.UsageError("--by-record prints term or csv tables")
    console = Console(width=width) if width else Console()
    for t in to_rich(result, metric, run_units(run.info())):
        console.print(t)
        console.print()


def _picks(run, fmt: str, picks: bool, folds: bool, top: int, output) -> None:
    from enginebench.results.picks import folds_frame, folds_text, missing_folds_lines, picks_frame, picks_text

    if fmt not in ("term", "csv"):
        raise click.UsageError("--picks and --folds print term or csv tables")
    if fmt == "csv" and picks and folds:
        raise click.UsageError("--format csv prints one table: give --picks or --folds (the folds' rows hold the "
                               "picked values too)")
    chosen = picks_frame(run)
    if fmt == "csv":
        emit((chosen if picks else folds_frame(run, top)).to_csv(index=False), output)
        return
    text = picks_text(chosen) if picks else ""
    if folds:
        scored = folds_frame(run, top)
        missing = missing_folds_lines(chosen)
        kind = run.config().get("selection", {}).get("kind")
        text += ("\n" if text else "") + folds_text(scored, kind) + ("\n" if len(scored) and missing else "")
        text += "".join(f"no selection table: {line}\n" for line in missing)
    emit(text, output)


def paired_lines(tests, metric: str, width: int | None = None) -> str:
    """Plain sentences for the paired tests of each method against its block's best (raw and Holm p-values),
    wrapped to `width` columns when given."""
    from enginebench.results.tables import paired_text

    return paired_text(tests, metric, width)

