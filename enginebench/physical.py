"""The physical-model contract a dataset may declare (used by ``pm`` and the hybrid methods).

A physical model maps run-time input signals of one segment to predicted outputs,
possibly with state carried along the segment (lags, thermal inertia). Its parameters
come from ``calibrate`` (on training data, or on factory-test points) and are a plain
dict so runs can store and show them.
"""

from __future__ import annotations

from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

Signals = Mapping[str, np.ndarray]
"""Column name -> values over one segment (the key ``time`` holds seconds)."""


@runtime_checkable
class PhysicalModel(Protocol):
    name: str
    inputs: tuple[str, ...]   # dataset columns it reads
    outputs: tuple[str, ...]  # dataset columns it predicts

    def calibrate(self, segments: Sequence[Signals]) -> dict[str, Any]:
        """Fit the free parameters on segments that carry inputs and measured outputs."""
        ...

    def simulate(self, params: Mapping[str, Any], segment: Signals, dt: float) -> dict[str, np.ndarray]:
        """Predicted outputs over one segment, one array per name in ``outputs``."""
        ...


_KNOWN: dict[str, str] = {
    # name -> "module:factory"; modules are imported only when a dataset asks for them
    "gas-turbine-tat": "enginebench.datasets.gas_turbine.physics:TATExpansionModel",
    "marine-diesel-pm": "enginebench.datasets.marine_diesel.physical_model:MarineDieselPM",
    "fmu": "enginebench.datasets.fmu:FMUPhysicalModel",  # an import spec's [physical_model] FMU (meta["fmu"])
}


def get_physical_model(name: str, meta: Mapping[str, Any] | None = None) -> PhysicalModel | None:
    """The physical model a dataset declares by name, or None where it is not available.

    A model class with a ``for_dataset(meta)`` constructor is built from the dataset's
    metadata (e.g. which calibration and generator seed it goes with).
    """
    import importlib

    target = _KNOWN.get(name)
    if target is None:
        return None
    module, attr = target.split(":")
    try:
        factory = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError):
        return None
    if meta is not None and hasattr(factory, "for_dataset"):
        return factory.for_dataset(meta)
    return factory()
