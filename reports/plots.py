"""Figures as PNG files: simulated vs true trajectories with MoE gate bands (turboshaft-moe, Figs. 3-6), scatter.

Pure functions: arrays in, one Figure (``*_figure``) or one PNG (``*_plot``) out, nothing
else touched. They draw on matplotlib's object-oriented API with the Agg canvas, so no
display, no global pyplot state and no backend switch is involved; the pixel size is
exactly ``size`` inches times ``dpi``. Axes name the quantity with its unit
(``results.units.axis_label``); a normalised axis says so in words; titles wrap to the
figure's width.
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from enginebench.errors import DataError
from enginebench.results.units import axis_label


def _canvas(size: tuple[float, float], dpi: int, rows: int, ratios: list[float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, 1, sharex=True, gridspec_kw={"height_ratios": ratios}, squeeze=False)[:, 0]
    return fig, axes


def _vector(values: object, name: str, n: int | None = None) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.ndim != 1:
        raise DataError(f"plot: {name} must be one signal (a 1-D array), got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise DataError(f"plot: {name} has {arr.size} values but the time axis has {n}; pass one value per time step")
    return arr


def _title(ax, title: str, width_in: float) -> None:
    """Set a title wrapped to the axes' figure width (each given line on its own), so no edge clips it."""
    if not title:
        return
    chars = max(20, int(width_in * 72 / (12 * 0.6)))  # 'large' (12 pt) glyphs average about 0.6 em
    ax.set_title("\n".join(textwrap.fill(line, chars) for line in title.splitlines()))


def normalised_label(name: str, unit: str = "", scale: float | None = None) -> str:
    """The y label of an axis divided by the training mean |y|: it says so in words, and gives the scale."""
    by = f" = {scale:.4g} {unit}".rstrip() if scale is not None else ""
    return f"{name}\nnormalised [-]: divided by its\ntraining mean |y|{by}"  # short lines: the panel's height


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png")
    return path


def trajectory_plot(
    times: object,
    true: object,
    simulated: Mapping[str, object],
    gate: object | None,
    path: str | Path,
    **options: Any,
) -> Path:
    """``trajectory_figure`` written to `path` as a PNG; returns the path."""
    return _save(trajectory_figure(times, true, simulated, gate, **options), path)


def trajectory_figure(
    times: object,
    true: object,
    simulated: Mapping[str, object],
    gate: object | None,
    *,
    inputs: Mapping[str, object] | None = None,
    scale: float | None = None,
    title: str = "",
    ylabel: str = "output",
    unit: str = "",
    input_units: Mapping[str, str] | None = None,
    size: tuple[float, float] = (10.0, 7.0),
    dpi: int = 100,
):
    """Simulated vs true output on top, optional inputs in the middle, MoE gate weights as stacked bands below.

    ``gate`` is (N, n_experts) (rows sum to 1) or None (no band panel). With ``scale``
    (mean |y| over training) the outputs are divided by it, as in the turboshaft-moe paper's figures, and
    the axis says so in words; without it the axis is ``ylabel [unit]``. Inputs are
    standardised (z-scores) and named with their ``input_units``. Times are in seconds.
    Returns the matplotlib Figure (on an Agg canvas).
    """
    t = _vector(times, "times")
    n = t.size
    if n < 2:
        raise DataError("plot: the trajectory needs at least 2 time steps")
    y = _vector(true, "true", n)
    sims = {label: _vector(v, f"simulated[{label!r}]", n) for label, v in simulated.items()}
    if scale is not None and not (np.isfinite(scale) and scale > 0):
        raise DataError(f"plot: scale must be a positive number (mean |y| over training), got {scale!r}")
    g = None
    if gate is not None:
        g = np.asarray(gate, dtype=float)
        if g.ndim != 2 or g.shape[0] != n:
            raise DataError(f"plot: gate must be (time steps, experts) = ({n}, M), got shape {g.shape}")
    panels = [3.0] + ([1.5] if inputs else []) + ([1.0] if g is not None else [])
    fig, axes = _canvas(size, dpi, len(panels), panels)
    div = float(scale) if scale is not None else 1.0
    ax = axes[0]
    ax.plot(t, y / div, color="black", lw=1.4, label="true", zorder=3)  # drawn over every model
    styles = ["-", "--", ":", "-."]
    for k, (label, v) in enumerate(sims.items()):
        ax.plot(t, v / div, lw=1.1, ls=styles[k % len(styles)], label=label)
    ax.set_ylabel(normalised_label(ylabel, unit, scale) if scale is not None else axis_label(ylabel, unit))
    ax.legend(loc="best", fontsize="small", ncols=min(4, len(sims) + 1))
    ax.grid(alpha=0.3)
    _title(ax, title, size[0])
    i = 1
    if inputs:
        ax_in = axes[i]
        units = input_units or {}
        for label, v in inputs.items():
            arr = _vector(v, f"inputs[{label!r}]", n)
            sd = arr.std()
            ax_in.plot(t, (arr - arr.mean()) / (sd if sd > 0 else 1.0), lw=0.9, label=axis_label(label, units.get(label)))
        ax_in.set_ylabel("inputs, standardised\n(z-score) [-]")
        ax_in.legend(loc="best", fontsize="x-small", ncols=min(5, len(inputs)))
        ax_in.grid(alpha=0.3)
        i += 1
    if g is not None:
        ax_g = axes[i]
        ax_g.stackplot(t, g.T, labels=[f"expert {j + 1}" for j in range(g.shape[1])], alpha=0.85)
        ax_g.set_ylim(0, 1)
        ax_g.set_ylabel("gate weight [-]")
        ax_g.legend(loc="upper right", fontsize="x-small", ncols=g.shape[1])
    axes[-1].set_xlabel("time [s]")
    return fig


def scatter_plot(y_true: object, y_pred: object, path: str | Path, **options: Any) -> Path:
    """``scatter_figure`` written to `path` as a PNG; returns the path."""
    return _save(scatter_figure(y_true, y_pred, **options), path)


def scatter_figure(
    y_true: object,
    y_pred: object,
    *,
    title: str = "",
    label: str = "y",
    unit: str = "",
    size: tuple[float, float] = (6.0, 6.0),
    dpi: int = 100,
):
    """Measured vs predicted with the identity line (the egt-hybrid paper's scatter plots), axes ``label [unit]``; the Figure."""
    t = _vector(y_true, "y_true")
    p = _vector(y_pred, "y_pred", t.size)
    if t.size == 0:
        raise DataError("plot: no points to scatter")
    fig, axes = _canvas(size, dpi, 1, [1.0])
    ax = axes[0]
    ax.scatter(t, p, s=4, alpha=0.4, edgecolors="none")
    finite = np.isfinite(t) & np.isfinite(p)
    lo = float(min(t[finite].min(), p[finite].min())) if finite.any() else 0.0
    hi = float(max(t[finite].max(), p[finite].max())) if finite.any() else 1.0
    ax.plot([lo, hi], [lo, hi], color="black", lw=1.0, label="identity")
    ax.set_xlabel(f"measured {axis_label(label, unit)}")
    ax.set_ylabel(f"predicted {axis_label(label, unit)}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    _title(ax, title, size[0])
    return fig
