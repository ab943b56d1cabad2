"""``enginebench layout`` (a run's table in a source paper's layout) and ``enginebench plots`` (trajectory figures)."""

from __future__ import annotations

import click

from enginebench.cli.options import check_output, emit, load_plugins, plugin_option, split_list, store_option
from enginebench.papers import LAYOUT_PAPERS, LEGACY_FLAGS, deprecated
from enginebench.results.output import output_folder


def _paper(paper: str | None, legacy: str | None) -> str:
    """The layout asked for: --paper, or an old --seedNNN flag (one note), turboshaft-moe by default."""
    if legacy is None:
        return paper or "turboshaft-moe"
    new = LEGACY_FLAGS[legacy]
    if paper is not None and paper != new:
        raise click.UsageError(f"--paper {paper} and --{legacy} ask for different layouts; give --paper only")
    click.echo(deprecated(f"--{legacy}", f"--paper {new}"), err=True)
    return new


@click.command()
@click.argument("run_refs", metavar="RUN...", nargs=-1, required=True)
@click.option("--paper", type=click.Choice(LAYOUT_PAPERS), default=None,
              help="Whose tables: turboshaft-moe (Tables 2-3: RMAE mean ± SD, median, IQR over trajectories, "
                   "validation and test) or egt-hybrid (Tables 8-9: rows Δ x model; MAE, MAPE, PPMCC mean ± 95% CI, "
                   "test). See docs/papers.md.  [default: turboshaft-moe]")
@click.option("--seed003", "legacy", flag_value="seed003", hidden=True, help="Deprecated: --paper turboshaft-moe.")
@click.option("--seed000", "legacy", flag_value="seed000", hidden=True, help="Deprecated: --paper egt-hybrid.")
@click.option("--literature/--no-literature", default=True, show_default=True,
              help="Add the paper's own rows, labelled as literature (confidential data; not comparable).")
@click.option("--format", "fmt", type=click.Choice(["md", "csv"]), default="md", show_default=True)
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None, help="Write to a file instead of standard output.")
@store_option
def layout(run_refs: tuple[str, ...], paper, legacy, literature: bool, fmt: str, output, store) -> None:
    """Print RUN's results in a source paper's table layout (--paper; docs/papers.md).

    Several runs are merged into one table (e.g. the turboshaft WF, TRQ and TRQ-ideal
    runs make Tables 2-3); a method may appear in only one run per target. The
    turboshaft-moe layout adds a paired test between the two best run-time methods of
    each target.
    """
    import pandas as pd

    from enginebench.errors import DataError
    from enginebench.results import layouts
    from enginebench.results.store import RunStore
    from enginebench.results.units import run_units

    layout = _paper(paper, legacy)
    check_output(output)
    rs = RunStore(store)
    frames, owner, datasets, units = [], {}, [], {}
    seen: set[str] = set()
    for ref in run_refs:
        run = rs.get(ref)
        if run.id in seen:
            continue
        seen.add(run.id)
        m = run.metrics()
        for key in m[["target", "method"]].drop_duplicates().itertuples(index=False):
            if tuple(key) in owner and owner[tuple(key)] != run.id:
                raise DataError(f"runs {owner[tuple(key)]} and {run.id} both hold method {key.method!r} for target "
                                f"{key.target!r}; pass only one of them")
            owner[tuple(key)] = run.id
        frames.append(m)
        datasets.append(str(run.config().get("dataset", "")))
        units.update(run_units(run.info()))
    metrics = pd.concat(frames, ignore_index=True)
    dataset = ", ".join(dict.fromkeys(d for d in datasets if d))
    if layout == "turboshaft-moe":
        table = layouts.turboshaft_moe_table(metrics, literature=literature)
        text = (table.to_csv(index=False) if fmt == "csv"
                else layouts.turboshaft_moe_markdown(table, layouts.turboshaft_moe_paired(metrics), dataset=dataset))
    else:
        table = layouts.egt_hybrid_table(metrics, literature=literature)
        text = table.to_csv(index=False) if fmt == "csv" else layouts.egt_hybrid_markdown(table, dataset=dataset, units=units)
    emit(text, output)


@click.command()
@click.argument("run_ref", metavar="RUN", default="latest")
@click.option("--output", "-o", "out_dir", type=click.Path(file_okay=False), required=True, help="Folder for the PNG files.")
@click.option("--methods", default=None, help="Comma-separated methods to draw [default: all of the run's].")
@click.option("--trajectories", "-n", type=click.IntRange(min=1), default=3, show_default=True,
              help="How many trajectories (the longest of the part).")
@click.option("--part", type=click.Choice(["test", "validation"]), default="test", show_default=True)
@click.option("--repetition", type=click.IntRange(min=0), default=0, show_default=True,
              help="Whose training trajectories and selected hyperparameters to re-fit with.")
@store_option
@plugin_option
def plots(run_ref: str, out_dir: str, methods, trajectories: int, part: str, repetition: int, store, plugins) -> None:
    """Draw simulated vs true trajectories of RUN, with MoE gate bands, as PNG files in DIR.

    The run's methods are re-fitted on one repetition's training trajectories with the
    hyperparameters the run selected (the turboshaft-moe paper's Figs. 3-6 layout); a scatter per method
    is written as well.
    """
    from enginebench.reports.trajectories import plot_run
    from enginebench.results.store import RunStore

    load_plugins(plugins)
    run = RunStore(store).get(run_ref)
    run.check_plugins("re-fitted for its figures")
    chosen = split_list(methods) or None
    output_folder(out_dir)
    report = plot_run(run, out_dir, chosen, trajectories=trajectories, part=part, repetition=repetition)
    for note in report.notes:
        click.echo(f"note: {note}", err=True)
    for path in report.paths:
        click.echo(str(path))
