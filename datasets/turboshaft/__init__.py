"""Built-in synthetic dataset ``turboshaft``: twin-engine helicopter flights at 12 Hz (the turboshaft-moe paper's setting)."""

from enginebench.datasets.turboshaft.generator import GENERATOR_VERSION, SCHEMA, generate

__all__ = ["GENERATOR_VERSION", "SCHEMA", "generate"]
