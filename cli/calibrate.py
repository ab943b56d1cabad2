"""``enginebench calibrate``: fit a dataset's physical model to factory-acceptance-test points."""

from __future__ import annotations

import json
import math

import click

from enginebench.cli.options import check_output, emit
from enginebench.errors import DataError
from enginebench.papers import deprecated

FAT_DATASETS = ("marine-diesel",)
"""Datasets whose physical model is calibrated on FAT points."""


def _num(x: float, digits: int = 4) -> str:
    return "-" if not math.isfinite(x) else f"{x:.{digits}g}"


def _pct(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:+.2f}"


def format_report(report, tolerance: float) -> str:
    """The calibration report as a plain-text table: one line per quantity and speed."""
    head = (f"{'quantity':<24} {'unit':<6} {'rpm':>6} {'FAT':>9} {'PM (ours)':>10} {'PE % (ours)':>12} "
            f"{'PM (paper)':>11} {'PE % (paper)':>13}")
    lines = [head, "-" * len(head)]
    for r in report.itertuples():
        flag = "  !" if abs(r.pe_pct) > tolerance else ""
        lines.append(f"{r.quantity:<24} {r.unit:<6} {r.speed_rpm:>6.0f} {_num(r.fat, 5):>9} {_num(r.pm, 5):>10} "
                     f"{_pct(r.pe_pct):>12} {_num(r.paper_pm, 5):>11} {_pct(r.paper_pe_pct):>13}{flag}")
    worst = report.loc[report["pe_pct"].abs().idxmax()]
    lines.append("")
    lines.append(f"worst |PE| (ours): {abs(worst.pe_pct):.2f} % ({worst.quantity} at {worst.speed_rpm:.0f} rpm); "
                 f"criterion |PE| <= {tolerance:g} %: {'met' if abs(worst.pe_pct) <= tolerance else 'NOT met'}")
    if report["paper_pe_pct"].notna().any():
        paper = report.loc[report["paper_pe_pct"].abs().idxmax()]
        lines.append(f"worst |PE| (paper, egt-hybrid Table 4): {abs(paper.paper_pe_pct):.2f} % "
                     f"({paper.quantity} at {paper.speed_rpm:.0f} rpm)")
    return "\n".join(lines) + "\n"


@click.group()
def calibrate() -> None:
    """Calibrate physical models on factory-acceptance-test (FAT) points."""


@calibrate.command("pm")
@click.option("--fat", "fat_ref", default="egt-hybrid", show_default=True, metavar="FILE|egt-hybrid|simulator",
              help="FAT points: 'egt-hybrid' (that paper's Table 4, shipped; docs/papers.md), 'simulator' (a shop "
                   "test of the synthetic engine) or a CSV file with the fixture's columns; for an FMU dataset "
                   "a CSV of operating points (its input and output columns).")
@click.option("--dataset", default="marine-diesel", show_default=True,
              help="Dataset whose physical model is calibrated (marine-diesel, or a dataset whose import spec "
                   "names an FMU: its .toml spec or .parquet file).")
@click.option("--on", "on", type=click.Choice(["fat", "train"]), default="fat", show_default=True,
              help="FMU datasets: fit to the --fat points, or to the dataset's training rows (its published "
                   "split's training part, else every segment).")
@click.option("--settle", type=click.FloatRange(min=0.0, min_open=True), default=600.0, show_default=True,
              help="FMU datasets: seconds each FAT point's inputs are held before the FMU is compared with it.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed of the synthetic engine tested with --fat simulator.")
@click.option("--pressure", type=click.Choice(["absolute", "gauge"]), default="absolute", show_default=True,
              help="How the table's pressures read: absolute, or gauge (above ambient).")
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=10.0, show_default=True,
              help="Largest acceptable |PE| in percent.")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None,
              help="Write the calibrated parameters (and the worst |PE|) to this JSON file.")
def calibrate_pm(fat_ref: str, dataset: str, on: str, settle: float, seed: int, pressure: str,
                 tolerance: float, output) -> None:
    """Fit the physical model's parameters to FAT points by weighted least squares.

    Prints, per quantity and speed, the FAT value, our PM's value and percentage error
    PE = (PM - FAT) / FAT, and the paper's PM value and PE where the table has them,
    then the worst |PE|.

    For a dataset whose import spec names an FMU ([physical_model], docs/data.md), fits the
    FMU parameters listed in its calibrate key to FAT points (--fat FILE) or to the training
    rows (--on train) and prints the parameters before and after and the weighted residual.

    Exit status: 0 when every |PE| is within --tolerance (10 % by default, the egt-hybrid
    paper's criterion), 1 when any |PE| exceeds it, 2 on bad input (a missing or malformed
    FAT file, an unknown dataset).
    """
    from enginebench.datasets.marine_diesel.calibration import calibrate_to_fat
    from enginebench.datasets.marine_diesel.fat import load_fat, simulator_fat

    check_output(output)
    if dataset not in FAT_DATASETS:
        return calibrate_fmu(dataset, fat_ref, on, settle, output)
    if fat_ref == "seed":                   # the old name of the paper's table: a seed is a random seed
        click.echo(deprecated("--fat seed", "--fat egt-hybrid"), err=True)
        fat_ref = "egt-hybrid"
    if fat_ref == "egt-hybrid":
        fat, source = load_fat(), "egt-hybrid Table 4 (fixture fat_seed000.csv)"
    elif fat_ref == "simulator":
        fat, source = simulator_fat(seed), f"synthetic shop test of the marine-diesel engine, random seed {seed}"
    else:
        fat, source = load_fat(fat_ref), fat_ref
    params, report = calibrate_to_fat(fat, pressure=pressure)
    click.echo(f"PM calibration ({dataset}) on {source}: {len(fat)} FAT points, pressures {pressure}, "
               f"{len(report.attrs['free'])} free parameters, {report.attrs['nfev']} model evaluations")
    click.echo(format_report(report, tolerance), nl=False)
    worst = float(report["pe_pct"].abs().max())
    if output:
        doc = {"dataset": dataset, "fat": source, "pressure": pressure, "max_abs_pe_pct": worst,
               "tolerance_pct": tolerance, "params": params}
        emit(json.dumps(doc, indent=2), output)
    if worst > tolerance:
        raise SystemExit(1)


def calibrate_fmu(dataset: str, fat_ref: str, on: str, settle: float, output) -> None:
    """``calibrate pm`` for a dataset whose physical model is an FMU."""
    from enginebench.datasets import fmu_calibrate
    from enginebench.datasets.fmu_dataset import dataset_model

    model, ds = dataset_model(dataset, FAT_DATASETS)
    if on == "train":
        segments, what = fmu_calibrate.dataset_segments(ds, model)
        fit, source = fmu_calibrate.calibrate_to_rows(model, segments), f"training rows: {what}"
    else:
        if fat_ref in ("egt-hybrid", "simulator", "seed"):  # the marine engine's tables
            raise DataError(f"dataset {dataset!r}: give --fat FILE (a CSV of operating points) or --on train")
        (fit, table), source = fmu_calibrate.calibrate_to_fat(model, fat_ref, settle), f"FAT points {fat_ref}"
        click.echo(table.to_string(index=False, float_format=lambda x: f"{x:.6g}"))
    click.echo(f"FMU calibration ({dataset}, {model.path.name}) on {source}:")
    click.echo(fmu_calibrate.format_fit(fit), nl=False)
    if output:
        doc = {"dataset": dataset, "fmu": str(model.path), "on": source, "params": fit.after,
               "rms_before": fit.rms_before, "rms_after": fit.rms_after}
        emit(json.dumps(doc, indent=2), output)
