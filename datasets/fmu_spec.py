"""The import spec's ``physical_model`` table: an FMU as the dataset's physical model.

::

    [physical_model]
    fmu = "engine.fmu"                        # path relative to the spec (stored absolute, with its sha256)
    inputs = { u = "u" }                      # dataset column -> FMU input variable
    outputs = { T = "T" }                     # dataset column -> FMU variable it is compared with
    parameters = { tau = 8.0, K = 1.5 }       # optional: start values of FMU variables
    calibrate = ["tau", "K"]                  # optional: parameters fitted by least squares on training rows;
    # calibrate = { tau = [0.1, 100.0] }      #   or a table with [lower, upper] bounds per parameter
    weights = { T = 1.0 }                     # optional: residual weight per output column (default 1)
    fmi_type = "CoSimulation"                 # optional: or "ModelExchange" (needed only to choose when both exist)
    tolerance = 1e-6                          # optional: relative tolerance of the solver

This module only checks the table's shape (no FMU is opened here, so it needs no fmpy);
:mod:`enginebench.datasets.fmu` checks the names against the FMU and the columns at
import. Every mistake is one :class:`SpecError` line starting with the spec's path.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any, Mapping

from enginebench.errors import SpecError

KEY = "physical_model"
FMU_KEYS = ("fmu", "inputs", "outputs", "parameters", "calibrate", "weights", "fmi_type", "tolerance")
FMI_TYPES = ("CoSimulation", "ModelExchange")
EXAMPLE = ('[physical_model] fmu = "engine.fmu", inputs = { column = "fmu variable" }, '
           'outputs = { target = "fmu variable" }')


def _where(origin: Path, key: str | None = None) -> str:
    return f"{origin}: [{KEY}]" + (f" {key}" if key else "")


def _names_table(origin: Path, raw: Mapping[str, Any], key: str, required: bool) -> dict[str, str]:
    table = raw.get(key, {} if not required else None)
    if table is None:
        raise SpecError(f"{_where(origin)} needs {key} = {{ column = \"fmu variable\", ... }}; {EXAMPLE}")
    if not isinstance(table, dict) or (required and not table):
        raise SpecError(f"{_where(origin, key)} must be a table such as {{ column = \"fmu variable\" }}, got {table!r}")
    for column, variable in table.items():
        if not isinstance(variable, str) or not variable.strip():
            raise SpecError(f"{_where(origin, key)}: column {column!r} must name an FMU variable, got {variable!r}")
    return {str(k): str(v) for k, v in table.items()}


def _number(origin: Path, key: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{_where(origin, key)}: {name!r} must be a finite number, got {value!r}")
    return float(value)


def _calibrate(origin: Path, raw: Any) -> dict[str, list[float | None]]:
    """Parameter -> [lower, upper] (None: unbounded) from a list of names or a table of bounds."""
    if isinstance(raw, list):
        if not all(isinstance(n, str) and n.strip() for n in raw):
            raise SpecError(f"{_where(origin, 'calibrate')} must list FMU parameter names, got {raw!r}")
        if len(set(raw)) < len(raw):
            raise SpecError(f"{_where(origin, 'calibrate')} lists a parameter twice: {raw!r}")
        return {n: [None, None] for n in raw}
    if not isinstance(raw, dict):
        raise SpecError(f'{_where(origin, "calibrate")} must be a list such as ["tau"] or a table such as '
                        f"{{ tau = [0.1, 100.0] }}, got {raw!r}")
    out: dict[str, list[float | None]] = {}
    for name, bounds in raw.items():
        if not isinstance(bounds, list) or len(bounds) != 2:
            raise SpecError(f"{_where(origin, 'calibrate')}: {name!r} needs [lower, upper] bounds, got {bounds!r}")
        lo, hi = (_number(origin, "calibrate", name, b) for b in bounds)
        if not lo < hi:
            raise SpecError(f"{_where(origin, 'calibrate')}: {name!r} has lower bound {lo:g} >= upper bound {hi:g}")
        out[str(name)] = [lo, hi]
    return out


def parse_physical_model(raw: Any, origin: Path) -> dict[str, Any] | None:
    """The checked ``physical_model`` table as a JSON-ready dict (the FMU path made absolute), or None when absent.

    ``origin`` is the spec's path: messages name it and its folder anchors the FMU path.
    """
    if raw is None:
        return None
    origin = Path(origin)
    if not isinstance(raw, dict):
        raise SpecError(f"{origin}: {KEY} must be a table: {EXAMPLE}")
    for key in raw:
        if key not in FMU_KEYS:
            close = difflib.get_close_matches(key, FMU_KEYS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise SpecError(f"{_where(origin)}: unknown key {key!r}{hint}; allowed: {', '.join(FMU_KEYS)}")
    fmu = raw.get("fmu")
    if not isinstance(fmu, str) or not fmu.strip():
        raise SpecError(f'{_where(origin)} needs fmu = "FILE.fmu" (relative to the spec), got {fmu!r}')
    inputs = _names_table(origin, raw, "inputs", required=False)
    outputs = _names_table(origin, raw, "outputs", required=True)
    params = raw.get("parameters", {})
    if not isinstance(params, dict):
        raise SpecError(f"{_where(origin, 'parameters')} must be a table such as {{ tau = 8.0 }}, got {params!r}")
    parameters = {str(k): _number(origin, "parameters", k, v) for k, v in params.items()}
    calibrate = _calibrate(origin, raw.get("calibrate", []))
    weights_raw = raw.get("weights", {})
    if not isinstance(weights_raw, dict):
        raise SpecError(f"{_where(origin, 'weights')} must be a table such as {{ T = 1.0 }}, got {weights_raw!r}")
    weights = {}
    for column, w in weights_raw.items():
        weights[str(column)] = _number(origin, "weights", column, w)
        if weights[column] <= 0:
            raise SpecError(f"{_where(origin, 'weights')}: {column!r} must be positive, got {w!r}")
        if column not in outputs:
            raise SpecError(f"{_where(origin, 'weights')}: {column!r} is not a column of outputs "
                            f"({', '.join(map(repr, outputs))})")
    fmi_type = raw.get("fmi_type")
    if fmi_type is not None and fmi_type not in FMI_TYPES:
        raise SpecError(f"{_where(origin, 'fmi_type')} must be one of {', '.join(FMI_TYPES)}, got {fmi_type!r}")
    tolerance = raw.get("tolerance")
    if tolerance is not None and (_number(origin, "tolerance", "tolerance", tolerance) <= 0 or tolerance >= 1):
        raise SpecError(f"{_where(origin, 'tolerance')} must be a number in (0, 1), got {tolerance!r}")
    clash = sorted(set(inputs.values()) & set(parameters))
    if clash:
        raise SpecError(f"{_where(origin)}: {clash[0]!r} is both fed from a column (inputs) and set in parameters; "
                        "keep one")
    fed = sorted(set(inputs.values()) & set(calibrate))
    if fed:
        raise SpecError(f"{_where(origin)}: {fed[0]!r} is fed from a column (inputs), so calibrate cannot fit it")
    return {
        "fmu": str((origin.parent / fmu).resolve()),
        "inputs": inputs,
        "outputs": outputs,
        "parameters": parameters,
        "calibrate": calibrate,
        "weights": weights,
        "fmi_type": fmi_type,
        "tolerance": None if tolerance is None else float(tolerance),
    }
