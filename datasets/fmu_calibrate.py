"""Fit an FMU's parameters by weighted least squares: to training rows or to factory-test (FAT) points.

The parameters named in the spec's ``calibrate`` (with optional bounds; else the bounds
of the FMU's ``min``/``max``) start from the spec's ``parameters`` or the FMU's start
values and are fitted by ``scipy.optimize.least_squares`` to the residuals
``weight[column] * (simulated - measured)`` over every segment; measured values that
are NaN are skipped. FAT points are steady operating points: each is simulated from
the FMU's initial state with its inputs held for ``settle`` seconds and compared at the
end of the hold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from enginebench.errors import DataError

FAT_STEPS = 200
"""Output intervals per FAT hold (the hold is simulated at settle / FAT_STEPS)."""


@dataclass(frozen=True)
class Fit:
    """A calibration: parameters before and after, and the weighted residuals' RMS before and after."""

    names: tuple[str, ...]
    before: dict[str, float]
    after: dict[str, float]
    rms_before: float
    rms_after: float
    n_residuals: int
    nfev: int


def _bounds(model: Any, name: str) -> tuple[float, float]:
    lo, hi = model.config["calibrate"][name]
    var = model.fmu.variable(name, "physical_model.calibrate")
    if lo is None and var.min is not None:
        lo = float(var.min)
    if hi is None and var.max is not None:
        hi = float(var.max)
    return (-math.inf if lo is None else float(lo), math.inf if hi is None else float(hi))


def _start(model: Any, name: str, lo: float, hi: float) -> float:
    x = model.parameters.get(name, model.start_value(name))
    if x is None:
        raise DataError(f"{model.path}: parameter {name!r} (physical_model.calibrate) has no start value in the FMU; "
                        "give one in physical_model.parameters")
    if not lo < x < hi:  # least_squares starts strictly inside the bounds
        x = min(max(x, lo), hi)
        span = (hi - lo) if math.isfinite(hi - lo) else max(abs(x), 1.0)
        x = x + 1e-6 * span if x <= lo else x - 1e-6 * span
    return float(x)


def residuals(model: Any, params: Mapping[str, float], segments: Sequence[Mapping[str, np.ndarray]],
              dt: float) -> np.ndarray:
    """Weighted residuals (simulated - measured) of every measured output value, segment by segment."""
    weights = model.config.get("weights", {})
    out = []
    for seg in segments:
        sim = model.simulate(params, seg, dt)
        for column in model.outputs:
            if column not in seg:
                continue
            measured = np.asarray(seg[column], dtype=float)
            keep = np.isfinite(measured)
            out.append(weights.get(column, 1.0) * (sim[column][keep] - measured[keep]))
    if not out:
        raise DataError(f"{model.name}: no measured output ({', '.join(model.outputs)}) to calibrate on")
    return np.concatenate(out)


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r * r))) if len(r) else math.nan


def fit_parameters(model: Any, segments: Sequence[Mapping[str, np.ndarray]], dt: float | None) -> Fit:
    """Fit the spec's ``calibrate`` parameters of ``model`` (an FMUPhysicalModel) to the segments."""
    from scipy.optimize import least_squares

    names = tuple(model.config["calibrate"])
    base = model.parameters
    if dt is None:
        steps = [np.diff(np.asarray(s["time"], dtype=float)) for s in segments]
        dt = float(np.median(np.concatenate(steps))) if any(len(s) for s in steps) else 1.0
    bounds = [_bounds(model, n) for n in names]
    x0 = np.array([_start(model, n, lo, hi) for n, (lo, hi) in zip(names, bounds)])

    def fun(x: np.ndarray) -> np.ndarray:
        return residuals(model, {**base, **dict(zip(names, map(float, x)))}, segments, dt)

    before = {**base, **dict(zip(names, map(float, x0)))}
    r0 = fun(x0)
    if not np.all(np.isfinite(r0)):
        raise DataError(f"{model.name}: the FMU's outputs are not finite at the starting parameters "
                        f"({', '.join(f'{k} = {v:g}' for k, v in before.items())}); change them in physical_model")
    sol = least_squares(fun, x0, bounds=([b[0] for b in bounds], [b[1] for b in bounds]), x_scale="jac",
                        diff_step=1e-4, xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200 * (len(names) + 1))
    after = {**base, **dict(zip(names, map(float, sol.x)))}
    return Fit(names, before, after, _rms(r0), _rms(sol.fun), len(r0), int(sol.nfev))


# -- FAT points --------------------------------------------------------------------------------
def load_fat_points(path: str | Path, model: Any) -> pd.DataFrame:
    """FAT points from a CSV (``#`` lines are comments): the PM's input columns and at least one output column.

    Blank output cells are points where that output was not measured. A missing file,
    a missing column or a value that is not a finite number is one DataError line.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: FAT file not found; give a CSV of operating points")
    try:
        fat = pd.read_csv(path, comment="#")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the FAT points ({' '.join(str(exc).split())}); give a CSV") from exc
    missing = [c for c in model.inputs if c not in fat.columns]
    if missing:
        raise DataError(f"{path}: FAT points lack input column(s) {', '.join(missing)}; the FMU reads "
                        f"{', '.join(model.inputs)}")
    outputs = [c for c in model.outputs if c in fat.columns]
    if not outputs:
        raise DataError(f"{path}: FAT points hold none of the FMU's output columns ({', '.join(model.outputs)})")
    if len(fat) == 0:
        raise DataError(f"{path}: no FAT points; give one operating point per row")
    for column in (*model.inputs, *outputs):
        values = pd.to_numeric(fat[column], errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if column not in model.inputs:  # a blank output cell: not measured at that point
            bad &= fat[column].notna().to_numpy()
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise DataError(f"{path}, column {column!r}, point {row + 1}: {fat[column].iloc[row]!r} is not a finite "
                            "number")
        fat[column] = values
    return fat[[*model.inputs, *outputs]].reset_index(drop=True)


def fat_segments(fat: pd.DataFrame, inputs: Sequence[str], settle: float) -> list[dict[str, np.ndarray]]:
    """One segment per FAT point: the ``inputs`` held for ``settle`` seconds, the other columns measured at its end."""
    segs = []
    for _, row in fat.iterrows():
        seg = {"time": np.array([0.0, settle])}
        for column, value in row.items():
            seg[str(column)] = np.array([value, value]) if column in inputs else np.array([math.nan, value])
        segs.append(seg)
    return segs


def calibrate_to_fat(model: Any, path: str | Path, settle: float) -> tuple[Fit, pd.DataFrame]:
    """Fit to the FAT points of ``path``; also the points with the FMU's steady values before and after."""
    if not model.config["calibrate"]:
        raise DataError(f"{model.name}: physical_model.calibrate names no parameter to fit; list some, e.g. "
                        'calibrate = ["tau"]')
    fat = load_fat_points(path, model)
    outputs = [c for c in model.outputs if c in fat.columns]
    segs = fat_segments(fat, model.inputs, settle)
    fit = fit_parameters(model, segs, settle / FAT_STEPS)
    table = fat.copy()
    for label, params in (("before", fit.before), ("after", fit.after)):
        sims = [model.simulate(params, s, settle / FAT_STEPS) for s in segs]
        for column in outputs:
            table[f"{column} ({label})"] = [float(s[column][-1]) for s in sims]
    return fit, table


def calibrate_to_rows(model: Any, segments: Sequence[Mapping[str, np.ndarray]]) -> Fit:
    """Fit to measured rows (``segments``: time, the PM's inputs and outputs per segment)."""
    if not model.config["calibrate"]:
        raise DataError(f"{model.name}: physical_model.calibrate names no parameter to fit; list some, e.g. "
                        'calibrate = ["tau"]')
    return fit_parameters(model, segments, model.dt)


def dataset_segments(ds: Any, model: Any) -> tuple[list[dict[str, np.ndarray]], str]:
    """The rows to calibrate on: the published split's training part where there is one, else every segment."""
    split = ds.meta.get("published_split") or {}
    what = "every segment"
    if split.get("train"):
        ds, what = ds.select_segments(list(split["train"])), "the published split's training part"
    columns = [c for c in (*model.inputs, *model.outputs) if c in ds.frame.columns]
    segs = []
    for _, frame in ds.segments():
        seg = {"time": frame["time"].to_numpy(dtype=float)}
        seg.update({c: frame[c].to_numpy(dtype=float) for c in columns})
        segs.append(seg)
    return segs, f"{what} ({len(segs)} segment(s), {sum(len(s['time']) for s in segs)} rows)"


def format_fit(fit: Fit) -> str:
    """Parameters before and after, and the weighted residual, as plain-text lines."""
    lines = [f"{'parameter':<20} {'before':>14} {'after':>14}"]
    for name in fit.names:
        lines.append(f"{name:<20} {fit.before[name]:>14.6g} {fit.after[name]:>14.6g}")
    lines.append(f"weighted residual RMS: {fit.rms_before:.6g} before, {fit.rms_after:.6g} after "
                 f"({fit.n_residuals} residuals, {fit.nfev} evaluations)")
    return "\n".join(lines) + "\n"

