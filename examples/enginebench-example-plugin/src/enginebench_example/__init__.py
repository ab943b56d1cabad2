"""An example enginebench plugin: one method, registered through the ``enginebench.methods`` entry point."""

from enginebench_example.ridge import Ridge

__all__ = ["Ridge"]
