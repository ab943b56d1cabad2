"""``enginebench compare``, ``guard`` and ``publish``: runs against runs and against published baselines."""

from __future__ import annotations

import sys

import click

from enginebench.cli.options import check_metrics, check_output, emit, store_option


def _metric_list(text: str | None) -> list[str] | None:
    if not text or text.strip() == "all":
        return None
    return [m.strip() for m in text.split(",") if m.strip()]


@click.command()
@click.argument("run_a", metavar="RUN_A")
@click.argument("others", metavar="RUN_B [RUN_C ...]", nargs=-1)
@click.option("--metrics", default=None,
              help="Comma-separated metrics to compare, or 'all' [default: the table's for RUN_A's mode, "
                   "mae,mape,ppmcc,rmae or rmse,nrmse,fit,rmae in simulation mode; those the runs have].")
@click.option("--format", "fmt", type=click.Choice(["term", "csv"]), default="term", show_default=True,
              help="term: statements and a table; csv: one row per compared metric with every column "
                   "(with several runs, led by the ids run_a and run_b).")
@click.option("--interval", type=click.Choice(["t", "bootstrap"]), default=None, help="Interval over repetitions [default: RUN_A's].")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@store_option
def compare(run_a: str, others: tuple[str, ...], metrics: str, fmt: str, interval, output, store) -> None:
    """Compare RUN_B (default: latest), and RUN_C ..., with RUN_A (the reference) per method and metric.

    For each (target, mode, window, split, method, metric) in both runs: both means with
    their intervals, the difference B - A with a 95% interval, a t-test and a rank test
    (paired t and Wilcoxon when the repetitions pair up, i.e. both runs have the same
    dataset, seed, training size, split, roles and mode; otherwise Welch t and
    Mann-Whitney U), and a plain statement of what moved outside RUN_A's interval.
    With three runs or more, each later run is compared with RUN_A the same way, after a
    side-by-side table of all runs and one note per run on what was compared and skipped.
    """
    from enginebench.results.compare import comparison_table, compare_many, many_csv, many_text, statements
    from enginebench.results.store import RunStore
    from enginebench.results.term import note_text

    from enginebench.results.tables import DEFAULT_METRICS, SIMULATION_METRICS

    check_output(output)
    rs = RunStore(store)
    runs = [rs.get(ref) for ref in (run_a, *(others or ("latest",)))]
    if metrics is None:  # the table's metrics for the mode; a metric no run has (undefined here) is left out
        default = SIMULATION_METRICS if runs[0].config().get("mode") == "simulation" else DEFAULT_METRICS
        have = {m for r in runs for m in r.metrics()["metric"]}
        wanted = [m for m in default if m in have] or list(default)
    else:
        wanted = _metric_list(metrics)
    cmps = compare_many(runs, interval=interval, metric_names=wanted)
    if wanted and metrics is not None:
        check_metrics(wanted, [m for c in cmps if "metric" in c.table for m in c.table["metric"]], "--metrics", "")
    if len(cmps) > 1:
        text = many_csv(cmps) if fmt == "csv" else many_text(cmps)
    elif fmt == "csv":
        text = cmps[0].table.to_csv(index=False)
    else:
        text = comparison_table(cmps[0]) + "\n" + note_text(statements(cmps[0]))
    emit(text, output)


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--baseline", "-b", required=True, metavar="FILE",
              help="Baseline JSON written by 'enginebench publish', or the name of one in results/published/.")
@click.option("--tolerance", "-t", default="0", show_default=True,
              help="Slack beyond the published interval: absolute (0.05, metric units) or relative (5%, of the published mean).")
@click.option("--strict", is_flag=True, help="Also fail when the run's experiment, config or dataset differs from the baseline's, or the run is unfinished.")
@click.option("--all", "all_rows", is_flag=True, help="Print every published value, not only the failing ones.")
@store_option
def guard(run_ref: str, baseline: str, tolerance: str, strict: bool, all_rows: bool, store) -> None:
    """Check RUN against a published baseline: exit 0 if nothing regressed, 1 otherwise.

    A lower-is-better metric regresses when the run's mean exceeds the published upper
    interval bound plus the tolerance (mirrored for higher-is-better metrics); a published
    value the run lacks is 'missing' and fails; values the run has beyond the baseline
    are ignored. On failure a table names each metric and method with the published
    value, the run's value, the allowed limit and the excess. A method with more failed
    repetitions than published fails too. Bad input exits 2.
    """
    from enginebench.experiments.run_dataset import run_dataset
    from enginebench.results.baseline import load_baseline
    from enginebench.results.guard import guard_run, parse_tolerance, report
    from enginebench.results.store import RunStore

    tol = parse_tolerance(tolerance)
    doc = load_baseline(baseline)
    run = RunStore(store).get(run_ref)
    result = guard_run(run, doc, tol, strict=strict, dataset_hash=run_dataset(run).content_hash)
    click.echo(report(result, run.id, doc["path"], all_rows=all_rows), nl=False)
    sys.exit(0 if result.passed else 1)


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--output", "-o", required=True, type=click.Path(dir_okay=False), help="Baseline JSON file to write.")
@click.option("--metrics", default="all", show_default=True, help="Comma-separated metrics to publish, or 'all'.")
@click.option("--interval", type=click.Choice(["t", "bootstrap"]), default=None, help="Interval over repetitions [default: the run's].")
@click.option("--measure-tolerance/--no-measure-tolerance", "measure", default=True, show_default=True,
              help="Rerun the experiment twice under other machines' numerics (other BLAS kernels, no AVX-512 / "
                   "no AVX, other BLAS threading) and record each method's measured relative tolerance, so that "
                   "the baseline passes on any supported machine. Takes about twice the run's own time.")
@store_option
def publish(run_ref: str, output: str, metrics: str, interval, measure: bool, store) -> None:
    """Write RUN's summary (mean and interval per metric and method) as a baseline for 'guard'.

    The baseline states the numeric tolerance each method needs to be reproduced on
    another machine, measured by rerunning the experiment (see --measure-tolerance).
    """
    from enginebench.experiments.run_dataset import run_dataset
    from enginebench.results.baseline import make_baseline, write_baseline
    from enginebench.results.store import RunStore

    check_output(output)
    run = RunStore(store).get(run_ref)
    data = run_dataset(run)
    doc = make_baseline(run, interval=interval, metric_names=_metric_list(metrics), measure_tolerance=measure,
                        dataset_hash=data.content_hash, generated_dataset=data.generated,
                        progress=lambda text: click.echo(f"measuring the reproduction tolerance: {text}", err=True))
    path = write_baseline(doc, output)
    methods = sorted({e["method"] for e in doc["entries"]})
    click.echo(f"wrote {path}: {len(doc['entries'])} published values of experiment {doc['experiment']} "
               f"(run {run.id}; methods {', '.join(methods)})")
    rtol = doc.get("reproducibility", {}).get("rtol")
    if rtol:
        click.echo("measured reproduction tolerance (relative, per method): "
                   + ", ".join(f"{m} {v:.2g}" for m, v in sorted(rtol.items())))
