"""Figures as PNG files: simulated vs true trajectories with MoE gate bands (seed 003, Figs. 3-6), scatter.

Pure functions: arrays in, one PNG out, nothing else touched. They draw on matplotlib's
object-oriented API with the Agg canvas, so no display, no global pyplot state and no
backend switch is involved; the pixel size is exactly ``size`` inches times ``dpi``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping

import numpy as np

from enginebench.errors import DataError


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
    *,
    inputs: Mapping[str, object] | None = None,
    scale: float | None = None,
    title: str = "",
    ylabel: str = "output",
    size: tuple[float, float] = (10.0, 7.0),
    dpi: int = 100,
) -> Path:
    """Simulated vs true output on top, optional inputs in the middle, MoE gate weights as stacked bands below.

    ``gate`` is (N, n_experts) (rows sum to 1) or None (no band panel). With ``scale``
    (mean |y| over training) the outputs are divided by it, as in the seed's figures.
    Returns the PNG path.
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
    ax.plot(t, y / div, color="black", lw=1.4, label="true")
    styles = ["-", "--", ":", "-."]
    for k, (label, v) in enumerate(sims.items()):
        ax.plot(t, v / div, lw=1.1, ls=styles[k % len(styles)], label=label)
    ax.set_ylabel(f"{ylabel} / mean|y| (train)" if scale is not None else ylabel)
    ax.legend(loc="best", fontsize="small", ncols=min(4, len(sims) + 1))
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    i = 1
    if inputs:
        ax_in = axes[i]
        for label, v in inputs.items():
            arr = _vector(v, f"inputs[{label!r}]", n)
            sd = arr.std()
            ax_in.plot(t, (arr - arr.mean()) / (sd if sd > 0 else 1.0), lw=0.9, label=label)
        ax_in.set_ylabel("inputs (z-score)")
        ax_in.legend(loc="best", fontsize="x-small", ncols=min(5, len(inputs)))
        ax_in.grid(alpha=0.3)
        i += 1
    if g is not None:
        ax_g = axes[i]
        ax_g.stackplot(t, g.T, labels=[f"expert {j + 1}" for j in range(g.shape[1])], alpha=0.85)
        ax_g.set_ylim(0, 1)
        ax_g.set_ylabel("gate")
        ax_g.legend(loc="upper right", fontsize="x-small", ncols=g.shape[1])
    axes[-1].set_xlabel("time (s)")
    return _save(fig, path)


def scatter_plot(
    y_true: object,
    y_pred: object,
    path: str | Path,
    *,
    title: str = "",
    label: str = "y",
    size: tuple[float, float] = (6.0, 6.0),
    dpi: int = 100,
) -> Path:
    """Measured vs predicted with the identity line (seed 000's scatter plots). Returns the PNG path."""
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
    ax.set_xlabel(f"measured {label}")
    ax.set_ylabel(f"predicted {label}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    return _save(fig, path)
