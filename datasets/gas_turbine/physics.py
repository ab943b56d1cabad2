"""A physical model of the gas turbine's exhaust temperature (TAT) from turbine expansion.

The turbine expands the hot gas from about the compressor discharge pressure (less the
combustor pressure loss) down to the exhaust pressure. For a polytropic expansion the
absolute temperatures obey

    T_out = T_in * (p_out / p_in) ** k,   k = eta_p * (gamma - 1) / gamma,

with T_in = TIT, p_in = c * CDP (c = 0.97: a 3 % combustor pressure loss, fixed because
c and an offset trade off against each other), p_out = AP + GTEP. The exponent k and a
thermocouple offset b (degC) are fitted on the training rows only, by nonlinear least
squares (scipy). Units in the data: TIT and TAT
in degC, CDP in bar (the UCI file calls it mbar, but its values, 10-16, are bar), AP
and GTEP in mbar.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares

from enginebench.errors import DataError

KELVIN = 273.15
MBAR_PER_BAR = 1000.0
COMBUSTOR_PRESSURE_RATIO = 0.97
INITIAL = {"k": 0.25, "b": 0.0}
BOUNDS = {"k": (0.05, 0.45), "b": (-100.0, 100.0)}


class TATExpansionModel:
    """TAT from TIT, CDP, AP and GTEP through a polytropic expansion (see module docstring)."""

    name = "gas-turbine-tat"
    inputs = ("TIT", "CDP", "AP", "GTEP")
    outputs = ("TAT",)

    @staticmethod
    def _predict(k: float, b: float, s: Mapping[str, np.ndarray]) -> np.ndarray:
        t_in = np.asarray(s["TIT"], dtype=float) + KELVIN
        p_in = COMBUSTOR_PRESSURE_RATIO * np.asarray(s["CDP"], dtype=float) * MBAR_PER_BAR
        p_out = np.asarray(s["AP"], dtype=float) + np.asarray(s["GTEP"], dtype=float)
        return t_in * (p_out / p_in) ** k - KELVIN + b

    def _check(self, s: Mapping[str, np.ndarray]) -> None:
        missing = [c for c in self.inputs if c not in s]
        if missing:
            raise DataError(f"physical model {self.name!r} needs input column(s) {', '.join(missing)}; "
                            "give them the 'input' role in the experiment (roles = {...})")

    def calibrate(self, segments: Sequence[Mapping[str, np.ndarray]]) -> dict[str, Any]:
        for s in segments:
            self._check(s)
            if "TAT" not in s:
                raise DataError(f"physical model {self.name!r} is calibrated on measured TAT; the training data lack it")
        stacked = {c: np.concatenate([np.asarray(s[c], dtype=float) for s in segments]) for c in (*self.inputs, "TAT")}
        names = list(INITIAL)
        fit = least_squares(
            lambda v: self._predict(*v, stacked) - stacked["TAT"],
            x0=[INITIAL[n] for n in names],
            bounds=([BOUNDS[n][0] for n in names], [BOUNDS[n][1] for n in names]),
            x_scale=[0.1, 10.0],
        )
        params = dict(zip(names, map(float, fit.x)))
        params["rms_residual_degC"] = float(np.sqrt(np.mean(fit.fun ** 2)))
        return params

    def c_model(self, params: Mapping[str, Any], dt: float, targets: Sequence[str]) -> Any:
        """The model's step in C (``c_step.py``, given this module's constants): the hybrids' FMUs on this data."""
        from enginebench.datasets.gas_turbine.c_step import c_model

        return c_model(self, params, targets, kelvin=KELVIN, pressure_ratio=COMBUSTOR_PRESSURE_RATIO,
                       mbar_per_bar=MBAR_PER_BAR)

    def simulate(self, params: Mapping[str, Any], segment: Mapping[str, np.ndarray], dt: float) -> dict[str, np.ndarray]:
        self._check(segment)
        return {"TAT": self._predict(params["k"], params["b"], segment)}
