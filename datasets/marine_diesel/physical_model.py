"""The marine-diesel PM (pm.py's equations, modules A-F) as a ``PhysicalModel`` (enginebench/physical.py).

It stands on the three modules that know the PM: ``pm.py`` (the equations), ``calibration.py`` (the
factory-test calibration it runs on first use) and ``c_step.py`` (its fixed step in C, for ``export --fmu``).
None of them imports this one back.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from enginebench.datasets.marine_diesel.pm import PM_NAME, RACK, SPEED, T_INLET, T_OUTLET, simulate_runs
from enginebench.errors import DataError

CALIBRATIONS = ("simulator", "seed")
"""Where the PM's default parameters come from: the FAT points of the generator's own
engine ("simulator", for the synthetic data) or the egt-hybrid paper's FAT fixture ("seed", the value's old name)."""
META_KEY = "pm_calibration"
"""Dataset meta entry naming the calibration (``CALIBRATIONS``); the meta ``seed`` picks the engine."""


class MarineDieselPM:
    """The egt-hybrid paper's mean-value physical model as a ``PhysicalModel`` (enginebench/physical.py).

    Parameters, in order of precedence: ``params`` if given; else the FAT calibration
    named by ``calibration``: "simulator" (default) fits the PM to the shop-test points
    of the true engine that generated ``marine-diesel`` with ``seed``
    (``calibration.simulator_fat_params``) -- the calibration the marine experiments
    use, because the synthetic data come from that engine; "seed" fits it to the
    egt-hybrid paper's FAT fixture (``calibration.seed_fat_params``; also ``enginebench calibrate
    pm``). ``for_dataset(meta)`` reads the choice from a dataset's meta
    (``meta["pm_calibration"]`` and ``meta["seed"]``, written by the generator).

    The calibration runs once per process and is resolved before the model is
    pickled, so worker processes receive the parameters instead of recomputing them.
    ``calibrate`` does not look at the operating data: the PM is calibrated on
    factory-test points, as in the egt-hybrid paper.
    """

    name = PM_NAME
    inputs = (SPEED, RACK)
    outputs = (T_INLET, T_OUTLET)

    def __init__(self, params: Mapping[str, Any] | None = None, *, calibration: str = "simulator",
                 seed: int = 0) -> None:
        if calibration not in CALIBRATIONS:
            raise DataError(f"{PM_NAME}: calibration must be one of {', '.join(CALIBRATIONS)}, got {calibration!r}")
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise DataError(f"{PM_NAME}: seed must be a non-negative integer, got {seed!r}")
        self._params = dict(params) if params is not None else None
        self.given = params is not None
        self.calibration = calibration
        self.seed = int(seed)

    @classmethod
    def for_dataset(cls, meta: Mapping[str, Any]) -> "MarineDieselPM":
        """The PM a dataset asks for: ``meta["pm_calibration"]`` (default "simulator") and ``meta["seed"]``."""
        calibration = meta.get(META_KEY, "simulator")
        if calibration not in CALIBRATIONS:
            raise DataError(f"dataset meta {META_KEY}={calibration!r} is not one of {', '.join(CALIBRATIONS)}")
        return cls(calibration=str(calibration), seed=int(meta.get("seed", 0)))

    @classmethod
    def from_fat(cls, fat, **options: Any) -> "MarineDieselPM":
        """A PM calibrated on FAT points (e.g. ``fat.simulator_fat(seed)``); see ``calibrate_to_fat``."""
        from enginebench.datasets.marine_diesel.calibration import calibrate_to_fat

        return cls(calibrate_to_fat(fat, **options)[0])

    @property
    def params(self) -> dict[str, float]:
        if self._params is None:
            from enginebench.datasets.marine_diesel.calibration import seed_fat_params, simulator_fat_params

            self._params = simulator_fat_params(self.seed) if self.calibration == "simulator" else seed_fat_params()
        return dict(self._params)

    def __getstate__(self) -> dict[str, Any]:
        return {"_params": self.params, "given": self.given, "calibration": self.calibration, "seed": self.seed}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)

    def __repr__(self) -> str:
        if self.given:
            return "MarineDieselPM(<given parameters>)"
        return f"MarineDieselPM(calibration={self.calibration!r}, seed={self.seed})"

    def calibrate(self, segments: Sequence[Mapping[str, np.ndarray]]) -> dict[str, Any]:
        """The FAT-calibrated parameters; the operating segments are not used (egt-hybrid sec. 5.1)."""
        return self.params

    def c_model(self, params: Mapping[str, Any], dt: float, targets: Sequence[str]) -> Any:
        """The model's fixed step at ``dt`` in C (``c_step.py``): ``pm``'s FMU and real-time figures."""
        from enginebench.datasets.marine_diesel.c_step import c_model

        return c_model(params, dt, targets)

    def simulate(self, params: Mapping[str, Any], segment: Mapping[str, np.ndarray],
                 dt: float) -> dict[str, np.ndarray]:
        """Predicted bank-averaged exhaust temperatures (degC) over one segment."""
        for col in self.inputs:
            if col not in segment:
                raise DataError(f"{PM_NAME}: segment lacks input column {col!r}; it needs {', '.join(self.inputs)}")
        return simulate_runs(params, np.asarray(segment[SPEED], dtype=float),
                             np.asarray(segment[RACK], dtype=float), dt)


__all__ = ["MarineDieselPM", "CALIBRATIONS", "META_KEY"]
