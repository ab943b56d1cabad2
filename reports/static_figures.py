"""The static report's PNG figures: time trends, measured vs predicted scatters, simulated trajectories.

``prediction_figures`` draws the re-fitted predictions of a static or window run
(``refit.refit_predictions``): one time trend per (target, window, split, part)
with every method, one scatter per method; ``simulation_figures`` redraws a simulation
run through ``trajectories.plot_run``. Each returns ``Figure`` entries (path, kind, caption)
that ``report.write_report`` places on its page; the page itself is ``report.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from enginebench.errors import MethodError
from enginebench.reports.refit import Predictions
from enginebench.results.run_folder import Run


@dataclass(frozen=True)
class Figure:
    """One PNG of the report: its path, kind (scatter, trend, trajectory, learning-curve) and caption."""

    path: Path
    kind: str
    caption: str


def _safe(text: str) -> str:
    import re

    return re.sub(r"[^A-Za-z0-9._-]+", "-", str(text)).strip("-")


def _time_axis(seconds: np.ndarray) -> tuple[np.ndarray, str]:
    """Time since the first row in a readable unit."""
    rel = seconds - seconds.min() if seconds.size else seconds
    span = float(rel.max()) if rel.size else 0.0
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if span >= 3 * size:
            return rel / size, unit
    return rel, "s"


def time_trend_plot(predictions: Sequence[Predictions], path: str | Path, *, title: str = "", unit: str = "",
                    size: tuple[float, float] = (11.0, 4.5), dpi: int = 100) -> Path:
    """``time_trend_figure`` written to ``path`` as a PNG; returns the path."""
    fig = time_trend_figure(predictions, title=title, unit=unit, size=size, dpi=dpi)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def time_trend_figure(predictions: Sequence[Predictions], *, title: str = "", unit: str = "",
                      size: tuple[float, float] = (11.0, 4.5), dpi: int = 100):
    """Measured and predicted (one line per method) over time on the shared rows; lines break between segments.

    All ``predictions`` must share the same rows (one (target, window, split, part)). The
    measured line is drawn over the models' (first in the legend); the y axis reads
    ``target [unit]``. Returns the matplotlib Figure (on an Agg canvas).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure as MplFigure

    from enginebench.reports.plots import _title
    from enginebench.results.units import axis_label

    if not predictions:
        raise MethodError("time trend: no predictions to draw")
    first = predictions[0]
    for p in predictions[1:]:
        if p.time.shape != first.time.shape or not np.array_equal(p.time, first.time):
            raise MethodError("time trend: the predictions do not share the same rows")
    x, time_unit = _time_axis(first.time)
    breaks = np.flatnonzero(np.diff(first.segment) != 0) + 1

    def broken(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # NaN between segments: no joining line
        return np.insert(x.astype(float), breaks, np.nan), np.insert(values.astype(float), breaks, np.nan)

    fig = MplFigure(figsize=size, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(*broken(first.truth), color="black", lw=1.2, label="measured", zorder=3)  # over every model
    styles = ["-", "--", ":", "-."]
    for k, p in enumerate(predictions):
        ax.plot(*broken(p.pred), lw=0.9, ls=styles[k % len(styles)], label=p.method)
    ax.set_xlabel(f"time since the first {first.part} row ({time_unit})")
    ax.set_ylabel(axis_label(first.target, unit))
    ax.legend(loc="best", fontsize="small", ncols=min(4, len(predictions) + 1))
    ax.grid(alpha=0.3)
    _title(ax, title, size[0])
    return fig


def prediction_figures(predictions: list[Predictions], out: Path, run: Run) -> list[Figure]:
    """Per (target, window, split, part): a time trend of every method, then one scatter per method."""
    from enginebench.reports.plots import scatter_plot
    from enginebench.results.units import run_units

    units = run_units(run.info())  # {} for a run made before units were recorded: labels without units
    figures = []
    groups: dict[tuple, list[Predictions]] = {}
    for p in predictions:
        groups.setdefault((p.target, p.window, p.split, p.part), []).append(p)
    for (target, window, split, part), group in groups.items():
        stem = f"{_safe(target)}__w{window:g}__{_safe(split)}"
        rep = group[0].repetition
        path = time_trend_plot(group, out / f"{stem}__trend.png", unit=units.get(target, ""),
                               title=f"{target}, window {window:g} s, {split}: {part} part (run {run.id}, "
                                     f"repetition {rep}, re-fitted)")
        figures.append(Figure(path, "trend", f"{target}, window {window:g} s, split {split}: measured and predicted "
                                             f"over time on the {part} part (repetition {rep}, re-fitted)"))
        for p in group:
            path = scatter_plot(p.truth, p.pred, out / f"{stem}__scatter__{_safe(p.method)}.png",
                                title=f"{p.method}: {target}, window {window:g} s, {split} {part}",
                                label=target, unit=units.get(target, ""))
            figures.append(Figure(path, "scatter", f"{p.method}: measured vs predicted {target}, window {window:g} s, "
                                                   f"split {split}, {part} part (repetition {rep}, re-fitted)"))
    return figures


def simulation_figures(run: Run, out: Path, methods, part: str, repetition: int, trajectories: int
                       ) -> tuple[list[Figure], list[str], list]:
    """A simulation run's trajectories and scatters (``trajectories.plot_run``): (figures, notes, ``Simulated``)."""
    from enginebench.reports.trajectories import plot_run

    drawn = plot_run(run, out, list(methods) if methods else None, trajectories=trajectories, part=part,
                     repetition=repetition)
    figures = []
    for path in drawn.paths:
        if "__scatter__" in path.name:
            figures.append(Figure(path, "scatter", f"measured vs simulated, {part} trajectories shown: "
                                                   f"{path.stem.split('__scatter__')[-1]} (repetition {repetition}, re-fitted)"))
        else:
            banded = drawn.bands.get(path)
            figures.append(Figure(path, "trajectory", f"simulated vs true on a {part} trajectory (repetition {repetition}, "
                                                      "re-fitted)" + (f"; {banded} gate weights as bands underneath"
                                                                      if banded else "")))
    return figures, list(drawn.notes), drawn.simulated
