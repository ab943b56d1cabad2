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
