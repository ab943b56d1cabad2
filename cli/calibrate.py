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
                   "test of the synthetic engine) or a CSV file with the fixture's columns.")
@click.option("--dataset", default="marine-diesel", show_default=True,
              help="Dataset whose physical model is calibrated.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Random seed of the synthetic engine tested with --fat simulator.")
@click.option("--pressure", type=click.Choice(["absolute", "gauge"]), default="absolute", show_default=True,
              help="How the table's pressures read: absolute, or gauge (above ambient).")
@click.option("--tolerance", type=click.FloatRange(min=0.0), default=10.0, show_default=True,
              help="Largest acceptable |PE| in percent.")
@click.option("--output", "-o", type=click.Path(dir_okay=False), default=None,
              help="Write the calibrated parameters (and the worst |PE|) to this JSON file.")
def calibrate_pm(fat_ref: str, dataset: str, seed: int, pressure: str, tolerance: float, output) -> None:
    """Fit the physical model's parameters to FAT points by weighted least squares.

    Prints, per quantity and speed, the FAT value, our PM's value and percentage error
    PE = (PM - FAT) / FAT, and the paper's PM value and PE where the table has them,
    then the worst |PE|.

    Exit status: 0 when every |PE| is within --tolerance (10 % by default, the egt-hybrid
    paper's criterion), 1 when any |PE| exceeds it, 2 on bad input (a missing or malformed
    FAT file, an unknown dataset).
    """
    from enginebench.datasets.marine_diesel.calibration import calibrate_to_fat
    from enginebench.datasets.marine_diesel.fat import load_fat, simulator_fat

    check_output(output)
    if dataset not in FAT_DATASETS:
        raise DataError(f"dataset {dataset!r} has no FAT-calibrated physical model; FAT calibration is available "
                        f"for: {', '.join(FAT_DATASETS)}")
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
