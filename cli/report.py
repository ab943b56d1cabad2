"""``enginebench report`` (an HTML page with tables and figures) and ``enginebench export`` (to MLflow)."""

from __future__ import annotations

import click

from enginebench.cli.options import check_metrics, load_plugins, plugin_option, split_list, store_option
from enginebench.results.output import output_folder


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--output", "-o", "out_dir", type=click.Path(file_okay=False), required=True,
              help="Folder for index.html, table.csv, the PNG figures and report.html (interactive).")
@click.option("--metrics", default=None, help="Comma-separated metric columns of the table "
              "[default: mae,mape,ppmcc,rmae; rmse,nrmse,fit,rmae for a simulation-mode run].")
@click.option("--paired", "paired_metric", default=None,
              help="Metric for the paired tests ('' to skip) [default: rmse for a simulation-mode run, else mae].")
@click.option("--figures/--no-figures", default=True, show_default=True,
              help="Draw figures (re-fits one repetition; --no-figures writes the tables only).")
@click.option("--repetition", type=click.IntRange(min=0), default=0, show_default=True,
              help="Whose training rows and selected hyperparameters to re-fit with for the figures.")
@click.option("--part", type=click.Choice(["test", "validation"]), default="test", show_default=True)
@click.option("--methods", default=None, help="Comma-separated methods to draw [default: all of the run's].")
@click.option("--trajectories", "-n", type=click.IntRange(min=1), default=3, show_default=True,
              help="Simulation runs: how many trajectories (the longest of the part).")
@click.option("--interactive/--no-interactive", default=True, show_default=True,
              help="Also write report.html: one self-contained interactive page (needs enginebench[report]).")
@store_option
@plugin_option
def report(run_ref: str, out_dir: str, metrics: str, paired_metric: str, figures: bool, repetition: int, part: str,
           methods, trajectories: int, interactive: bool, store, plugins) -> None:
    """Write an HTML report of RUN into DIR: tables, paired tests, settings and PNG figures.

    The figures need predictions, which a run does not store: the run's methods are
    re-fitted on one repetition's training rows with the hyperparameters the run selected
    (measured vs predicted scatters, time trends; simulation runs: trajectories with MoE
    gate bands). A learning-curve run gets its curve instead. report.html shows the same
    re-fit as zoomable plots, with the table sortable, offline (plotly inlined).
    """
    from enginebench.reports.interactive import write_reports
    from enginebench.results.store import RunStore

    load_plugins(plugins)
    run = RunStore(store).get(run_ref)
    if figures:  # the figures re-fit the run's methods: with the code that made the run
        run.check_plugins("re-fitted for the report's figures (--no-figures writes the tables only)")
    chosen = split_list(methods) or None
    cols = split_list(metrics) or None
    have = run.metrics()["metric"]
    if cols:
        check_metrics(cols, have, "--metrics", run.id)  # the default columns are shown where the run has them
    if paired_metric:
        check_metrics([paired_metric], have, "--paired", run.id)
    output_folder(out_dir)
    result, page, notes = write_reports(run, out_dir, interactive=interactive, metrics=cols,
                                        paired_metric=paired_metric, figures=figures, repetition=repetition,
                                        part=part, methods=chosen, trajectories=trajectories)
    for note in notes:
        click.echo(f"note: {note}", err=True)
    click.echo(f"wrote {result.index} ({len(result.figures)} figures)")
    if page is not None:
        click.echo(f"wrote {page.path} (interactive, {len(page.figures)} figures)")


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--mlflow", "tracking_uri", required=True, metavar="URI",
              help="MLflow tracking URI: a server (http://...), sqlite:///FILE, or a local folder / file: URI.")
@click.option("--experiment", default=None, help="MLflow experiment name [default: the run's experiment name].")
@click.option("--artifacts", default=None, metavar="DIR",
              help="Folder (or URI) for the artefacts of a new MLflow experiment [default: with sqlite:///DB "
                   "next to the database (mlflow.db: mlflow-artifacts/); a server's or file store's own place; "
                   "another database needs it].")
@click.option("--report/--no-report", "with_report", default=False, show_default=True,
              help="Also log the HTML report (tables only, no figures with --no-figures) under report/.")
@click.option("--figures/--no-figures", default=True, show_default=True, help="With --report: draw its figures.")
@click.option("--replace", is_flag=True, default=False,
              help="The MLflow experiment already holds RUN: log it again and delete the earlier export "
                   "(refused without this flag).")
@store_option
@plugin_option
def export(run_ref: str, tracking_uri: str, experiment, artifacts, with_report: bool, figures: bool, replace: bool,
           store, plugins) -> None:
    """Log RUN to an MLflow tracking store: one parent MLflow run and one child run per method.

    Parent: the config as params, the run's tags and artefacts (config.toml,
    environment.json, run.json, table.csv, selected_hyperparameters.csv, the report).
    Children (one per method, nested): params method, family, dataset, mode and the
    selected hyperparameters (most frequent pick); the table's metrics under the same keys
    in every child (mae, mae_ci_low, ... or mae/TARGET/dWINDOW/PART), so MLflow's compare
    view lines the methods up. Exporting RUN again is refused unless --replace.
    Needs: pip install "enginebench[mlflow]".
    """
    import tempfile

    from enginebench.results.mlflow_export import check_destination, export_run, import_mlflow
    from enginebench.results.store import RunStore

    import_mlflow()  # a missing package is reported before any work
    load_plugins(plugins)
    run = RunStore(store).get(run_ref)
    if with_report and figures:
        run.check_plugins("re-fitted for the report's figures (--no-figures logs the tables only)")
    if with_report:  # a store that would refuse the run does so before the report is built
        check_destination(run, tracking_uri, experiment=experiment, replace=replace, artifacts=artifacts)
    with tempfile.TemporaryDirectory(prefix="enginebench-report-") as tmp:
        report_dir = None
        if with_report:
            from enginebench.reports.static import write_report

            written = write_report(run, tmp, figures=figures)
            for note in written.notes:
                click.echo(f"note: {note}", err=True)
            report_dir = tmp
        result = export_run(run, tracking_uri, experiment=experiment, report_dir=report_dir, replace=replace,
                            artifacts=artifacts)
    click.echo(f"exported run {run.id} to {result.tracking_uri}: experiment {result.experiment_id}, "
               f"parent MLflow run {result.mlflow_run_id} with {len(result.child_run_ids)} child runs "
               f"({', '.join(result.child_run_ids)}; {result.n_params} params, {result.n_metric_values} metric values, "
               f"artefacts {', '.join(result.artifacts)})")
    if result.replaced:
        click.echo(f"replaced the earlier export (deleted parent run {', '.join(result.replaced)} and its child runs)")
