"""Units in labels: table headers (``mae [degC]``) and plot axes (``t_exhaust [degC]``).

A run records the units of its targets and inputs (``info["units"]``, from the dataset's
schema). Every table header and plot axis is built here, so the wording is the same in
the terminal, markdown, LaTeX, HTML, csv and the figures. An unknown unit ("" or None,
e.g. a run made before units were recorded) leaves the label without brackets.
"""

from __future__ import annotations

from typing import Mapping

__all__ = ["WINDOW", "axis_label", "header", "metric_unit", "run_units", "window_header"]

TARGET = "target"
"""Marker in ``METRIC_UNITS``: the metric is in the target's own unit."""

METRIC_UNITS: dict[str, str] = {
    "mae": TARGET,
    "rmse": TARGET,
    "nrmse": "-",
    "nrmse_seg_mean": "-",
    "nrmse_seg_median": "-",
    "fit": "%",
    "fit_seg_mean": "%",
    "fit_seg_median": "%",
    "fit_seg_iqr": "%",
    "r2": "-",
    "ppmcc": "-",
    "mape": "%",
    "rmae": "%",
    "rmae_seg_sd": "%",
    "rmae_seg_median": "%",
    "rmae_seg_iqr": "%",
    "skill_mae": "-",
    "skill_rmae": "-",
}
"""The unit of each metric: ``TARGET`` (the target's unit), ``%`` or ``-`` (dimensionless)."""

WINDOW = "Delta [s]"
"""The header of the window column, as the papers name it (the horizon Delta, in seconds)."""


def window_header() -> str:
    """The window column's header in every table format: ``Delta [s]``."""
    return WINDOW


def metric_unit(metric: str, unit: str | None = None) -> str:
    """The unit of `metric` for a target in `unit`: ``degC`` for mae, ``%`` for mape, ``-`` for ppmcc.

    Returns "" when it is not known (a target-unit metric of a target without a unit, a
    metric this module does not list; ``time_*`` metrics are in seconds).
    """
    if metric.startswith("time_"):
        return "s"
    found = METRIC_UNITS.get(metric, "")
    if found == TARGET:
        return (unit or "").strip()
    return found


def header(metric: str, unit: str | None = None) -> str:
    """A table header for `metric` of a target in `unit`: ``mae [degC]``, ``mape [%]``, ``nrmse [-]``, or ``mae``."""
    u = metric_unit(metric, unit)
    return f"{metric} [{u}]" if u else metric


def axis_label(column: str, unit: str | None = None) -> str:
    """A plot axis label for a signal: ``t_exhaust_turbine_inlet [degC]``, or just the name without a unit."""
    u = (unit or "").strip()
    return f"{column} [{u}]" if u else column


def run_units(info: Mapping[str, object] | None) -> dict[str, str]:
    """The ``{column: unit}`` a run recorded in its info (``{}`` for runs made before units were recorded)."""
    units = (info or {}).get("units")
    if not isinstance(units, Mapping):
        return {}
    return {str(k): str(v) for k, v in units.items() if v}
