"""The gas-turbine TAT expansion model's step in C (``physics.py``): what ``export --fmu`` builds for the hybrids
that combine it with KRLS on this data.

The model is algebraic (no state): TAT = (TIT + 273.15) (p_out / p_in)^k - 273.15 + b with p_in = 0.97 CDP 1000
and p_out = AP + GTEP. The C below evaluates it in ``physics.py``'s order, operation by operation, with libm's
``pow`` (numpy's power of float64 arrays), so it reproduces the model to rounding.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

BODY = """    double t_in = uh[0] + GT_KELVIN;
    double p_in = GT_RATIO * uh[LU] * GT_MBAR_PER_BAR;
    double p_out = uh[2 * LU] + uh[3 * LU];
    double tat = t_in * pow(p_out / p_in, GT_K) - GT_KELVIN + GT_B;
    for (int j = 0; j < NY; j++) ys[j] = tat;"""


def c_model(model: Any, params: Mapping[str, Any], targets: Sequence[str], *, kelvin: float, pressure_ratio: float,
            mbar_per_bar: float, method: str = "pm") -> Any:
    """The ``CModel`` of the TAT model ``model`` (``physics.TATExpansionModel``, whose module hands over its
    constants: this one imports it not back) with ``params`` (k, b) predicting ``targets`` (TAT only) from TIT,
    CDP, AP and GTEP (no state, so no sample period)."""
    from enginebench.c_model import CModel, c_double
    from enginebench.errors import MethodError

    (out,) = model.outputs
    if tuple(model.inputs) != ("TIT", "CDP", "AP", "GTEP"):
        raise MethodError(f"{model.name}: its C step reads TIT, CDP, AP, GTEP, not {', '.join(model.inputs)}")
    if not targets or any(t != out for t in targets):
        raise MethodError(f"{model.name}: its C step predicts {out}, not {', '.join(targets) or 'nothing'}")
    defines = "".join(f"#define {k} {c_double(v)}\n" for k, v in (
        ("GT_KELVIN", kelvin), ("GT_RATIO", pressure_ratio), ("GT_MBAR_PER_BAR", mbar_per_bar),
        ("GT_K", float(params["k"])), ("GT_B", float(params["b"]))))
    return CModel(method=method, inputs=tuple(model.inputs), targets=tuple(targets), u_lags=1, y_lags=0,
                  body=BODY, prelude=defines)
